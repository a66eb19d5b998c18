"""The points stage that reads the odometry's own landmarks (``--points vio``).

With ``--poses vio`` the odometry (:mod:`vio_depth.vio`) already refines metric landmarks
with covariances in its gtsam window for every frame it tracks, and poses the frame
against them. :class:`VioPoints` hands those landmarks to the rescaler as they are: the
frame's keypoints associated with landmarks, their depths in the frame and each depth's
1-sigma -- no second matching or triangulation of the frame (the two-view stage,
``--points sfm``, matches it again with keyframes and triangulates pairs from the
odometry's relative poses).

The error model (docs/error_model.md):

* **per point**: ``sigma`` is the depth's 1-sigma from the landmark's marginal covariance
  (a multi-view triangulation at the refined keyframe poses with their covariances relative
  to the newest keyframe) and, for a frame that is not a keyframe, the covariance of the
  frame's pose refined against the landmarks (:func:`triangulation.multiview.depth_in_view`).
  It already holds the odometry's pose uncertainty, but as if it were independent per point.
* **shared** (``depth_shared``): the part of that error every point of the frame has in
  common, which no number of points averages away, so that ``predicted_error`` and the
  refusal (``max_fit_error``) stay honest: six columns for the frame's pose relative to
  the window's newest keyframe (``dz/dxi L`` with ``L L^T`` its covariance; zero for the
  newest keyframe itself) and one for the window's metric scale (``z * s``, ``s`` the
  relative 1-sigma of the span between the window's oldest and newest keyframe: an IMU
  scale error moves every landmark depth together). The landmarks' correlation through the
  keyframes' other relative-pose directions is not modelled (as for ``--points landmarks``).
* No consistency test of the pose against the matches (``pose_inflation`` is None): the
  frame's pose was refined against these same landmarks, so the test would be circular.

A frame without landmarks -- initialising, at rest (``still``: the window is not
updated), lost, or forgotten -- gets ``too_few_points`` / ``no_pose`` with the reason; the
rescaler's fallbacks (previous fit, within ``max_fit_error``) may still give it depth.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from matchers import Features, Matcher
from triangulation.jacobians import pose_jacobian
from vio_core.camera import Camera
from vio_core.errors import SettingsError

from ..frame import Frame
from ..landmarks import LandmarkPoints
from ..poses import FramePose, PoseSource, PoseStatus
from ..rescale import shared_depth_errors
from ..vio.landmark_feed import OdometryLandmarks
from .result import LandmarkInfo, PointsOutcome
from .status import FrameStatus


@runtime_checkable
class OdometryLandmarkSource(Protocol):
    """A pose source that keeps the landmarks its odometry saw in each frame
    (:class:`~vio_depth.vio.VioPoseSource`)."""

    name: str

    def frame_landmarks(self, frame: Frame) -> OdometryLandmarks | None:
        """The landmarks the odometry saw in ``frame``, or None."""


class VioPoints:
    """``--points vio``: the odometry's landmarks of each frame (module docstring).

    Args:
        source: the odometry (an :class:`OdometryLandmarkSource`).
        matcher: the pipeline's matcher (the odometry's: it extracts every frame's
            features; this stage matches nothing).

    Raises:
        SettingsError: ``source`` keeps no landmarks (any pose source but ``vio``).
    """

    def __init__(self, source: PoseSource, matcher: Matcher | None):
        if not isinstance(source, OdometryLandmarkSource):
            raise SettingsError(f"--points vio takes the odometry's own landmarks (--poses vio); the "
                                f"{source.name!r} pose source has none: use --points sfm or --points landmarks")
        self.source = source
        self.matcher = matcher

    def process(self, frame: Frame, features: Features | None = None,
                frame_pose: FramePose | None = None) -> PointsOutcome:
        """The landmarks the odometry saw in ``frame``; ``frame_pose`` is the odometry's pose
        of it (a frame without one gets ``no_pose``). ``features`` are not used."""
        if frame_pose is None or not frame_pose.ok:
            reason = "the odometry has no pose for this frame" if frame_pose is None else (
                frame_pose.reason or "the pose source has no pose for this frame")
            return PointsOutcome(FrameStatus.NO_POSE, reason)
        seen = self.source.frame_landmarks(frame)
        if seen is None:
            why = ("at rest: the odometry's landmark window was not updated for this frame"
                   if frame_pose.status == PoseStatus.STILL else "the odometry kept no landmarks for this frame")
            return PointsOutcome(FrameStatus.TOO_FEW_POINTS, f"{why} ({frame_pose.status})")
        pts = seen.points
        update = seen.update
        info = LandmarkInfo(keyframe=seen.keyframe, keyframe_reason=seen.keyframe_reason, matches=seen.matches,
                            associated=int(pts.associated), pose_refined=bool(pts.pose_refined),
                            window_keyframes=seen.window_keyframes,
                            window_residual_px=None if update is None else float(update.median_residual_px))
        if len(pts) == 0:
            return PointsOutcome(FrameStatus.TOO_FEW_POINTS, pts.reason or "no landmark seen", landmarks=info,
                                 T_w_c=pts.T_w_c)
        if not np.isfinite(seen.scale_sigma):
            return PointsOutcome(FrameStatus.TOO_FEW_POINTS, "the odometry's window had no metric scale yet",
                                 landmarks=info, T_w_c=pts.T_w_c)
        return PointsOutcome(FrameStatus.OK, pts.reason, uv=pts.uv, depth=pts.depth, sigma=pts.sigma_depth,
                             landmarks=info, T_w_c=pts.T_w_c, depth_shared=shared_columns(frame.camera, pts, seen.scale_sigma))


def shared_columns(camera: Camera, points: LandmarkPoints, scale_sigma: float) -> np.ndarray:
    """(N, 7) metres: the depth errors all of a frame's landmark points share (module
    docstring): six columns for the frame's pose relative to the window's newest keyframe
    (``points.covariance``, (6, 6) rad / m; none when it is None), one for the window's
    metric scale (``scale_sigma``: relative 1-sigma).

    Args:
        camera: the frame's camera.
        points: the frame's :class:`~vio_depth.landmarks.LandmarkPoints` (``uv`` (N, 2) raw
            pixels, ``depth`` (N,) metres).
        scale_sigma: relative 1-sigma of the window's metric scale (finite, >= 0).
    """
    pts = points
    z = np.asarray(pts.depth, np.float64)
    ideal = camera.undistort_points(pts.uv)
    rays = np.column_stack([ideal, np.ones(len(z))]) @ np.linalg.inv(camera.K).T
    p_c = rays / rays[:, 2:3] * z[:, None]  # (N, 3) the points in the camera, metres
    out = np.zeros((len(z), 7))
    if pts.covariance is not None:
        out[:, :6] = shared_depth_errors(pose_jacobian(p_c)[:, 2, :], pts.covariance)
    out[:, 6] = z * scale_sigma
    return out
