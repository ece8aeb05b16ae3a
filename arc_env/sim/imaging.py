"""Realistic imaging: how the robot looks and what a real camera does to the frames of a sweep.

Appearance (``SceneConfig.appearance``):

* ``painted``: every drawn geom of the robot wears a uniform random speckle (today's default, and far
  richer in corners than any real arm);
* ``as_shipped``: the model's own materials, nothing added -- smoother than any real arm: the hard floor;
* ``realistic``: as shipped plus what real arms carry (``arc_env.sim.marks``), all from a generator seeded
  by ``SceneConfig.appearance_seed``: screw heads and specks on some geoms, panel seams (lines around
  the link) on others, each in the geom's own colour; a printed label (a few cm: light ground, dark text
  lines, a logo) on about 40 % of the links and a dark cable 5-10 mm thick along about 60 % of them
  (of those long enough), placed on the link's surface by ray casting and fixed to it. Labels and cables
  are visual-only geoms: no mass, no collision, not in the oracle's surface points. Nothing downstream
  knows where any mark is.

Camera effects (``CameraEffects``, applied by ``arc_env.sim.scene.Scene.render_sweep``), each imitating a
real colour camera at 30 Hz (figures of a RealSense D415 / typical USB3 industrial camera indoors):

* sensor noise: read noise of ``read_noise_grey`` grey levels plus shot noise whose variance grows with
  the signal (``shot_noise_grey2`` grey levels^2 per grey level: about 2 grey levels of shot noise at
  mid-grey with the default 0.016), drawn per pixel and channel;
* motion blur: the mean of ``subframes`` renders spread over the exposure (``exposure_s`` at the sweep's
  joint speed; 8 ms is a typical indoor auto-exposure);
* auto-exposure gain drift: a smooth random walk of the image gain within +- ``gain_drift`` over a sweep;
* lossy video: the sweep encoded as H.264 MP4 at ``video_bitrate`` bit/s (scaled to 1080p; PyAV's
  libx264 with its ``veryfast`` preset, the speed class of a camera's real-time encoder) and decoded
  back, as a ROS bag or a phone recording delivers it. On a 1080p test sweep ``veryfast`` encodes in
  27 ms per frame against ``medium``'s 71 (libx264's default) with the same mean error after decoding
  (2.60 vs 2.63 grey levels).

All randomness comes from the generator handed to ``apply`` (seeded by the caller).
"""

from __future__ import annotations

import io
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from solver.arrays import FloatArray, ImageArray
from solver.errors import InvalidInputError

APPEARANCES = ("painted", "as_shipped", "realistic")
REALISMS = ("clean", "realistic")
#: Pixels of a 1080p frame: ``video_bitrate`` is scaled by the frame's pixels over this.
_FULL_HD_PIXELS = 1920 * 1080
#: libx264's speed preset for the lossy video (a real-time encoder's class; see the module notes).
_X264_PRESET = "veryfast"


@dataclass(frozen=True)
class CameraEffects:
    """What a real camera adds to rendered frames (see the module docstring for the figures).

    Attributes:
        read_noise_grey: standard deviation of the read noise, grey levels (0-255).
        shot_noise_grey2: shot-noise variance per grey level of signal, grey levels^2.
        exposure_s: exposure time, s; the joint moves during it (0: a sharp instant).
        subframes: renders averaged over the exposure (>= 2 when exposure_s > 0).
        gain_drift: largest relative change of the auto-exposure gain within a sweep (0.05: +-5 %).
        video_bitrate: H.264 bitrate at 1080p, bit/s (scaled with the frame's pixels); 0: no video.
    """

    read_noise_grey: float = 0.0
    shot_noise_grey2: float = 0.0
    exposure_s: float = 0.0
    subframes: int = 5
    gain_drift: float = 0.0
    video_bitrate: int = 0

    def __post_init__(self) -> None:
        if min(self.read_noise_grey, self.shot_noise_grey2, self.exposure_s, self.gain_drift) < 0:
            raise InvalidInputError("camera effects must be >= 0")
        if self.exposure_s > 0.1 or self.gain_drift > 0.5 or self.read_noise_grey > 50:
            raise InvalidInputError("camera effects out of range: exposure_s <= 0.1 s, gain_drift <= 0.5, "
                                    "read_noise_grey <= 50")
        if self.subframes < 2 and self.exposure_s > 0:
            raise InvalidInputError("an exposure needs subframes >= 2")
        if self.video_bitrate < 0:
            raise InvalidInputError("video_bitrate must be >= 0")

    @property
    def active(self) -> bool:
        """Whether anything is applied (a clean camera changes nothing and draws no random numbers)."""
        return bool(self.read_noise_grey or self.shot_noise_grey2 or self.gain_drift or self.video_bitrate)

    @classmethod
    def preset(cls, realism: str) -> CameraEffects:
        """``clean`` (nothing) or ``realistic`` (noise ~3 grey levels, 8 ms exposure, +-5 % gain, H.264)."""
        if realism == "clean":
            return cls()
        if realism == "realistic":
            return cls(read_noise_grey=2.0, shot_noise_grey2=0.016, exposure_s=0.008, gain_drift=0.05,
                       video_bitrate=8_000_000)
        raise InvalidInputError(f"realism must be one of {REALISMS}, got {realism!r}")

    def exposure_offsets(self, joint_speed: float) -> FloatArray:
        """Joint offsets (rad) of the sub-frame renders around each frame's reading: (S,), mean 0.

        A frame's joint reading is taken at the middle of its exposure.
        """
        if self.exposure_s <= 0:
            return np.zeros(1)
        span = self.exposure_s * joint_speed
        return np.linspace(-0.5 * span, 0.5 * span, self.subframes)

    def apply(self, frames: Sequence[ImageArray], rng: np.random.Generator) -> list[ImageArray]:
        """Gain drift, noise and lossy video on a sweep's frames (F images (H, W, 3) uint8 RGB); new list."""
        out = [np.asarray(f) for f in frames]
        if not self.active or not out:
            return out
        n = len(out)
        if self.gain_drift:
            walk = np.cumsum(rng.normal(0.0, 1.0, n))
            walk -= walk.mean()
            scale = np.max(np.abs(walk)) or 1.0
            gains = 1.0 + self.gain_drift * rng.uniform(0.3, 1.0) * walk / scale
        else:
            gains = np.ones(n)
        noisy = []
        for frame, gain in zip(out, gains, strict=True):
            signal = frame.astype(np.float32) * np.float32(gain)
            sigma = np.sqrt(self.read_noise_grey**2 + self.shot_noise_grey2 * np.clip(signal, 0, 255))
            signal += sigma * rng.standard_normal(signal.shape, dtype=np.float32)
            noisy.append(np.clip(np.rint(signal), 0, 255).astype(np.uint8))
        if self.video_bitrate:
            noisy = h264_round_trip(noisy, self.video_bitrate)
        return noisy


def realism_settings(realism: str = "clean", appearance: str | None = None) -> dict[str, object]:
    """``SceneConfig`` fields for a realism preset: appearance, effects and shadows.

    ``realistic`` means the realistic appearance (unless ``appearance`` says otherwise), the realistic
    camera effects and shadows on; ``clean`` means the painted appearance (unless given), no effects, no
    shadows -- today's setting.
    """
    if realism not in REALISMS:
        raise InvalidInputError(f"realism must be one of {REALISMS}, got {realism!r}")
    default = "realistic" if realism == "realistic" else "painted"
    chosen = appearance or default
    if chosen not in APPEARANCES:
        raise InvalidInputError(f"appearance must be one of {APPEARANCES}, got {chosen!r}")
    return {"appearance": chosen, "effects": CameraEffects.preset(realism), "shadows": realism == "realistic"}


def h264_round_trip(frames: Sequence[ImageArray], bitrate_1080p: int, fps: float = 30.0) -> list[ImageArray]:
    """Encode RGB frames (H, W, 3) uint8 as H.264 MP4 in memory (bitrate scaled from 1080p) and decode them."""
    import av  # PyAV: FFmpeg with libx264, from its wheel

    h, w = frames[0].shape[:2]
    buffer = io.BytesIO()
    with av.open(buffer, mode="w", format="mp4") as container:
        stream = container.add_stream("libx264", rate=int(round(fps)))
        stream.width, stream.height = w - w % 2, h - h % 2  # yuv420p needs even sides
        stream.pix_fmt = "yuv420p"
        stream.options = {"preset": _X264_PRESET}
        stream.bit_rate = max(100_000, int(bitrate_1080p * w * h / _FULL_HD_PIXELS))
        for frame in frames:
            even = np.ascontiguousarray(frame[:stream.height, :stream.width])
            for packet in stream.encode(av.VideoFrame.from_ndarray(even, format="rgb24")):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
    buffer.seek(0)
    with av.open(buffer) as container:
        decoded = [f.to_ndarray(format="rgb24") for f in container.decode(video=0)]
    if len(decoded) != len(frames):
        raise InvalidInputError(f"the H.264 round trip returned {len(decoded)} of {len(frames)} frames")
    if (h, w) != decoded[0].shape[:2]:  # odd sides: repeat the last row/column
        decoded = [np.pad(f, ((0, h - f.shape[0]), (0, w - f.shape[1]), (0, 0)), mode="edge") for f in decoded]
    return decoded
