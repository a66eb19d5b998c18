"""What the pipeline produces for one frame: typed results of the points stage and of the frame."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from matchers import Features
from triangulation import PoseConsistency

from ..frame import Frame
from ..keyframes import Motion
from ..poses import FramePose
from ..rescale import AffineFit, RescaleResult
from .point_source import PointSourceSpec
from .status import FrameStatus, PairStatus


@dataclass(frozen=True)
class PairAttempt:
    """One frame pair the points stage matched (and, with enough matches, triangulated).

    Attributes:
        keyframe: index of the keyframe.
        motion: relative motion between the two frames.
        matches: number of feature matches.
        status: :class:`PairStatus`.
        point_status: number of candidate points per triangulation status (empty when
            the pair was not triangulated).
        valid: points that passed every check.
        T_kf_cur: (4, 4) the relative pose used (current camera to keyframe camera, metres),
            or None.
        predicted_error: the pair's predicted median relative depth sigma before matching
            (:func:`triangulation.predicted_depth_error`), or None.
        consistency: the images' test of the stated pose
            (:class:`triangulation.PoseConsistency`), or None (pose taken as exact).
        pose_sigma: ``(rotation deg, translation m)`` 1-sigma of the relative pose used
            (largest axis, inflation included), or None (exact).
    """

    keyframe: int
    motion: Motion
    matches: int
    status: PairStatus
    point_status: dict[str, int] = field(default_factory=dict)
    valid: int = 0
    T_kf_cur: np.ndarray | None = field(default=None, repr=False, compare=False)
    predicted_error: float | None = None
    consistency: PoseConsistency | None = field(default=None, compare=False)
    pose_sigma: tuple[float, float] | None = None

    def problem(self, min_matches: int) -> str:
        """Why this pair gave no point ("" when it did)."""
        if self.status == PairStatus.TOO_FEW_MATCHES:
            return f"{self.matches} matches with keyframe {self.keyframe} (< {min_matches})"
        if self.status == PairStatus.NO_VALID_POINTS:
            return f"no point passed the checks with keyframe {self.keyframe}"
        if self.status == PairStatus.POSE_INCONSISTENT and self.consistency is not None:
            return (f"keyframe {self.keyframe}: the images disagree with the poses beyond their stated "
                    f"uncertainty: {self.consistency.describe()}")
        return ""


@dataclass(frozen=True)
class LandmarkInfo:
    """What the landmark window did for a frame (``--points landmarks``).

    Attributes:
        keyframe: the frame became a keyframe; ``keyframe_reason`` says why.
        matches: feature matches with the window's newest keyframes.
        associated: keypoints associated with a landmark.
        pose_refined: the frame's pose was refined against the landmarks (or by the window).
        window_keyframes: keyframes in the window after this frame.
        window_residual_px: median reprojection residual of the window's landmarks after
            its refinement (keyframes only), pixels.
        pose_shift_sigmas: largest move of a keyframe pose from its prior in that refinement,
            in prior sigmas (keyframes only): large values mean the images and the poses disagree.
    """

    keyframe: bool
    keyframe_reason: str
    matches: int
    associated: int
    pose_refined: bool
    window_keyframes: int
    window_residual_px: float | None = None
    pose_shift_sigmas: float | None = None


@dataclass
class PointsOutcome:
    """The metric points of one frame and how they were obtained.

    Attributes:
        status: OK when points were delivered, else NO_PAIR / NO_POSE / TOO_FEW_MATCHES /
            TOO_FEW_POINTS.
        reason: a readable explanation, rendered from the data below.
        attempts: the frame pairs tried (SfM), newest keyframe first.
        weak: no keyframe was beyond the pairing thresholds, the largest baseline was used.
        uv: (N, 2) raw pixels of the points in this image.
        depth: (N,) metres, z in this camera.
        sigma: (N,) metres, 1-sigma of ``depth``, or None (reference points: exact).
        confidence: (N,) matching confidence in [0, 1], or None.
        landmarks: what the landmark window did (``--points landmarks``), else None.
        T_w_c: (4, 4) camera-to-world pose of the frame as the stage used it (the landmark
            window's refined pose), or None when the stage used relative poses only.
        timings: seconds of ``matching`` and ``triangulation``, summed over the pairs.
        depth_shared: (N, K) metres, the points' sensitivities to K independent unit-variance
            errors they share (their relative poses', six per pair or one set for the
            landmark window's frame pose), or None (no pose uncertainty).
        pose_inflation: the factor the stated pose uncertainty was inflated by, because the
            images showed it too small (:class:`triangulation.PoseInflation`), or None.
    """

    status: FrameStatus
    reason: str = ""
    attempts: list[PairAttempt] = field(default_factory=list)
    weak: bool = False
    uv: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)), repr=False)
    depth: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    sigma: np.ndarray | None = field(default=None, repr=False)
    confidence: np.ndarray | None = field(default=None, repr=False)
    landmarks: LandmarkInfo | None = None
    T_w_c: np.ndarray | None = field(default=None, repr=False)
    timings: dict[str, float] = field(default_factory=dict, repr=False)
    depth_shared: np.ndarray | None = field(default=None, repr=False)
    pose_inflation: float | None = None
    scale_agreement: tuple[float, float, int] | None = None

    @property
    def partners(self) -> list[int]:
        return [a.keyframe for a in self.attempts]

    @property
    def matches(self) -> int:
        return self.landmarks.matches if self.landmarks is not None else sum(a.matches for a in self.attempts)

    @property
    def motion(self) -> Motion | None:
        return self.attempts[0].motion if self.attempts else None

    @property
    def relative_pose(self) -> tuple[int, np.ndarray] | None:
        """``(keyframe index, T_kf_cur (4, 4))`` of the first pair tried, or None."""
        if not self.attempts or self.attempts[0].T_kf_cur is None:
            return None
        return self.attempts[0].keyframe, self.attempts[0].T_kf_cur

    @property
    def point_status(self) -> dict[str, int]:
        """Candidate points per triangulation status, summed over the pairs."""
        counts: dict[str, int] = {}
        for a in self.attempts:
            for name, k in a.point_status.items():
                counts[name] = counts.get(name, 0) + k
        return counts


@dataclass
class FrameResult:
    """Everything the pipeline decided for one frame (``frames.jsonl`` is built from it).

    Attributes:
        frame: 0-based index in the sequence; ``stem`` the image stem; ``timestamp`` seconds.
        status: :class:`FrameStatus`; ``reason`` says why (readable).
        point_source: where the points came from (``sfm``, ``lidar:16``...).
        points: the points stage's :class:`PointsOutcome`.
        rescale: the rescaler's decision, or None when the frame had no disparity map.
        points_sampled: points whose position fell on valid disparity (fed to the fit).
        depth: (H, W) float32 metres, NaN = invalid; None without metric depth.
        disparity: (H, W) float32 input disparity (None when absent).
        points_uv: (N, 2) raw px / points_depth: (N,) metres / points_sigma: (N,) metres or
            None: the metric points fed to the fit; points_inlier: (N,) bool, inliers of this
            frame's own fit (full or scale-only), or None.
        timings: seconds per stage (``disparity``, ``features``, ``points``, ``fit``,
            ``depth``; the runner adds ``load``, ``write``, ``evaluation``).
        backfilled: the result comes from the offline backward pass.
        disparity_valid_fraction: fraction of finite pixels of the disparity map (None
            without a map).
        frame_pose: the tracking pose source's own pose of the frame (``--poses vio``), or None.
        depth_released: the frame had a depth map that :meth:`without_arrays` released
            (``has_depth`` stays True).
    """

    frame: int
    stem: str
    timestamp: float
    status: FrameStatus
    reason: str
    point_source: PointSourceSpec
    points: PointsOutcome
    rescale: RescaleResult | None = None
    points_sampled: int = 0
    depth: np.ndarray | None = field(default=None, repr=False)
    disparity: np.ndarray | None = field(default=None, repr=False)
    points_uv: np.ndarray | None = field(default=None, repr=False)
    points_depth: np.ndarray | None = field(default=None, repr=False)
    points_sigma: np.ndarray | None = field(default=None, repr=False)
    points_inlier: np.ndarray | None = field(default=None, repr=False)
    timings: dict[str, float] = field(default_factory=dict)
    backfilled: bool = False
    disparity_valid_fraction: float | None = None
    frame_pose: FramePose | None = field(default=None, repr=False)
    depth_released: bool = field(default=False, repr=False)

    @property
    def has_depth(self) -> bool:
        return self.depth is not None or self.depth_released

    def without_arrays(self) -> "FrameResult":
        """A copy for keeping every frame's result over a long run in small constant memory
        per frame: without the (H, W) depth and disparity maps and without the per-point
        arrays (``points_*`` and the points stage's ``uv``, ``depth``, ``sigma``,
        ``confidence``); statuses, fit, poses, pairs and timings are kept."""
        points = replace(self.points, uv=np.zeros((0, 2), self.points.uv.dtype),
                         depth=np.zeros(0, self.points.depth.dtype), sigma=None, confidence=None, depth_shared=None)
        return replace(self, depth=None, disparity=None, depth_released=self.has_depth, points=points,
                       points_uv=None, points_depth=None, points_sigma=None, points_inlier=None)

    @property
    def fit(self) -> AffineFit | None:
        """The fit used for the depth map (None without depth)."""
        return None if self.rescale is None else self.rescale.fit

    @property
    def seconds(self) -> float:
        """Pipeline seconds spent on this frame (sum of the pipeline's own stage timings)."""
        return sum(v for k, v in self.timings.items() if k in PIPELINE_STAGES)


#: the stages timed by :class:`~vio_depth.pipeline.Pipeline` itself (``points`` includes its
#: sub-stages ``matching`` and ``triangulation``, also recorded; ``poses``: a tracking pose source)
PIPELINE_STAGES = ("image", "disparity", "features", "poses", "points", "fit", "depth")


@dataclass
class PreparedFrame:
    """A frame after the pipeline's stateless stages (:meth:`~vio_depth.pipeline.Pipeline.prepare`):
    image decoding, feature extraction and the disparity map. They depend on nothing but the
    frame, so they may run ahead of :meth:`~vio_depth.pipeline.Pipeline.process_prepared`,
    in another thread.

    Attributes:
        frame: the frame; when its image was read, ``frame.image()`` returns the decoded
            pixels without reading them again.
        features: the frame's features (SfM points), else None.
        disparity: (H, W) float affine-invariant disparity, or None (no map for this frame).
        timings: seconds of the stages done: ``image``, ``features``, ``disparity``.
        corrupt_image: why the image's data are damaged ("" when they are not); such a
            frame has neither features nor disparity and gets the status ``corrupt_image``.
    """

    frame: Frame
    features: Features | None
    disparity: np.ndarray | None = field(repr=False)
    timings: dict[str, float] = field(default_factory=dict)
    corrupt_image: str = ""
