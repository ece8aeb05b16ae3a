"""The solver's exceptions: one base class, one subclass per kind of failure."""

from __future__ import annotations


class ArcCalibError(Exception):
    """Base class of every error ARC-Calib raises on purpose."""


class InvalidInputError(ArcCalibError, ValueError):
    """An argument has the wrong shape, a non-finite value, or an impossible value."""


class DegenerateTrajectoryError(ArcCalibError):
    """A keypoint trajectory carries no usable ellipse (a line, too few points, no motion)."""


class DegenerateMotionError(ArcCalibError):
    """A whole exploratory motion yields no rotation axis or reference line."""


class NonRigidTracksError(DegenerateMotionError):
    """Too few of a motion's tracks turn as one rigid body by the known angles, from any start tried.

    The rigid front end's verdict, the conic front end's axis among the starts: the tracks support no axis.

    ``fit``: the fit the most tracks followed, too few of them (a ``solver.rigid_axis.RigidAxisFit``: its inliers at
    least ``RigidAxisConfig.min_tracks``, an axis the tracks fix), or None: not an axis for the linear calibration, a
    candidate that something else must confirm (``solver.one_axis``'s search, the outlines). Typed loosely: this
    module imports nothing of the solver's.
    """

    def __init__(self, message: str, fit: object | None = None) -> None:
        super().__init__(message)
        self.fit = fit


class InsufficientMotionsError(ArcCalibError):
    """Too few accepted motions to estimate T_camera_base."""


class OutlineMismatchError(InsufficientMotionsError):
    """From the first motions, the robot's outlines fit the images' edges too loosely at the tracks' pose (far off?)."""


class OutlineReachError(InsufficientMotionsError):
    """The pose given to the outlines is too uncertain to pair their contour points with the nearest edges.

    ``refuted``: the outlines searched along the pose's weakest direction anyway and found it wanting there: they fit
    their edges too loosely wherever the search put them, or their pose disagrees with it (the pose is likely on a
    wrong branch, not merely uncertain).
    """

    def __init__(self, message: str, refuted: bool = False) -> None:
        super().__init__(message)
        self.refuted = refuted


class OutlineDisagreementError(InsufficientMotionsError):
    """The outlines' pose lies further from the tracks' than their covariances allow.

    Attributes:
        chi2: the outlines' pose's Mahalanobis distance squared from the tracks' pose (``OutlineFusion``'s
            ``disagreement_chi2``).
        xi: (6,) float64 or None: the outlines' pose's perturbation from the tracks' (rad, m), where it was judged.
        prior_information: (6, 6) float64 or None: the tracks' pose's information there.
        outline_information: (6, 6) float64 or None: the outlines'.
    """

    def __init__(self, message: str, chi2: float, xi: object = None, prior_information: object = None,
                 outline_information: object = None):
        super().__init__(message)
        self.chi2 = chi2
        self.xi = xi
        self.prior_information = prior_information
        self.outline_information = outline_information


class UnobservablePoseError(ArcCalibError):
    """The accepted motions cannot fix all six degrees of freedom of T_camera_base."""


class TimeOffsetError(ArcCalibError):
    """The joint and camera clocks disagree by more than the bundle adjustment may estimate."""
