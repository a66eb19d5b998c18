"""What the pipeline produces for one frame: typed results of the points stage and of the frame."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..evaluation import PointSourceSpec
from ..keyframes import Motion
from ..poses import FramePose
from ..rescale import AffineFit, RescaleResult
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
    """

    keyframe: int
    motion: Motion
    matches: int
    status: PairStatus
    point_status: dict[str, int] = field(default_factory=dict)
    valid: int = 0
    T_kf_cur: np.ndarray | None = field(default=None, repr=False, compare=False)

    def problem(self, min_matches: int) -> str:
        """Why this pair gave no point ("" when it did)."""
        if self.status == PairStatus.TOO_FEW_MATCHES:
            return f"{self.matches} matches with keyframe {self.keyframe} (< {min_matches})"
        if self.status == PairStatus.NO_VALID_POINTS:
            return f"no point passed the checks with keyframe {self.keyframe}"
        return ""


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
    """

    status: FrameStatus
    reason: str = ""
    attempts: list[PairAttempt] = field(default_factory=list)
    weak: bool = False
    uv: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)), repr=False)
    depth: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    sigma: np.ndarray | None = field(default=None, repr=False)
    confidence: np.ndarray | None = field(default=None, repr=False)

    @property
    def partners(self) -> list[int]:
        return [a.keyframe for a in self.attempts]

    @property
    def matches(self) -> int:
        return sum(a.matches for a in self.attempts)

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

    @property
    def has_depth(self) -> bool:
        return self.depth is not None

    @property
    def fit(self) -> AffineFit | None:
        """The fit used for the depth map (None without depth)."""
        return None if self.rescale is None else self.rescale.fit

    @property
    def seconds(self) -> float:
        """Pipeline seconds spent on this frame (sum of the pipeline's own stage timings)."""
        return sum(v for k, v in self.timings.items() if k in PIPELINE_STAGES)


#: the stages timed by :class:`~vio_depth.pipeline.Pipeline` itself
PIPELINE_STAGES = ("image", "disparity", "features", "poses", "points", "fit", "depth")
