"""Re-triangulating only the changed tracks (vio_depth.landmarks.incremental): which tracks
are reusable, and a merged result equal to triangulating everything again."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from triangulation.multiview import MultiviewSettings, TrackStatus, triangulate_tracks
from vio_core.camera import Camera
from vio_core.geometry import make_transform
from vio_depth.landmarks import Observations
from vio_depth.landmarks.incremental import _extend, extended_tracks, gate_extensions, merge_points, reusable_tracks

CAM = Camera(640, 480, 500.0, 500.0, 320.0, 240.0)


def _scene(n_points=60, n_views=5, seed=0):
    rng = np.random.default_rng(seed)
    T = np.array([make_transform(Rotation.from_rotvec(rng.normal(0, 0.02, 3)).as_matrix(),
                                 np.array([0.15 * i, 0.02 * i, 0.0])) for i in range(n_views)])
    P = np.column_stack([rng.uniform(-2, 2, n_points), rng.uniform(-1.5, 1.5, n_points), rng.uniform(3, 8, n_points)])
    tr, fr, kp, uv = [], [], [], []
    for v, Tv in enumerate(T):
        ideal, _ = CAM.project((P - Tv[:3, 3]) @ Tv[:3, :3])
        seen = rng.random(n_points) < 0.8
        tr.append(np.nonzero(seen)[0])
        fr.append(np.full(seen.sum(), 10 + v))
        kp.append(rng.permutation(200)[: seen.sum()])  # any keypoint indices, distinct per frame
        uv.append(ideal[seen] + rng.normal(0, 0.5, (seen.sum(), 2)))
    obs = Observations(*(np.concatenate(x) for x in (tr, fr, kp)), np.concatenate(uv))
    keep = np.bincount(obs.track, minlength=n_points)[obs.track] >= 2
    return obs.take(keep), T


def _triangulate(obs, T, rows=None):
    rows = np.ones(len(obs), bool) if rows is None else rows
    return triangulate_tracks(obs.track[rows], obs.frame[rows] - 10, obs.uv[rows], CAM, T, MultiviewSettings(),
                              np.tile(np.diag([1e-6] * 3 + [1e-4] * 3), (len(T), 1, 1)))


def test_only_changed_tracks_are_fresh_and_the_merge_equals_a_full_triangulation():
    obs, T = _scene()
    old = _triangulate(obs, T)
    assert reusable_tracks(obs, obs, old).all()
    # track 3 loses its first observation, track 5 is renamed (split off), track 8 gains none
    drop = np.nonzero(obs.track == 3)[0][0]
    now = obs.take(np.arange(len(obs)) != drop)
    track = now.track.copy()
    track[track == 5] = 999
    now = Observations(track, now.frame, now.keypoint, now.uv)
    reuse = reusable_tracks(now, obs, old)
    assert not reuse[now.track == 3].any() and not reuse[now.track == 999].any()
    assert reuse[~np.isin(now.track, (3, 999))].all()
    fresh = ~reuse
    merged = merge_points(now, fresh, _triangulate(now, T, fresh), obs, old)
    full = _triangulate(now, T)
    np.testing.assert_array_equal(merged.track_ids, full.track_ids)
    np.testing.assert_array_equal(merged.obs_track, full.obs_track)
    np.testing.assert_array_equal(merged.status, full.status)
    np.testing.assert_array_equal(merged.inlier, full.inlier)
    np.testing.assert_allclose(merged.points_w, full.points_w, atol=1e-9)
    np.testing.assert_allclose(merged.sigma_depth, full.sigma_depth, rtol=1e-9)


def test_a_track_with_a_moved_observation_is_not_reusable():
    obs, T = _scene(seed=1)
    old = _triangulate(obs, T)
    kp = obs.keypoint.copy()
    row = np.nonzero(obs.track == 7)[0][1]
    kp[row] = 500  # the same frame, another keypoint
    reuse = reusable_tracks(Observations(obs.track, obs.frame, kp, obs.uv), obs, old)
    assert not reuse[obs.track == 7].any() and reuse[obs.track != 7].all()
    assert not reusable_tracks(obs, None, None).any()


def test_a_track_extended_by_one_keyframe_keeps_its_point_and_the_gate_judges_the_new_observation():
    obs, T = _scene(n_points=80, seed=2)
    before = obs.frame < 14  # the first four views, triangulated before the fifth came
    old_obs = obs.take(before)
    old_obs = old_obs.take(np.bincount(old_obs.track, minlength=80)[old_obs.track] >= 2)
    old = _triangulate(old_obs, T[:4])
    uv = obs.uv.copy()
    new_rows = np.nonzero(obs.frame == 14)[0]
    bad = new_rows[::10]  # every tenth new observation is a wrong match, 25 px off
    uv[bad] += 25.0
    now = Observations(obs.track, obs.frame, obs.keypoint, uv)
    ext = extended_tracks(now, old_obs, old, 14)
    had_point = np.isin(now.track, old.track_ids[np.isin(old.status, (TrackStatus.VALID, TrackStatus.UNCERTAIN))])
    np.testing.assert_array_equal(ext, (now.frame == 14) & had_point)
    assert ext.sum() > 30
    assert not extended_tracks(now, old_obs, old, 13).any()  # the fifth view's, not another's

    rows = np.nonzero(ext)[0]
    cov = np.tile(np.diag([1e-6] * 3 + [1e-4] * 3), (len(T), 1, 1))
    gate = gate_extensions(now, rows, now.frame - 10, old, [CAM] * 5, T, cov, MultiviewSettings())
    wrong = np.isin(rows, bad)
    assert not gate.inlier[wrong].any()  # 25 px against ~1 px of predicted spread
    assert gate.inlier[~wrong].mean() > 0.95
    z_true = np.einsum("nj,j->n", old.points_w[np.searchsorted(old.track_ids, now.track[rows])] - T[4, :3, 3],
                       T[4, :3, 2])
    np.testing.assert_allclose(gate.depth, z_true, rtol=1e-12)

    # merged with a triangulation of the other tracks: the extended tracks keep old's points and
    # gain their inliers; every other track is as a triangulation of it
    fresh = ~np.isin(now.track, now.track[ext]) & ~reusable_tracks(now, old_obs, old)
    merged = merge_points(now, fresh, _triangulate(now, T, fresh), old_obs, old, ext, gate)
    _extend(merged, now, rows, gate, MultiviewSettings())
    t_ext = np.searchsorted(merged.track_ids, now.track[rows])
    t_old = np.searchsorted(old.track_ids, now.track[rows])
    np.testing.assert_array_equal(merged.points_w[t_ext], old.points_w[t_old])
    np.testing.assert_array_equal(merged.n_inliers[t_ext], old.n_inliers[t_old] + gate.inlier)
    np.testing.assert_array_equal(merged.inlier[rows], gate.inlier)
    np.testing.assert_array_equal(merged.track_ids[merged.obs_track], now.track)
    full = _triangulate(now, T, fresh)
    t_fresh = np.searchsorted(merged.track_ids, full.track_ids)
    np.testing.assert_allclose(merged.points_w[t_fresh], full.points_w, atol=1e-12)
