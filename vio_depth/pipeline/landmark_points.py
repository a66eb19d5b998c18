"""The points stage with multi-view landmarks (``--points landmarks``).

:class:`LandmarkPointsStage` feeds each frame's features and its pose (the sequence's, as a
prior with the uncertainty of the sequence's kind of poses) to a
:class:`~vio_depth.landmarks.LandmarkEstimator`: tracks over a keyframe window, refined
with gtsam, give every frame the metric landmarks it sees -- also frames without a fresh
pair (stops, slow motion, turning in place). The two-view stage
(:class:`~vio_depth.pipeline.points.TwoViewPoints`, ``--points sfm``) stays as the baseline.

The same error model as the two-view stage (docs/error_model.md): the frame's matches with
the window's newest keyframes test the sequence's relative poses against their stated
uncertainty (:func:`triangulation.pose_consistency`; a frame all of whose tested pairs
disagree is ``pose_inconsistent``), the inflation is estimated online, and the points carry
their depth sensitivities to the relative pose with the longest-baseline keyframe the frame
was matched with: the window's scale comes from the poses, so their error moves every
landmark of the frame together.
"""

from __future__ import annotations

import numpy as np

from matchers import Features, Matcher
from triangulation import ConsistencySettings, PoseInflation, depth_pose_jacobian, pose_consistency
from vio_core.geometry import relative_transform

from ..frame import Frame
from ..landmarks import POINTS_WINDOW_BACKEND, LandmarkEstimator, LandmarkSettings, ProcessWindow, WindowBackendSettings
from ..poses import FramePose, FrameTwist, PoseUncertainty
from ..rescale import shared_depth_errors
from .result import LandmarkInfo, PointsOutcome
from .status import FrameStatus


class LandmarkPointsStage:
    """Landmark points for a stream of frames (one instance per stream).

    Args:
        matcher: extracts and matches features.
        settings: :class:`~vio_depth.landmarks.LandmarkSettings` with a resolved pose prior.
        uncertainty: the stated uncertainty of the sequence's relative poses
            (:class:`~vio_depth.poses.PoseUncertainty`; exact: no test, no shared error).
        consistency: the test of the poses against the matches and the online inflation.
        backend: a :class:`~vio_depth.landmarks.ProcessWindow` to keep the window in, or None:
            in this process. With one, ``backend_settings`` say when a keyframe's update is
            taken over (:class:`~vio_depth.landmarks.WindowBackendSettings`; the frames between
            its submission and then are answered from the window as it was: the pose priors are
            the sequence's, so the worker needs no motion source); the window's second keyframe
            is inserted as inline, so that the frames after it have landmarks at once.
        backend_settings: see ``backend``.

    Frames are numbered by their position in the stream (not their sequence index), so the
    offline backward pass, which feeds frames in reverse, is a stream like any other.
    """

    def __init__(self, matcher: Matcher, settings: LandmarkSettings, uncertainty: PoseUncertainty = PoseUncertainty(),
                 consistency: ConsistencySettings = ConsistencySettings(), backend: ProcessWindow | None = None,
                 backend_settings: WindowBackendSettings = POINTS_WINDOW_BACKEND):
        self.matcher = matcher
        #: the worker process the window is kept in (None: this process); its builder stops it
        self.worker = backend
        self.estimator = LandmarkEstimator(settings, matcher, None, backend, backend_settings, start_inline=True)
        self.uncertainty = uncertainty
        self.consistency = consistency
        self.inflation = PoseInflation(consistency)
        self._twists = FrameTwist()
        self._count = 0

    def process(self, frame: Frame, features: Features, frame_pose: FramePose | None = None) -> PointsOutcome:
        """The landmarks ``frame`` sees (its ``features`` were just extracted). ``frame_pose``
        (a tracking pose source's) is not used: the window takes the sequence's poses as priors."""
        if frame.T_w_c is None:
            return PointsOutcome(FrameStatus.NO_POSE, "the landmark window needs the frame's pose (a prior)")
        frame_id = self._count
        self._twists.observe(frame_id, frame.timestamp, frame.T_w_c)
        out = self.estimator.process(frame_id, frame.timestamp, frame.camera, frame.T_w_c, features)
        self._count += 1
        pts = out.points
        update = out.update
        inconsistent = self._test(frame_id, frame, features, out.frame_matches)
        info = LandmarkInfo(
            keyframe=out.keyframe, keyframe_reason=out.keyframe_reason, matches=out.matches,
            associated=int(pts.associated), pose_refined=bool(pts.pose_refined),
            window_keyframes=len(self.estimator.window.keyframe_ids),
            window_residual_px=None if update is None else float(update.median_residual_px),
            pose_shift_sigmas=None if update is None else float(update.pose_shift_sigmas),
        )
        inflation = None if self.uncertainty.exact else self.inflation.value
        if inconsistent:
            return PointsOutcome(FrameStatus.POSE_INCONSISTENT, inconsistent, landmarks=info, T_w_c=pts.T_w_c,
                                 pose_inflation=inflation)
        if len(pts) == 0:
            return PointsOutcome(FrameStatus.TOO_FEW_POINTS, pts.reason or "no landmark seen", landmarks=info,
                                 T_w_c=pts.T_w_c, pose_inflation=inflation)
        return PointsOutcome(FrameStatus.OK, pts.reason, uv=pts.uv, depth=pts.depth, sigma=pts.sigma_depth,
                             landmarks=info, T_w_c=pts.T_w_c,
                             depth_shared=self._shared(frame_id, frame, pts, out.frame_matches),
                             pose_inflation=inflation)

    def _covariance(self, kf_id: int, frame_id: int, T_kf_cur) -> np.ndarray:
        cov = self.uncertainty.relative_covariance(T_kf_cur, self._twists.twist(kf_id), self._twists.twist(frame_id))
        return self.inflation.value**2 * cov

    def _test(self, frame_id: int, frame: Frame, features: Features, frame_matches) -> str:
        """Test the frame's relative poses with the keyframes it was matched with; the reason
        when every tested pair disagrees beyond the (inflated) stated uncertainty, else ""."""
        if self.uncertainty.exact:
            return ""
        window = self.estimator.window
        refused = []
        tested = 0
        for m in frame_matches:
            kf_features = self.estimator.keyframe_features(m.keyframe)
            if kf_features is None or m.keyframe == frame_id or m.keyframe not in window.keyframe_ids:
                continue
            info = window.keyframe(m.keyframe)
            if info.T_w_c is None:
                continue
            T_kf_cur = relative_transform(info.T_w_c, frame.T_w_c)
            check = pose_consistency(features.keypoints[m.idx_frame], kf_features.keypoints[m.idx_keyframe],
                                     frame.camera, info.camera, T_kf_cur,
                                     self.uncertainty.relative_covariance(T_kf_cur, self._twists.twist(m.keyframe),
                                                                          self._twists.twist(frame_id)),
                                     self.consistency, self.inflation.value)
            if not check.tested:
                continue
            tested += 1
            self.inflation.update(check)
            if check.chi2 > self.consistency.threshold(check.dof):
                refused.append(f"keyframe {m.keyframe}: {check.describe()}")
        if tested and len(refused) == tested:
            return ("the images disagree with the poses beyond their stated uncertainty (inflation "
                    f"x{self.inflation.value:.2g}): " + "; ".join(refused))
        return ""

    def _shared(self, frame_id: int, frame: Frame, pts, frame_matches) -> np.ndarray | None:
        """(N, 6): the points' sensitivities to the relative pose with the keyframe of the
        longest baseline among those the frame was matched with (the newest of the window,
        whose landmarks it sees; their depths rest on those keyframes' relative poses), or
        None (exact poses)."""
        if self.uncertainty.exact:
            return None
        window = self.estimator.window
        best, longest = None, -1.0
        for k in [m.keyframe for m in frame_matches] or window.keyframe_ids:
            if k == frame_id or k not in window.keyframe_ids:
                continue
            info = window.keyframe(k)
            if info.T_w_c is None:
                continue
            T = relative_transform(info.T_w_c, frame.T_w_c)
            if np.linalg.norm(T[:3, 3]) > longest:
                best, longest = (k, info, T), float(np.linalg.norm(T[:3, 3]))
        if best is None:
            return np.zeros((len(pts), 6))
        k, info, T = best
        J = depth_pose_jacobian(pts.uv, pts.depth, frame.camera, info.camera, T)
        return shared_depth_errors(J, self._covariance(k, frame_id, T))
