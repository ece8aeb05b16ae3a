"""Exploratory motions found in a continuous joint stream (a bag): which spans turn one joint alone.

A bag holds one stream: the arm rests, transits to a start configuration (several joints at once), rests,
turns one joint by Delta (the exploratory motion), rests, transits again... ``segment_motions`` reads the
joint states alone:

1. A joint *moves* at a sample when its position changes by more than ``SegmentConfig.rest_rad`` over the
   ``SegmentConfig.window_s`` centred on the sample (a displacement over a window, not a velocity from
   neighbouring samples: encoder noise at 1 kHz would make that jump); a *span* is a maximal run of
   samples where some joint moves. Spans are separated by rests.
2. A span is an exploratory motion (a *segment*) when exactly one joint's positions over the span range
   more than ``SegmentConfig.still_tolerance_rad`` (the others stay within it) and that joint's net turn
   |Delta| (last sample minus first) is at least ``SegmentConfig.min_delta_rad``. Every other span is
   *skipped* with its reason: several joints move (a transit, a multi-joint motion), the one joint turns
   too little, or the span runs into the start or end of the stream (cut off).

The window lets a span start up to window_s / 2 before the joint leaves its rest and end as long after it
stops, so a segment holds the whole turn plus a little rest at each end.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from solver.arrays import FloatArray
from solver.errors import InvalidInputError


@dataclass(frozen=True)
class SegmentConfig:
    """How ``segment_motions`` tells motions, transits and rests apart.

    Attributes:
        min_delta_rad: rad; smallest net turn |Delta| of an exploratory motion (the session's minimum).
        still_tolerance_rad: rad; the other joints' positions may range this much over a segment (servo
            jitter, encoder noise) and the span still counts as one joint's motion.
        rest_rad: rad; a joint moves at a sample when it moves more than this over the window.
        window_s: s; the window the displacement is measured over.
    """

    min_delta_rad: float = 0.2
    still_tolerance_rad: float = 0.01
    rest_rad: float = 0.002
    window_s: float = 0.1

    def __post_init__(self) -> None:
        values = (self.min_delta_rad, self.still_tolerance_rad, self.rest_rad, self.window_s)
        if not all(np.isfinite(v) and v > 0 for v in values):
            raise InvalidInputError(f"segmentation settings must be finite and > 0, got {self}")


@dataclass(frozen=True)
class Span:
    """A span of the joint stream where the arm moves.

    Attributes:
        first: index of its first joint sample.
        last: index of its last joint sample (inclusive).
        t_start: s, joint clock: the first sample's time.
        t_stop: s, joint clock: the last sample's time.
        joint: the index of the one joint that turns (a segment), else None.
        delta: rad: that joint's net turn over the span (0 when ``joint`` is None).
        ranges: (n,) float64, rad: every joint's range (max - min) over the span.
        reason: "" for a segment, else why the span is skipped.
    """

    first: int
    last: int
    t_start: float
    t_stop: float
    joint: int | None
    delta: float
    ranges: FloatArray
    reason: str

    @property
    def duration(self) -> float:
        """s, on the joint clock."""
        return self.t_stop - self.t_start


def moving_samples(t: FloatArray, values: FloatArray, config: SegmentConfig) -> FloatArray:
    """Per sample and joint, whether the joint moves there: (M, n) bool.

    Args:
        t: (M,) float64, s: increasing sample times.
        values: (M, n) float64, rad: joint positions.
        config: the window and the rest threshold.
    """
    half = config.window_s / 2
    before, after = t - half, t + half
    moving = np.empty(values.shape, bool)
    for j in range(values.shape[1]):
        change = np.interp(after, t, values[:, j]) - np.interp(before, t, values[:, j])
        moving[:, j] = np.abs(change) > config.rest_rad
    return moving


def segment_motions(t: FloatArray, values: FloatArray, joint_names: Sequence[str],
                    config: SegmentConfig | None = None) -> tuple[list[Span], list[Span]]:
    """Find the exploratory motions in a joint stream.

    Args:
        t: (M,) float64, s: sample times (joint clock), strictly increasing.
        values: (M, n) float64, rad: joint positions, columns in joint_names' order.
        joint_names: the n joints (messages name them).
        config: thresholds (default ``SegmentConfig()``).

    Returns:
        (segments, skipped): the spans where one joint turns alone by at least the minimum, and every
        other span with its reason, each list in time order.

    Raises:
        InvalidInputError: shapes disagree.
    """
    config = config or SegmentConfig()
    t = np.asarray(t, dtype=np.float64)
    values = np.asarray(values, dtype=np.float64)
    if values.ndim != 2 or values.shape != (len(t), len(joint_names)):
        raise InvalidInputError(f"values must be ({len(t)}, {len(joint_names)}), got {values.shape}")
    active = moving_samples(t, values, config).any(axis=1)
    edges = np.diff(np.concatenate([[0], active.astype(np.int8), [0]]))
    starts, stops = np.nonzero(edges == 1)[0], np.nonzero(edges == -1)[0] - 1
    segments: list[Span] = []
    skipped: list[Span] = []
    for first, last in zip(starts.tolist(), stops.tolist(), strict=True):
        window = values[first:last + 1]
        ranges = np.ptp(window, axis=0)
        moving = [j for j in range(len(joint_names)) if ranges[j] > config.still_tolerance_rad]
        joint: int | None = None
        delta = 0.0
        if first == 0 or last == len(t) - 1:
            reason = f"runs into the {'start' if first == 0 else 'end'} of the joint stream (cut off)"
        elif not moving:
            reason = (f"no joint ranges more than {config.still_tolerance_rad} rad "
                      f"(largest: {joint_names[int(np.argmax(ranges))]} {ranges.max():.4f} rad)")
        elif len(moving) > 1:
            listed = ", ".join(f"{joint_names[j]} {ranges[j]:.3f} rad" for j in moving)
            reason = f"{len(moving)} joints move ({listed}): a transit or a multi-joint motion"
        else:
            joint = moving[0]
            delta = float(window[-1, joint] - window[0, joint])
            reason = "" if abs(delta) >= config.min_delta_rad else (
                f"{joint_names[joint]} turns by only {delta:+.3f} rad (minimum |delta| {config.min_delta_rad} rad)")
        span = Span(first, last, float(t[first]), float(t[last]), joint if not reason else None,
                    delta if not reason else 0.0, ranges, reason)
        (skipped if reason else segments).append(span)
    return segments, skipped


__all__ = ["SegmentConfig", "Span", "moving_samples", "segment_motions"]
