"""The points stage with multi-view landmarks (``--points landmarks``).

:class:`LandmarkPointsStage` feeds each frame's features and its pose (the sequence's, as a
prior with the uncertainty of the sequence's kind of poses) to a
:class:`~vio_depth.landmarks.LandmarkEstimator`: tracks over a keyframe window, refined
with gtsam, give every frame the metric landmarks it sees -- also frames without a fresh
pair (stops, slow motion, turning in place). The two-view stage
(:class:`~vio_depth.pipeline.points.TwoViewPoints`, ``--points sfm``) stays as the baseline.
"""

from __future__ import annotations

from matchers import Features, Matcher

from ..frame import Frame
from ..landmarks import LandmarkEstimator, LandmarkSettings
from ..poses import FramePose
from .result import LandmarkInfo, PointsOutcome
from .status import FrameStatus


class LandmarkPointsStage:
    """Landmark points for a stream of frames (one instance per stream).

    Args:
        matcher: extracts and matches features.
        settings: :class:`~vio_depth.landmarks.LandmarkSettings` with a resolved pose prior.

    Frames are numbered by their position in the stream (not their sequence index), so the
    offline backward pass, which feeds frames in reverse, is a stream like any other.
    """

    def __init__(self, matcher: Matcher, settings: LandmarkSettings):
        self.matcher = matcher
        self.estimator = LandmarkEstimator(settings, matcher)
        self._count = 0

    def process(self, frame: Frame, features: Features, frame_pose: FramePose | None = None) -> PointsOutcome:
        """The landmarks ``frame`` sees (its ``features`` were just extracted). ``frame_pose``
        (a tracking pose source's) is not used: the window takes the sequence's poses as priors."""
        if frame.T_w_c is None:
            return PointsOutcome(FrameStatus.NO_POSE, "the landmark window needs the frame's pose (a prior)")
        out = self.estimator.process(self._count, frame.timestamp, frame.camera, frame.T_w_c, features)
        self._count += 1
        pts = out.points
        update = out.update
        info = LandmarkInfo(
            keyframe=out.keyframe, keyframe_reason=out.keyframe_reason, matches=out.matches,
            associated=int(pts.associated), pose_refined=bool(pts.pose_refined),
            window_keyframes=len(self.estimator.window.keyframe_ids),
            window_residual_px=None if update is None else float(update.median_residual_px),
            pose_shift_sigmas=None if update is None else float(update.pose_shift_sigmas),
        )
        if len(pts) == 0:
            return PointsOutcome(FrameStatus.TOO_FEW_POINTS, pts.reason or "no landmark seen", landmarks=info,
                                 T_w_c=pts.T_w_c)
        return PointsOutcome(FrameStatus.OK, pts.reason, uv=pts.uv, depth=pts.depth, sigma=pts.sigma_depth,
                             landmarks=info, T_w_c=pts.T_w_c)
