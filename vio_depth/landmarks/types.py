"""Domain types of the landmark window: keyframe input, motion-factor hook, per-frame points,
window update diagnostics."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

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
            :class:`MotionFactorSource` that supplies the initial estimate.
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


class MotionFactorSource(Protocol):
    """Adds motion factors between consecutive keyframes (e.g. gtsam ``CombinedImuFactor``).

    With it, the pose-prior settings' ``absolute_on_every_keyframe`` is normally False: the
    first keyframe is anchored by its prior and the source's factors carry the rest. A
    source with a true attribute ``anchors_first_keyframe`` adds the first keyframe's prior
    itself (in :meth:`factors` with ``previous`` None) and the window adds none. A source
    with a method ``after_marginalisation(oldest_frame_id, estimate) -> gtsam.NonlinearFactorGraph``
    adds factors on the window's oldest keyframe after each marginalisation (VIO: a gauge
    prior on the unobservable yaw and position). A source with a true attribute
    ``provides_poses`` gives every keyframe's initial pose (keyframes then carry no
    ``T_w_c``): the pose priors of frames are its predictions in the window's current frame,
    used as they are by :meth:`LandmarkWindow.query` (not corrected like a sequence pose).
    """

    def extra_keys(self, frame_id: int) -> list[int]:
        """gtsam keys the source adds for a keyframe besides its pose ``X(frame_id)``
        (e.g. velocity and bias); they are marginalised together with it."""

    def factors(self, previous: "KeyframeInput | None", current: KeyframeInput, estimate):
        """``(gtsam.NonlinearFactorGraph, gtsam.Values)``: factors linking ``previous``
        (None for the first keyframe) and ``current``, and initial values of every new key
        (including ``X(current.frame_id)`` when ``current.T_w_c`` is None). ``estimate`` is
        the window's current ``gtsam.Values``."""


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
