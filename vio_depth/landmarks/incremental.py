"""Re-triangulating only the tracks that changed: :func:`reusable_tracks`, :func:`merge_points`,
and the window's triangulation built on them, :func:`triangulate_window`.

The window triangulates its tracks before every refinement and again after it. A track
whose observations are exactly those of an earlier triangulation (same keyframes, same
keypoints) and that the caller does not need fresh keeps that result: only the tracks a new
keyframe extended, merged or split, the tracks that lost an observation to marginalisation
or outlier rejection, and the ones the caller asks for are triangulated again. Rows of
:class:`~triangulation.multiview.MultiviewPoints` (track-level and observation-level) are
carried over unchanged.
"""

from __future__ import annotations

import numpy as np

from triangulation.multiview import MultiviewPoints, MultiviewSettings, triangulate_tracks
from vio_core.checks import check_array

from .tracks import Observations, TrackTable

# (frame, keypoint) packed into one int64: keypoint indices stay below 2^24
_KP_BITS = 24


def _obs_key(obs: Observations) -> np.ndarray:
    return (obs.frame.astype(np.int64) << _KP_BITS) | obs.keypoint.astype(np.int64)


def reusable_tracks(obs: Observations, old_obs: Observations | None, old: MultiviewPoints | None) -> np.ndarray:
    """(M,) bool: the observations of ``obs`` whose track has exactly the same observations
    (same track id, keyframes and keypoints) in ``old_obs``, triangulated into ``old``."""
    out = np.zeros(len(obs), bool)
    if old is None or old_obs is None or not len(obs) or not len(old_obs):
        return out
    key, old_key = _obs_key(obs), _obs_key(old_obs)
    order = np.argsort(old_key)
    pos = np.clip(np.searchsorted(old_key[order], key), 0, len(order) - 1)
    j = order[pos]
    same = (old_key[j] == key) & (old_obs.track[j] == obs.track)
    ids, t = np.unique(obs.track, return_inverse=True)
    n_new = np.bincount(t, minlength=len(ids))
    n_same = np.bincount(t, weights=same.astype(float), minlength=len(ids))
    old_ids, old_counts = np.unique(old_obs.track, return_counts=True)
    r = np.clip(np.searchsorted(old_ids, ids), 0, len(old_ids) - 1)
    n_old = np.where(old_ids[r] == ids, old_counts[r], -1)
    whole = (n_same == n_new) & (n_old == n_new)
    return whole[t]


def merge_points(obs: Observations, fresh: np.ndarray, new: MultiviewPoints, old_obs: Observations,
                 old: MultiviewPoints) -> MultiviewPoints:
    """The triangulation of every observation of ``obs``: ``new`` for the rows ``fresh``
    (triangulated from ``obs`` rows ``fresh``, in order), ``old`` for the others (which
    :func:`reusable_tracks` must have allowed).

    Args:
        obs: (M rows) the current observations.
        fresh: (M,) bool, the rows triangulated into ``new``.
        new: :class:`MultiviewPoints` of the rows ``fresh``.
        old_obs / old: an earlier triangulation and its observations.
    """
    kept = ~fresh
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

    def per_obs(a_new, a_old):
        out = np.empty((len(obs),) + a_new.shape[1:], a_new.dtype)
        out[fresh] = a_new
        out[kept] = a_old[j]
        return out

    return MultiviewPoints(track_ids[perm], tracks(new.points_w, old.points_w),
                           tracks(new.covariance_w, old.covariance_w), tracks(new.status, old.status),
                           tracks(new.n_inliers, old.n_inliers), tracks(new.max_angle_deg, old.max_angle_deg),
                           obs_track, per_obs(new.inlier, old.inlier), per_obs(new.residual_px, old.residual_px),
                           per_obs(new.depth, old.depth), per_obs(new.sigma_depth, old.sigma_depth),
                           tracks(new.relative_sigma, old.relative_sigma))


def triangulate_window(tracks: TrackTable, frame_ids, cameras, poses, covariances, settings: MultiviewSettings,
                       min_length: int, previous=None, fresh_frames=()) -> tuple[Observations, MultiviewPoints]:
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

    Returns:
        ``(observations, MultiviewPoints)``: the observations triangulated and the result.
    """
    ids = [int(f) for f in frame_ids]
    T = check_array("poses", poses, (len(ids), 4, 4))
    C = check_array("covariances", covariances, (len(ids), 6, 6))
    obs = tracks.observations(min_length=min_length)
    view = np.searchsorted(np.array(ids), obs.frame) if len(obs) else np.zeros(0, np.int64)
    fresh = np.ones(len(obs), bool)
    if previous is not None:
        fresh = ~reusable_tracks(obs, *previous)
        fresh |= np.isin(obs.track, obs.track[np.isin(obs.frame, list(fresh_frames))])
    res = triangulate_tracks(obs.track[fresh], view[fresh], obs.uv[fresh], list(cameras), T, settings, C)
    if not fresh.all():
        res = merge_points(obs, fresh, res, *previous)
    return obs, res
