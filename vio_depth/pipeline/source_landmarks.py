"""``--points landmarks`` with a pose source that gives relative poses with a covariance
(``--poses imu``, ``--poses vio``): the source's motion as factors of the landmark window.

The ``gt`` source hands the window the sequence's absolute poses as priors, with the stated
uncertainty of the sequence's kind (:class:`~vio_depth.pipeline.LandmarkPointsStage`). The
``imu`` and ``vio`` sources have no poses to give as absolute priors -- they state relative
poses between frames with their covariance (:class:`~vio_depth.poses.RelativePose`). Here
they enter the window the way the odometry's IMU factors do
(:class:`~vio_depth.landmarks.MotionFactorSource`): :class:`RelativePoseFactors` puts a
``BetweenFactorPose3`` between consecutive keyframes carrying the source's relative pose
with **its stated covariance**, and anchors the first keyframe at the origin (the window's
world is the first keyframe's camera: the gauge; no absolute prior is claimed). A frame's
pose prior is the newest keyframe's refined pose composed with the source's relative pose,
uncertain by that pose's covariance; the images refine it against the landmarks.

The points carry the landmarks' depth sigma (from their marginal covariances) and the
errors they share (:func:`~vio_depth.pipeline.vio_points.shared_columns`): the frame's
pose relative to the newest keyframe, and the window's scale -- the relative 1-sigma of the
span between its oldest and newest keyframe, which the source's relative translations fix.
A frame the source cannot relate to the newest keyframe gets ``no_pose`` with the source's
reason.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from matchers import Features, Matcher
from vio_core.checks import check_array
from vio_core.errors import InputError, NumericalError

from ..frame import Frame
from ..landmarks import KeyframeInput, LandmarkEstimator, LandmarkSettings, MotionFactors
from ..poses import FramePose, PoseSource
from ..vio import PoseHistory
from .result import LandmarkInfo, PointsOutcome
from .status import FrameStatus
from .vio_points import shared_columns

#: 1-sigma (rotation rad x 3, translation m x 3) of the first keyframe's anchor. Loose: it only
#: fixes the gauge. The window reads its poses' uncertainty relative to the newest keyframe
#: (a conditional covariance, which cannot exceed the marginal): a tight anchor would make the
#: oldest keyframe look certain relative to the newest, whatever the source's covariance says.
_ANCHOR_SIGMAS = np.array([0.01] * 3 + [0.1] * 3)
#: 1-sigma (rad, m) of a relative pose whose source states no covariance (exact), and the
#: floor of a stated covariance's eigenvalues (a nearly singular one makes the window's
#: linear systems indeterminate; 10 micrometres / radians is far below any source's error)
_EXACT_SIGMA = 1e-5


class RelativePoseFactors:
    """A :class:`~vio_depth.landmarks.MotionFactorSource` from a pose source's relative poses.

    Args:
        source: gives ``relative(keyframe, current)`` with a (6, 6) covariance (right
            perturbation in the current camera, rotation rad first, then metres).
        frames: frame id -> :class:`~vio_depth.frame.Frame` of the window's keyframes (the
            stage keeps it up to date).
    """

    #: the keyframes' initial poses come from here (they carry no prior pose); the first
    #: keyframe is anchored here too (at the origin)
    provides_poses = True
    #: a chain of relative factors: a marginalised keyframe's factors become a linear marginal
    #: factor (dropping them would free the window)
    keep_marginals = True

    def __init__(self, source: PoseSource, frames: dict[int, Frame]):
        self.source = source
        self.frames = frames

    def extra_keys(self, frame_id: int) -> list[int]:
        return []

    def factors(self, previous: KeyframeInput | None, current: KeyframeInput, estimate,
                initial=None) -> MotionFactors:
        """A gauge prior on the first keyframe, else the source's relative pose between
        ``previous`` and ``current`` as a ``BetweenFactorPose3`` with its covariance; no
        relative pose: :meth:`MotionFactors.failed` (the window refuses the keyframe).
        ``initial`` is not used (the source predicts every keyframe)."""
        import gtsam  # optional heavy dependency, imported where it is used
        from gtsam.symbol_shorthand import X

        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        key = X(current.frame_id)
        if previous is None:
            noise = gtsam.noiseModel.Diagonal.Sigmas(_ANCHOR_SIGMAS)
            graph.add(gtsam.PriorFactorPose3(key, gtsam.Pose3(), noise))
            values.insert(key, gtsam.Pose3())
            return MotionFactors(graph, values)
        rel = self.source.relative(self.frames[previous.frame_id], self.frames[current.frame_id])
        if not rel.ok:
            return MotionFactors.failed(f"no relative pose between keyframes: {rel.reason}")
        cov = _usable_covariance(rel.covariance)
        T = gtsam.Pose3(rel.T_kf_cur)
        graph.add(gtsam.BetweenFactorPose3(X(previous.frame_id), key, T, gtsam.noiseModel.Gaussian.Covariance(cov)))
        values.insert(key, estimate.atPose3(X(previous.frame_id)).compose(T))
        return MotionFactors(graph, values)

    def after_marginalisation(self, oldest: int, estimate):
        """No factors: the marginal factor kept by the window holds the gauge."""
        import gtsam  # optional heavy dependency, imported where it is used

        return gtsam.NonlinearFactorGraph()


def _usable_covariance(covariance) -> np.ndarray:
    """(6, 6) symmetric positive definite: the stated covariance with its eigenvalues floored
    at ``_EXACT_SIGMA**2``, or that floor when the source states none."""
    if covariance is None:
        return (_EXACT_SIGMA ** 2) * np.eye(6)
    C = check_array("covariance", covariance, (6, 6), finite=True)
    lam, V = np.linalg.eigh(0.5 * (C + C.T))
    C = (V * np.maximum(lam, _EXACT_SIGMA ** 2)) @ V.T
    return 0.5 * (C + C.T)


class SourceLandmarkPoints:
    """Landmark points with the priors of a relative pose source (module docstring).

    Args:
        matcher: extracts and matches features.
        source: the pose source (``imu``, ``vio``...).
        settings: the landmark window; its pose prior (None: the ``imu`` preset) has
            ``absolute_on_every_keyframe`` turned off (the source's factors carry the motion).

    Frames are numbered by their position in the stream, as in
    :class:`~vio_depth.pipeline.LandmarkPointsStage`.
    """

    def __init__(self, matcher: Matcher, source: PoseSource, settings: LandmarkSettings):
        settings = settings.resolved("imu")
        settings = replace(settings, pose_prior=replace(settings.pose_prior, absolute_on_every_keyframe=False))
        self.matcher = matcher
        self.source = source
        self._frames: dict[int, Frame] = {}
        self.estimator = LandmarkEstimator(settings, matcher, RelativePoseFactors(source, self._frames))
        self._count = 0

    def process(self, frame: Frame, features: Features, frame_pose: FramePose | None = None) -> PointsOutcome:
        """The landmarks ``frame`` sees; ``frame_pose`` (a tracking source's) gives ``no_pose``
        when it is not ok, and is otherwise not used (its relative poses are)."""
        if frame_pose is not None and not frame_pose.ok:
            return PointsOutcome(FrameStatus.NO_POSE, frame_pose.reason or "the pose source has no pose for this frame")
        window = self.estimator.window
        frame_id = self._count
        T_prior, C_prior = np.eye(4), None
        if window.keyframe_ids:
            newest = window.keyframe_ids[-1]
            rel = self.source.relative(self._frames[newest], frame)
            if not rel.ok:
                return PointsOutcome(FrameStatus.NO_POSE, rel.reason or "no relative pose to the newest keyframe")
            T_prior, C_prior = window.pose(newest) @ rel.T_kf_cur, _usable_covariance(rel.covariance)
        self._frames[frame_id] = frame
        try:
            out = self.estimator.process(frame_id, frame.timestamp, frame.camera, T_prior, features,
                                         prior_covariance=C_prior)
        except (InputError, NumericalError, RuntimeError) as exc:  # the window is unusable: start a new one
            self.estimator.reset()
            self._frames.clear()
            return PointsOutcome(FrameStatus.NO_POSE, f"the landmark window was restarted: {exc}")
        finally:
            self._count += 1
        for k in [k for k in self._frames if k not in window.keyframe_ids and k != frame_id]:
            del self._frames[k]
        if not out.keyframe:
            self._frames.pop(frame_id, None)
        pts, update = out.points, out.update
        info = LandmarkInfo(keyframe=out.keyframe, keyframe_reason=out.keyframe_reason, matches=out.matches,
                            associated=int(pts.associated), pose_refined=bool(pts.pose_refined),
                            window_keyframes=len(window.keyframe_ids),
                            window_residual_px=None if update is None else float(update.median_residual_px))
        if len(pts) == 0:
            return PointsOutcome(FrameStatus.TOO_FEW_POINTS, pts.reason or "no landmark seen", landmarks=info,
                                 T_w_c=pts.T_w_c)
        return PointsOutcome(FrameStatus.OK, pts.reason, uv=pts.uv, depth=pts.depth, sigma=pts.sigma_depth,
                             landmarks=info, T_w_c=pts.T_w_c,
                             depth_shared=shared_columns(frame.camera, pts, self._scale_sigma()))

    def _scale_sigma(self) -> float:
        """Relative 1-sigma of the span between the window's oldest and newest keyframe."""
        w = self.estimator.window
        ids = w.keyframe_ids
        if len(ids) < 2:
            return 0.0
        sigma, n = PoseHistory.span_sigma(w.pose(ids[0]), w.pose(ids[-1]), w.joint_covariance([ids[0], ids[-1]]), 0, 1)
        return sigma / n if n > 0 else 0.0
