"""The window's per-frame query: the metric landmark points a frame sees (:func:`query_frame`).

A keyframe of the window reads its landmarks directly. Another frame associates its
keypoints with tracks through its matches; its pose prior is corrected like its newest
matched keyframe's (unless the motion source gives the priors itself) and then refined
against the landmarks (:func:`~vio_depth.landmarks.resection.refine_pose`), and the
landmarks' depths follow with a first-order sigma
(:func:`triangulation.multiview.depth_in_view`).
"""

from __future__ import annotations

import numpy as np

from triangulation.multiview import depth_in_view
from vio_core.camera import Camera
from vio_core.checks import check_array, check_transform
from vio_core.errors import InputError
from vio_core.geometry import invert_transform

from .covariance import prior_covariance as relative_prior_covariance
from .resection import refine_pose
from .types import LandmarkPoints


def frame_prior(window, T_w_c, matches=(), prior_covariance=None) -> tuple[np.ndarray, np.ndarray]:
    """A frame's pose prior in the window, before the landmarks refine it.

    ``T_w_c`` (4, 4) camera-to-world, metres, is corrected like the newest keyframe of
    ``matches`` (:class:`FrameMatches` with keyframes of the window; none: the newest keyframe)
    was by the window -- unless the motion source gives the priors itself (keyframes without a
    prior) -- and is uncertain by that keyframe's covariance relative to the window's reference
    plus ``prior_covariance`` (6, 6) (None: the settings' relative pose prior over the step).

    Returns:
        ``(T_w_c (4, 4), covariance (6, 6) relative to the window's reference keyframe)``.
    """
    w = window
    ids = w.keyframe_ids
    T_prior = check_transform("T_w_c", T_w_c)
    ref = max((m.keyframe for m in matches if m.keyframe in ids), default=ids[-1])
    ref_info = w.keyframe(ref)
    T0 = T_prior if ref_info.T_w_c is None else w.pose(ref) @ invert_transform(ref_info.T_w_c) @ T_prior
    step = float(np.linalg.norm((invert_transform(T0) @ w.pose(ref))[:3, 3]))
    motion_cov = relative_prior_covariance(w.settings.pose_prior, step) if prior_covariance is None else check_array(
        "prior_covariance", prior_covariance, (6, 6), finite=True)
    return T0, w.relative_covariances()[ids.index(ref)] + motion_cov


def query_frame(window, camera: Camera, T_w_c, keypoints, matches=(), frame_id: int | None = None,
                prior_covariance=None) -> LandmarkPoints:
    """Metric landmark points seen by a frame (module docstring).

    ``window`` is the :class:`~.window.LandmarkWindow` (read through its public methods
    only); the other arguments as :meth:`~.window.LandmarkWindow.query`.
    """
    kp = check_array("keypoints", keypoints, (None, 2))
    w = window
    lm = w.landmarks()
    ids = w.keyframe_ids
    if not ids:
        return LandmarkPoints.empty("no keyframe in the window yet", T_w_c)
    if frame_id is not None and frame_id in ids:
        rel_cov = w.relative_covariances()[ids.index(frame_id)]
        obs = w.observations()
        sel = np.zeros(0, bool) if lm is None else (obs.frame == frame_id) & lm.inlier & lm.valid[lm.obs_track]
        if not sel.any():
            out = LandmarkPoints.empty("no landmark of the window qualifies in this keyframe", w.pose(frame_id))
            return LandmarkPoints(**{**out.__dict__, "covariance": rel_cov})
        return LandmarkPoints(obs.uv[sel], lm.depth[sel], lm.sigma_depth[sel], obs.track[sel],
                              w.pose(frame_id), int(sel.sum()), True, "", rel_cov, obs.keypoint[sel])
    if T_w_c is None:
        raise InputError("landmarks: a frame that is not a keyframe of the window needs a pose prior")
    matches = [m for m in matches if m.keyframe in ids]
    T0, prior_cov = frame_prior(w, T_w_c, matches, prior_covariance)
    s = w.settings

    def empty(reason):
        out = LandmarkPoints.empty(reason, T0)
        return LandmarkPoints(**{**out.__dict__, "covariance": prior_cov})

    if lm is None or len(lm.track_ids) == 0:
        return empty("the window has no landmark yet")
    tracks = w.tracks.associate(matches, len(kp))
    rows = np.clip(np.searchsorted(lm.track_ids, tracks), 0, len(lm.track_ids) - 1)
    has = (tracks >= 0) & (lm.track_ids[rows] == tracks) & lm.valid[rows]
    n_assoc = int(has.sum())
    if n_assoc == 0:
        return empty("no keypoint of this frame is associated with a landmark")
    kp_idx = np.nonzero(has)[0]
    r = rows[kp_idx]
    P, C = lm.points_w[r], lm.covariance_w[r]
    T, cov, refined = T0, prior_cov, False
    if n_assoc >= s.min_query_points and s.query_max_iterations > 0:
        ref_pose = refine_pose(P, C, kp[kp_idx], camera, T0, prior_cov, s.multiview.pixel_sigma_px,
                               s.huber_sigmas, s.query_max_iterations)
        T, cov, refined = ref_pose.T_w_c, ref_pose.covariance, True
        inl = ref_pose.inlier & (ref_pose.whitened_residual <= s.multiview.max_residual_sigmas)
    else:
        inl = np.ones(len(kp_idx), bool)
    depth, sigma = depth_in_view(P, C, T, cov)
    ok = inl & (depth > 0) & (sigma <= s.multiview.max_relative_sigma * np.maximum(depth, 1e-12))
    reason = "" if ok.any() else "no associated landmark passed the residual and uncertainty gates"
    if not refined:
        reason = (reason + "; " if reason else "") + f"pose not refined ({n_assoc} landmarks < {s.min_query_points})"
    return LandmarkPoints(kp[kp_idx][ok], depth[ok], sigma[ok], tracks[kp_idx][ok], T, n_assoc, refined, reason,
                          cov, kp_idx[ok])
