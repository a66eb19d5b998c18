"""KLT tracking front end: tracks follow a known image motion, the rotation hint keeps fast
turns tracked, epipolar outliers are dropped, matches join track ids."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from matchers import Features, FrameTracker, KltSettings, KltTracker, MotionHint, TrackIds, create_matcher
from matchers.klt import free_mask, predict_rotated, rotation_epipolar_inliers, spaced_oldest
from vio_core.camera import Camera
from vio_core.errors import SettingsError, ShapeError

W, H = 640, 480
CAMERA = Camera.from_K(np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]]), W, H)


def texture(seed: int = 0, size=(H + 400, W + 400)) -> np.ndarray:
    """A blurred random texture, larger than the image (for warps), uint8 grey."""
    rng = np.random.default_rng(seed)
    img = rng.integers(0, 256, size=(size[0] // 8, size[1] // 8)).astype(np.uint8)
    img = cv2.resize(img, (size[1], size[0]), interpolation=cv2.INTER_CUBIC)
    return cv2.GaussianBlur(img, (5, 5), 1.2)


def rot_y(deg: float) -> np.ndarray:
    a = np.radians(deg)
    return np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])


def view(big: np.ndarray, R_cur_ref: np.ndarray | None = None) -> np.ndarray:
    """The image seen by a camera rotated by ``R_cur_ref`` from the reference view (the centre of
    ``big``, as a plane at infinity): a warp by ``K R K^-1``, RGB."""
    K = CAMERA.K
    Hm = np.eye(3) if R_cur_ref is None else K @ R_cur_ref @ np.linalg.inv(K)
    off = np.array([[1, 0, 200], [0, 1, 200], [0, 0, 1.0]])  # reference image = big[200:200+H, 200:200+W]
    M = Hm @ np.linalg.inv(off)  # big pixel -> current pixel
    grey = cv2.warpPerspective(big, M, (W, H), flags=cv2.INTER_LINEAR)
    return np.repeat(grey[:, :, None], 3, axis=2)


def homography_map(uv: np.ndarray, R: np.ndarray) -> np.ndarray:
    Hm = CAMERA.K @ R @ np.linalg.inv(CAMERA.K)
    p = np.column_stack([uv, np.ones(len(uv))]) @ Hm.T
    return p[:, :2] / p[:, 2:]


def test_preset_is_a_frame_tracker():
    m = create_matcher("klt")
    assert isinstance(m, KltTracker) and isinstance(m, FrameTracker)
    assert not isinstance(create_matcher("sift"), FrameTracker)
    assert m.concurrent_extract is False


@pytest.mark.parametrize("bad", [dict(max_tracks=0), dict(window_px=20), dict(quality=1.0), dict(ransac_px=0.0),
                                 dict(back_check_px=-1.0), dict(pyramid_levels=-1), dict(max_tracks=True),
                                 dict(top_up_below=0.0), dict(top_up_below=1.5)])
def test_settings_refuse_bad_values(bad):
    with pytest.raises(SettingsError):
        KltSettings(**bad)


def test_tracks_follow_a_known_rotation_to_a_tenth_of_a_pixel():
    big = texture(1)
    R = rot_y(1.0)  # about 8.7 px of image motion
    tr = KltTracker()
    a = tr.track(view(big))
    b = tr.track(view(big, R), MotionHint(CAMERA, R))
    m = tr.match(a, b)
    assert len(a) >= 200 and len(m) >= 0.9 * len(a)
    err = np.linalg.norm(b.keypoints[m.idx_b] - homography_map(a.keypoints[m.idx_a].astype(float), R), axis=1)
    assert np.median(err) < 0.1 and np.percentile(err, 95) < 0.3
    assert np.all(b.scores[m.idx_b] == 2)  # tracked twice
    assert isinstance(b.payload, TrackIds) and len(np.unique(b.payload.ids)) == len(b)


def test_rotation_hint_keeps_a_fast_turn_tracked():
    """8 degrees between frames (~70 px) is beyond one pyramid level's reach without a prediction."""
    big = texture(2)
    R = rot_y(8.0)
    s = KltSettings(pyramid_levels=1, window_px=15)
    found = {}
    for hinted in (False, True):
        tr = KltTracker(s)
        a = tr.track(view(big))
        b = tr.track(view(big, R), MotionHint(CAMERA, R if hinted else None))
        m = tr.match(a, b)
        err = np.linalg.norm(b.keypoints[m.idx_b] - homography_map(a.keypoints[m.idx_a].astype(float), R), axis=1)
        found[hinted] = int((err < 0.5).sum())
    assert found[True] >= 100
    assert found[False] < 0.5 * found[True]


def test_predict_rotated_matches_the_homography_and_respects_distortion():
    uv = np.array([[100.0, 100.0], [320.0, 240.0], [500.0, 400.0]])
    R = rot_y(2.0)
    np.testing.assert_allclose(predict_rotated(uv, CAMERA, R), homography_map(uv, R), atol=1e-9)
    distorted = Camera.from_K(CAMERA.K, W, H, dist=(-0.2, 0.05, 0.001, -0.001))
    ideal = distorted.undistort_points(uv)
    expected = distorted.distort_points(homography_map(ideal, R))
    np.testing.assert_allclose(predict_rotated(uv, distorted, R), expected, atol=1e-3)


def test_rotation_epipolar_ransac_drops_outliers():
    rng = np.random.default_rng(3)
    n = 200
    X = np.column_stack([rng.uniform(-3, 3, n), rng.uniform(-2, 2, n), rng.uniform(4, 12, n)])  # prev camera, metres
    R = rot_y(3.0)
    t = np.array([0.3, 0.02, 0.1])
    Xc = X @ R.T + t
    rays_prev = X / X[:, 2:]
    rays_cur = Xc / Xc[:, 2:]
    bad = rng.choice(n, 30, replace=False)
    rays_cur[bad, :2] += rng.normal(0, 0.02, (30, 2)) + 0.01  # 5-15 px off at f = 500
    inl = rotation_epipolar_inliers(rays_prev, rays_cur, R, 1.0 / 500)
    good = np.setdiff1d(np.arange(n), bad)
    assert inl[good].mean() == 1.0
    assert inl[bad].mean() < 0.2


def test_rotation_epipolar_ransac_keeps_everything_without_parallax():
    rng = np.random.default_rng(4)
    rays = np.column_stack([rng.uniform(-0.5, 0.5, (50, 2)), np.ones(50)])
    R = rot_y(5.0)
    cur = rays @ R.T
    assert rotation_epipolar_inliers(rays, cur / cur[:, 2:], R, 0.002).all()


def test_spacing_keeps_the_oldest_track_per_cell():
    uv = np.array([[5.0, 5.0], [6.0, 6.0], [50.0, 50.0], [7.0, 4.0]])
    age = np.array([1, 9, 3, 9])
    keep = spaced_oldest(uv, age, 20.0, 100, 100)
    np.testing.assert_array_equal(keep, [1, 2])  # 1 and 3 tie at age 9: the lower index


def test_free_mask_blocks_near_tracks_only():
    mask = free_mask(np.array([[50.0, 40.0]]), 20.0, 200, 100)
    assert mask.shape == (100, 200) and mask.dtype == np.uint8
    assert mask[40, 50] == 0 and mask[40, 65] == 0
    assert mask[40, 120] == 255 and mask[95, 195] == 255


def test_match_joins_track_ids_and_refuses_foreign_features():
    tr = KltTracker()
    a = Features(np.zeros((3, 2), np.float32), np.zeros((3, 0), np.float32), np.ones(3, np.float32), (W, H),
                 payload=TrackIds(np.array([4, 7, 9])))
    b = Features(np.zeros((3, 2), np.float32), np.zeros((3, 0), np.float32), np.ones(3, np.float32), (W, H),
                 payload=TrackIds(np.array([9, 1, 4])))
    m = tr.match(a, b)
    np.testing.assert_array_equal(m.idx_a, [0, 2])
    np.testing.assert_array_equal(m.idx_b, [2, 0])
    sift = create_matcher("sift").extract(view(texture(5)))
    with pytest.raises(ShapeError, match="KLT"):
        tr.match(a, sift)


def test_reset_starts_new_tracks_and_refuses_a_size_change():
    big = texture(6)
    tr = KltTracker()
    a = tr.track(view(big))
    tr.reset()
    b = tr.track(view(big))
    assert len(tr.match(a, b)) == 0  # ids never repeat
    with pytest.raises(ShapeError):
        tr.track(np.zeros((100, 100, 3), np.uint8))


def test_top_up_refills_where_tracks_left_the_image():
    big = texture(7)
    tr = KltTracker()
    tr.track(view(big))
    R = rot_y(6.0)  # ~52 px: the corners near the left edge leave
    b = tr.track(view(big, R), MotionHint(CAMERA, R))
    s = tr.last_stats
    assert s.lost_flow > 0 and s.new > 0
    assert s.tracks == len(b) <= tr.settings.max_tracks


def test_top_up_waits_until_enough_tracks_are_lost():
    """With ``top_up_below`` 0.9 a frame that keeps 90 % of ``max_tracks`` searches no new corners
    (the search is the tracker's largest cost); one that loses more does; 1.0 refills any loss."""
    big = texture(7)
    for frac, R, expect_new in ((0.9, rot_y(1.0), False), (1.0, rot_y(1.0), True), (0.9, rot_y(20.0), True)):
        tr = KltTracker(KltSettings(top_up_below=frac))
        a = tr.track(view(big))
        assert len(a) >= 0.99 * tr.settings.max_tracks  # the texture holds (nearly) all
        tr.track(view(big, R), MotionHint(CAMERA, R))
        s = tr.last_stats
        kept = s.previous - s.lost_flow - s.lost_back - s.lost_epipolar - s.thinned
        assert kept < s.previous  # some were lost either way
        assert (kept < frac * tr.settings.max_tracks) == expect_new
        assert (s.new > 0) == expect_new, (frac, kept, s)
