"""Re-triangulating only the tracks that changed: :func:`reusable_tracks`, :func:`merge_points`,
and the window's triangulation built on them, :func:`triangulate_window`.

The window triangulates its tracks before every refinement and again after it. A track
whose observations are exactly those of an earlier triangulation (same keyframes, same
keypoints) and that the caller does not need fresh keeps that result: only the tracks a new
keyframe extended, merged or split, the tracks that lost an observation to marginalisation
or outlier rejection, and the ones the caller asks for are triangulated again. Rows of
:class:`~triangulation.multiview.MultiviewPoints` (track-level and observation-level) are
carried over unchanged.

Before a refinement a caller may also keep the point of a track that only gained the new
keyframe's observation (:func:`extended_tracks`) and judge that observation against it
(:func:`gate_extensions`, the residual gate of the prediction) -- the refinement and the
triangulation after it see the track whole either way. With KLT tracks almost every track of
a keyframe is such a one, and the odometry's window in a worker (``--poses vio``) spends a
fifth less on a keyframe (docs/benchmarks.md "The worker's keyframe update, 2026-12-07 (late)").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from triangulation.batched import inv2, quad2
from triangulation.jacobians import image_pose_jacobian, point_jacobian, sandwich2
from triangulation.multiview import MultiviewPoints, MultiviewSettings, TrackStatus, depth_in_view, triangulate_tracks
from vio_core.checks import check_array

from .tracks import Observations, TrackTable

# (frame, keypoint) packed into one int64: keypoint indices stay below 2^24
_KP_BITS = 24


def _obs_key(obs: Observations) -> np.ndarray:
    return (obs.frame.astype(np.int64) << _KP_BITS) | obs.keypoint.astype(np.int64)


def _compare(obs: Observations, old_obs: Observations):
    """Per row of ``obs``: whether ``old_obs`` has it (same keyframe, keypoint and track); per
    track of ``obs`` (``np.unique`` order, ``t`` the row's): its rows now, those of them in
    ``old_obs``, and its rows in ``old_obs`` (-1: not there)."""
    key, old_key = _obs_key(obs), _obs_key(old_obs)
    order = np.argsort(old_key)
    pos = np.clip(np.searchsorted(old_key[order], key), 0, len(order) - 1)
    j = order[pos]
    same = (old_key[j] == key) & (old_obs.track[j] == obs.track)
    ids, t = np.unique(obs.track, return_inverse=True)
    n_new = np.bincount(t, minlength=len(ids))
    n_same = np.bincount(t, weights=same.astype(float), minlength=len(ids)).astype(np.int64)
    old_ids, old_counts = np.unique(old_obs.track, return_counts=True)
    r = np.clip(np.searchsorted(old_ids, ids), 0, len(old_ids) - 1)
    n_old = np.where(old_ids[r] == ids, old_counts[r], -1)
    return same, ids, t, n_new, n_same, n_old


def reusable_tracks(obs: Observations, old_obs: Observations | None, old: MultiviewPoints | None) -> np.ndarray:
    """(M,) bool: the observations of ``obs`` whose track has exactly the same observations
    (same track id, keyframes and keypoints) in ``old_obs``, triangulated into ``old``."""
    return _reuse_and_extend(obs, old_obs, old, None)[0]


def extended_tracks(obs: Observations, old_obs: Observations | None, old: MultiviewPoints | None,
                    frame: int) -> np.ndarray:
    """(M,) bool: the observations in keyframe ``frame`` that extend a track of an earlier
    triangulation by one: the rest of the track is exactly its observations in ``old_obs``, and
    ``old`` gave it a point (VALID or UNCERTAIN)."""
    return _reuse_and_extend(obs, old_obs, old, frame)[1]


def _reuse_and_extend(obs: Observations, old_obs: Observations | None, old: MultiviewPoints | None,
                      frame: int | None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`reusable_tracks` and :func:`extended_tracks` (all False without ``frame``) from one
    comparison of the observations."""
    none = np.zeros(len(obs), bool)
    if old is None or old_obs is None or not len(obs) or not len(old_obs):
        return none, none
    same, ids, t, n_new, n_same, n_old = _compare(obs, old_obs)
    reuse = ((n_same == n_new) & (n_old == n_new))[t]
    if frame is None:
        return reuse, none
    r = np.clip(np.searchsorted(old.track_ids, ids), 0, max(len(old.track_ids) - 1, 0))
    defined = (old.track_ids[r] == ids) & np.isin(old.status[r], (TrackStatus.VALID, TrackStatus.UNCERTAIN))
    track_ok = defined & (n_same == n_old) & (n_new == n_old + 1)
    return reuse, track_ok[t] & ~same & (obs.frame == frame)


def merge_points(obs: Observations, fresh: np.ndarray, new: MultiviewPoints, old_obs: Observations,
                 old: MultiviewPoints, extended: np.ndarray | None = None,
                 extension: Extension | None = None) -> MultiviewPoints:
    """The triangulation of every observation of ``obs``: ``new`` for the rows ``fresh``
    (triangulated from ``obs`` rows ``fresh``, in order), ``old`` for the others (which
    :func:`reusable_tracks` must have allowed) -- but for the rows ``extended``, new observations
    of ``old``'s tracks judged by :func:`gate_extensions` (``extension``, in row order).

    Args:
        obs: (M rows) the current observations.
        fresh: (M,) bool, the rows triangulated into ``new``.
        new: :class:`MultiviewPoints` of the rows ``fresh``.
        old_obs / old: an earlier triangulation and its observations.
        extended: (M,) bool or None, rows not in ``old_obs`` whose tracks are ``old``'s.
        extension: their :class:`Extension` (with ``extended``).

    Returns:
        :class:`MultiviewPoints`; the extended tracks' rows are ``old``'s (point, covariance,
        ``n_inliers``, status): :func:`_extend` then counts the new inliers into them.
    """
    added = np.zeros(len(obs), bool) if extended is None else extended
    kept = ~fresh & ~added
    key, old_key = _obs_key(obs.take(kept)), _obs_key(old_obs)
    order = np.argsort(old_key)
    j = order[np.searchsorted(old_key[order], key)]  # old row of each kept observation
    old_rows = np.unique(old.obs_track[j])
    track_ids = np.concatenate([new.track_ids, old.track_ids[old_rows]])
    perm = np.argsort(track_ids, kind="stable")
    rank = np.empty_like(perm)
    rank[perm] = np.arange(len(perm))

    def tracks(a_new, a_old):
        return np.concatenate([a_new, a_old[old_rows]])[perm]

    obs_track = np.empty(len(obs), np.int64)
    obs_track[fresh] = rank[new.obs_track]
    obs_track[kept] = rank[len(new.track_ids) + np.searchsorted(old_rows, old.obs_track[j])]
    obs_track[added] = np.searchsorted(track_ids[perm], obs.track[added])

    def per_obs(a_new, a_old, a_ext=None):
        out = np.empty((len(obs),) + a_new.shape[1:], a_new.dtype)
        out[fresh] = a_new
        out[kept] = a_old[j]
        if a_ext is not None:
            out[added] = a_ext
        return out

    e = extension
    return MultiviewPoints(track_ids[perm], tracks(new.points_w, old.points_w),
                           tracks(new.covariance_w, old.covariance_w), tracks(new.status, old.status),
                           tracks(new.n_inliers, old.n_inliers), tracks(new.max_angle_deg, old.max_angle_deg),
                           obs_track, per_obs(new.inlier, old.inlier, None if e is None else e.inlier),
                           per_obs(new.residual_px, old.residual_px, None if e is None else e.residual_px),
                           per_obs(new.depth, old.depth, None if e is None else e.depth),
                           per_obs(new.sigma_depth, old.sigma_depth, None if e is None else e.sigma_depth),
                           tracks(new.relative_sigma, old.relative_sigma))


@dataclass(frozen=True)
class Extension:
    """New observations judged against their tracks' earlier points (:func:`gate_extensions`);
    (K,) each, in the order of the rows given.

    Attributes:
        inlier: bool. residual_px: ideal pixels. depth: metres (camera z). sigma_depth: metres.
    """

    inlier: np.ndarray
    residual_px: np.ndarray
    depth: np.ndarray
    sigma_depth: np.ndarray


def gate_extensions(obs: Observations, rows: np.ndarray, view: np.ndarray, old: MultiviewPoints, cameras, poses,
                    covariances, settings: MultiviewSettings) -> Extension:
    """Judge new observations of tracks against their earlier points instead of triangulating
    the tracks again.

    A new observation is an inlier when it lies in front of its camera and its reprojection
    residual at its keyframe's pose is within ``max_residual_sigmas`` of the predicted
    ``S = sigma_px^2 I + J_X Sigma_X J_X^T + J_pose Sigma J_pose^T`` (pixel noise, the point's
    and the pose's uncertainty: the point was estimated without it). Its depth and sigma are
    :func:`~triangulation.multiview.depth_in_view`'s.

    Args:
        obs: the observations; ``rows`` (K,) indices of the new ones, one per track, each track
            with a point in ``old`` (an earlier :class:`MultiviewPoints`).
        view: (M,) index of each observation's keyframe into ``cameras`` (K cameras),
            ``poses`` ((K, 4, 4) camera-to-world, metres) and ``covariances`` ((K, 6, 6) rad / m).
        settings: the triangulation's :class:`MultiviewSettings` (pixel sigma, the gate).

    Returns:
        :class:`Extension`.
    """
    rows = check_array("rows", rows, (None,), dtype="int")
    poses = check_array("poses", poses, (None, 4, 4))
    covariances = check_array("covariances", covariances, (len(poses), 6, 6))
    s = settings
    r_old = np.searchsorted(old.track_ids, obs.track[rows])  # each new observation's track in old
    P, C = old.points_w[r_old], np.nan_to_num(old.covariance_w[r_old])
    v = view[rows]
    R_cw = np.transpose(poses[v, :3, :3], (0, 2, 1))
    p_c = np.einsum("nij,nj->ni", R_cw, P - poses[v, :3, 3])
    n = len(rows)
    ideal = np.empty((n, 2))
    fx, fy, cx, cy = (np.empty(n) for _ in range(4))
    depth, sigma = np.empty(n), np.empty(n)
    for k in np.unique(v):
        sel = v == k
        cam = cameras[k]
        ideal[sel] = cam.undistort_points(obs.uv[rows[sel]])
        fx[sel], fy[sel], cx[sel], cy[sel] = cam.fx, cam.fy, cam.cx, cam.cy
        depth[sel], sigma[sel] = depth_in_view(P[sel], C[sel], poses[k], covariances[k])
    front = p_c[:, 2] > 0
    pc = np.where(front[:, None], p_c, 1.0)  # finite Jacobians: a point behind is an outlier anyway
    r = np.column_stack([fx * pc[:, 0] / pc[:, 2] + cx, fy * pc[:, 1] / pc[:, 2] + cy]) - ideal
    S = sandwich2(point_jacobian(pc, fx, fy, R_cw), C) + sandwich2(image_pose_jacobian(pc, fx, fy), covariances[v])
    S[:, 0, 0] += s.pixel_sigma_px**2
    S[:, 1, 1] += s.pixel_sigma_px**2
    inlier = front & (quad2(r, inv2(S)) <= s.max_residual_sigmas**2)
    return Extension(inlier, np.where(front, np.linalg.norm(r, axis=1), np.inf), depth, sigma)


def _extend(mv: MultiviewPoints, obs: Observations, rows: np.ndarray, ext: Extension,
            settings: MultiviewSettings) -> None:
    """Count the inliers of ``ext`` (observations ``rows`` of ``obs``, already in ``mv``'s rows)
    into their tracks, in place: ``n_inliers``, ``relative_sigma``, and a VALID track turns
    DEPTH_RANGE or UNCERTAIN as :func:`~triangulation.multiview.triangulate_tracks` marks it."""
    s = settings
    tr = mv.obs_track[rows][ext.inlier]
    d, sd = ext.depth[ext.inlier], ext.sigma_depth[ext.inlier]
    np.add.at(mv.n_inliers, tr, 1)
    rel = sd / np.where(d > 0, d, np.nan)
    np.maximum.at(mv.relative_sigma, tr, np.nan_to_num(rel, nan=np.inf))
    valid = mv.status[tr] == TrackStatus.VALID
    out_of_range = (d < s.min_depth_m) | (d > s.max_depth_m)
    mv.status[tr[valid & out_of_range]] = TrackStatus.DEPTH_RANGE
    mv.status[tr[valid & ~out_of_range & ~(rel <= s.max_relative_sigma)]] = TrackStatus.UNCERTAIN


def triangulate_window(tracks: TrackTable, frame_ids, cameras, poses, covariances, settings: MultiviewSettings,
                       min_length: int, previous=None, fresh_frames=(), gate_frame: int | None = None
                       ) -> tuple[Observations, MultiviewPoints]:
    """Triangulate a window's tracks of ``min_length`` observations or more.

    Args:
        tracks: the window's :class:`~.tracks.TrackTable`.
        frame_ids: (K,) its keyframe ids, oldest first.
        cameras: their K cameras.
        poses: (K, 4, 4) their camera-to-world poses, metres.
        covariances: (K, 6, 6) their pose covariances relative to a reference keyframe
            (rotation rad, translation m).
        settings: :class:`~triangulation.multiview.MultiviewSettings`.
        min_length: fewest observations of a triangulated track.
        previous: ``(observations, MultiviewPoints)`` of an earlier triangulation, or None. Its
            result is kept for the tracks whose observations did not change since and that
            have no observation in a keyframe of ``fresh_frames``; the others are
            triangulated at ``poses`` and ``covariances``.
        fresh_frames: keyframe ids whose tracks are always triangulated again.
        gate_frame: a keyframe id, or None. With ``previous``, a track that only gained an
            observation in this keyframe since (and had a point) keeps its point, the new
            observation judged against it (:func:`gate_extensions`), instead of being
            triangulated again -- whatever ``fresh_frames`` says.

    Returns:
        ``(observations, MultiviewPoints)``: the observations triangulated and the result.
    """
    ids = [int(f) for f in frame_ids]
    T = check_array("poses", poses, (len(ids), 4, 4))
    C = check_array("covariances", covariances, (len(ids), 6, 6))
    obs = tracks.observations(min_length=min_length)
    view = np.searchsorted(np.array(ids), obs.frame) if len(obs) else np.zeros(0, np.int64)
    fresh = np.ones(len(obs), bool)
    extended = extension = None
    if previous is not None:
        reuse, extended = _reuse_and_extend(obs, *previous, None if gate_frame is None else int(gate_frame))
        fresh = ~reuse
        fresh |= np.isin(obs.track, obs.track[np.isin(obs.frame, list(fresh_frames))])
        if gate_frame is not None:
            fresh &= ~np.isin(obs.track, obs.track[extended])
            extension = gate_extensions(obs, np.nonzero(extended)[0], view, previous[1], list(cameras), T, C, settings)
    res = triangulate_tracks(obs.track[fresh], view[fresh], obs.uv[fresh], list(cameras), T, settings, C)
    if not fresh.all():
        res = merge_points(obs, fresh, res, *previous, extended, extension)
        if extension is not None:
            _extend(res, obs, np.nonzero(extended)[0], extension, settings)
    return obs, res
