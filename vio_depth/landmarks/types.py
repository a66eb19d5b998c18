"""Domain types of the landmark window: keyframe input, per-frame points, the window's
landmarks in the world, window update diagnostics (with :class:`UpdateStatus`)."""

from __future__ import annotations

import enum
from dataclasses import dataclass, field

import numpy as np

from vio_core.camera import Camera
from vio_core.checks import check_array, check_transform


@dataclass(frozen=True)
class KeyframeInput:
    """A frame that becomes a keyframe of the window.

    Attributes:
        frame_id: unique, increasing frame id (e.g. the sequence index).
        timestamp: seconds.
        camera: its intrinsics and distortion.
        T_w_c: (4, 4) camera-to-world pose prior mean, metres; None only with a
            :class:`~.motion.MotionFactorSource` that provides the poses.
        keypoints: (N, 2) raw pixels of its keypoints (extracted once).
        matches: :class:`FrameMatches` with keyframes of the window.
    """

    frame_id: int
    timestamp: float
    camera: Camera
    T_w_c: np.ndarray | None
    keypoints: np.ndarray
    matches: tuple = ()

    def __post_init__(self):
        if self.T_w_c is not None:
            check_transform("T_w_c", self.T_w_c)
        check_array("keypoints", self.keypoints, (None, 2))


@dataclass(frozen=True)
class LandmarkPoints:
    """Metric points of one frame for the rescaler.

    Attributes:
        uv: (N, 2) raw pixels in the frame's image.
        depth: (N,) metres, camera z.
        sigma_depth: (N,) metres, 1-sigma.
        landmark_ids: (N,) int track ids.
        T_w_c: (4, 4) the frame's refined pose (its prior when not refined), or None.
        associated: keypoints associated with a landmark before the residual gate.
        pose_refined: whether the pose was refined (keyframes: by the window).
        reason: why there are no (or few) points, else "".
        covariance: (6, 6) covariance of ``T_w_c`` relative to the newest keyframe, or None.
        keypoint_index: (N,) int, index of each point's keypoint in the frame's features.
    """

    uv: np.ndarray
    depth: np.ndarray
    sigma_depth: np.ndarray
    landmark_ids: np.ndarray
    T_w_c: np.ndarray | None = None
    associated: int = 0
    pose_refined: bool = False
    reason: str = ""
    covariance: np.ndarray | None = None
    keypoint_index: np.ndarray | None = None

    def __post_init__(self):
        n = len(check_array("depth", self.depth, (None,)))
        check_array("uv", self.uv, (n, 2))
        check_array("sigma_depth", self.sigma_depth, (n,))
        check_array("landmark_ids", self.landmark_ids, (n,), dtype="int")
        if self.keypoint_index is None:
            object.__setattr__(self, "keypoint_index", np.full(n, -1, np.int64))

    def __len__(self) -> int:
        return len(self.depth)

    @classmethod
    def empty(cls, reason: str, T_w_c=None, associated: int = 0) -> "LandmarkPoints":
        z = np.zeros(0)
        return cls(np.zeros((0, 2)), z, z.copy(), np.zeros(0, np.int64), T_w_c, associated, False, reason)


class UpdateStatus(str, enum.Enum):
    """What became of a keyframe offered to the window."""

    #: inserted, the window refined (and the oldest keyframe marginalised beyond the window)
    INSERTED = "inserted"
    #: refused because the motion factor source had no factors for it (e.g. no IMU samples
    #: between it and the previous keyframe): the window is unchanged, ``reason`` says why
    REFUSED = "refused"


@dataclass(frozen=True)
class WorldLandmarks:
    """The window's landmarks in the world frame (:meth:`LandmarkWindow.world_landmarks`).

    Attributes:
        ids: (N,) int, track ids (as in :attr:`LandmarkPoints.landmark_ids`), sorted.
        points_w: (N, 3) metres, world points (at the window's refined keyframe poses).
        covariance_w: (N, 3, 3) square metres, marginal covariance of each point (pixel
            noise and the keyframe poses' uncertainty relative to the newest keyframe).
        observations: (N,) int, inlier observations (keyframes) of each landmark.
    """

    ids: np.ndarray
    points_w: np.ndarray
    covariance_w: np.ndarray
    observations: np.ndarray

    def __post_init__(self):
        n = len(check_array("ids", self.ids, (None,), dtype="int"))
        check_array("points_w", self.points_w, (n, 3), finite=True)
        check_array("covariance_w", self.covariance_w, (n, 3, 3), finite=True)
        check_array("observations", self.observations, (n,), dtype="int")

    def __len__(self) -> int:
        return len(self.ids)


@dataclass(frozen=True)
class WindowUpdate:
    """What one keyframe insertion did (for diagnostics).

    Attributes:
        frame_id, keyframes, landmarks (VALID after refinement), observations (projection
        factors), detached (observations split off their tracks), marginalised (frame id
        or None), track_status (counts before refinement), lm_error_before/after (graph
        error).
        median_residual_px: median reprojection residual of the landmarks' inlier
            observations after refinement (ideal pixels; about 1.2 x pixel sigma when the
            images agree with the model).
        pose_shift_sigmas: largest move of a keyframe pose from its prior, in units of the
            absolute prior sigmas (RMS over the 6 components): above ~3 the images and the
            stated pose uncertainty disagree.
        status: :class:`UpdateStatus`; reason: why it was refused ("" when inserted).
    """

    frame_id: int
    keyframes: int
    landmarks: int
    observations: int
    detached: int
    marginalised: int | None
    track_status: dict = field(default_factory=dict)
    lm_error_before: float = float("nan")
    lm_error_after: float = float("nan")
    median_residual_px: float = float("nan")
    pose_shift_sigmas: float = float("nan")
    status: UpdateStatus = UpdateStatus.INSERTED
    reason: str = ""

    @property
    def ok(self) -> bool:
        """The keyframe was inserted."""
        return self.status == UpdateStatus.INSERTED

    def summary(self) -> str:
        """One line for a log: the keyframe, its landmarks, observations, residual and graph error."""
        return (f"keyframe {self.frame_id}: {self.landmarks} landmarks, {self.observations} observations, median "
                f"residual {self.median_residual_px:.2f} px, graph error {self.lm_error_before:.1f} -> "
                f"{self.lm_error_after:.1f}")

    @classmethod
    def refused(cls, frame_id: int, keyframes: int, reason: str) -> "WindowUpdate":
        """The keyframe ``frame_id`` was refused (``reason``); the window (``keyframes``) is unchanged."""
        return cls(int(frame_id), keyframes, 0, 0, 0, None, status=UpdateStatus.REFUSED, reason=reason)
