"""Point accuracy: relative depth error of sparse points against (robust) ground truth."""

import numpy as np
import pytest

from vio_core.errors import ShapeError
from vio_depth.evaluation.point_accuracy import point_depth_errors, window_median_depth


def _plane(h=60, w=80, depth=4.0):
    return np.full((h, w), depth, np.float32)


def test_known_errors_on_dense_ground_truth():
    rng = np.random.default_rng(0)
    gt = _plane()
    n = 200
    uv = np.stack([rng.uniform(5, 74, n), rng.uniform(5, 54, n)], axis=1)
    rel = rng.uniform(-0.2, 0.2, n)
    acc = point_depth_errors(uv, 4.0 * (1 + rel), gt)
    assert acc.count == n
    assert acc.median == pytest.approx(np.median(np.abs(rel)), rel=1e-5)
    assert acc.p90 == pytest.approx(np.percentile(np.abs(rel), 90), rel=1e-5)
    assert acc.bias == pytest.approx(np.median(rel), abs=1e-6)
    assert acc.evaluated.all()
    np.testing.assert_allclose(acc.gt_depth, 4.0, rtol=1e-6)


def test_window_median_matches_a_direct_computation_on_sparse_ground_truth():
    rng = np.random.default_rng(1)
    gt = rng.uniform(1, 20, (40, 50)).astype(np.float32)
    gt[rng.random(gt.shape) < 0.9] = 0.0  # LiDAR-like: 10 % valid
    uv = np.stack([rng.uniform(-2, 51, 300), rng.uniform(-2, 41, 300)], axis=1)
    got = window_median_depth(uv, gt, window=2)
    for (u, v), g in zip(uv, got):
        c, r = int(np.round(u)), int(np.round(v))
        if not (0 <= c < 50 and 0 <= r < 40):
            assert np.isnan(g)
            continue
        win = gt[max(r - 2, 0):r + 3, max(c - 2, 0):c + 3]
        win = win[win > 0]
        if len(win) == 0:
            assert np.isnan(g)
        else:
            assert g == pytest.approx(np.median(win), rel=1e-6)


def test_points_without_reference_are_not_counted():
    gt = _plane()
    gt[:, 40:] = 0.0  # right half has no ground truth
    uv = np.array([[10.0, 10.0], [70.0, 10.0], [np.nan, 3.0], [-30.0, 5.0], [20.0, 20.0]])
    depth = np.array([4.4, 4.0, 4.0, 4.0, -1.0])  # last: non-positive depth
    acc = point_depth_errors(uv, depth, gt, window=1)
    assert acc.count == 1
    assert acc.evaluated.tolist() == [True, False, False, False, False]
    assert acc.median == pytest.approx(0.1, rel=1e-5)


def test_no_points_gives_count_zero_and_nan():
    acc = point_depth_errors(np.zeros((0, 2)), np.zeros(0), _plane())
    assert acc.count == 0 and np.isnan(acc.median) and np.isnan(acc.p90)
    assert acc.to_json()["points_rel_err_median"] is None


def test_robust_to_a_misregistered_depth_camera():
    # foreground box at 1.5 m on a 5 m wall; ground truth shifted by 4 px (unregistered camera)
    h, w = 120, 160
    truth = np.full((h, w), 5.0, np.float32)
    truth[30:90, 40:120] = 1.5
    shifted = np.roll(truth, (4, 4), axis=(0, 1))
    rng = np.random.default_rng(2)
    uv = np.stack([rng.uniform(0, w - 1, 2000), rng.uniform(0, h - 1, 2000)], axis=1)
    r, c = np.round(uv[:, 1]).astype(int), np.round(uv[:, 0]).astype(int)
    z = truth[r, c].astype(float)  # perfect points
    acc = point_depth_errors(uv, z, shifted, window=2)
    # the few points near the box edges are wrong by up to 233 %, the median is unaffected
    assert acc.count == 2000
    assert acc.median < 1e-6
    assert acc.p90 < 1e-6
    assert np.max(np.abs(z - acc.gt_depth) / acc.gt_depth) > 1.0


def test_shape_errors():
    with pytest.raises(ShapeError):
        point_depth_errors(np.zeros((3, 3)), np.zeros(3), _plane())
    with pytest.raises(ShapeError):
        point_depth_errors(np.zeros((3, 2)), np.zeros(4), _plane())
    with pytest.raises(ShapeError):
        point_depth_errors(np.zeros((3, 2)), np.zeros(3), np.zeros(5))
