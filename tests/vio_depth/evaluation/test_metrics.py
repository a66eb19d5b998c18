"""Tests of vio_depth/metrics.py against hand-computed values on tiny arrays."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from vio_core.errors import InputError, ShapeError
from vio_depth.evaluation.metrics import DepthMetrics, average_metrics, compute_metrics, oracle_fit
from vio_depth.rescale import FitStatus, metric_depth

DATA = Path(__file__).resolve().parents[3] / ".." / "shared" / "data"


def test_hand_computed_metrics_with_an_invalid_prediction():
    gt = np.array([[2.0, 4.0], [0.0, 8.0]])  # 0 = no ground truth
    pred = np.array([[2.0, 5.0], [3.0, np.nan]])  # NaN = no prediction -> max_depth
    m = compute_metrics(pred, gt, min_depth=1e-3, max_depth=10.0)
    # evaluated pixels: (g, p) = (2, 2), (4, 5), (8, 10)
    assert m.n_pixels == 3
    assert m.coverage == pytest.approx(2 / 3)
    assert m.abs_rel == pytest.approx((0 + 1 / 4 + 2 / 8) / 3)
    assert m.sq_rel == pytest.approx((0 + 1 / 4 + 4 / 8) / 3)
    assert m.rmse == pytest.approx(math.sqrt((0 + 1 + 4) / 3))
    assert m.rmse_log == pytest.approx(math.sqrt(2 * math.log(1.25) ** 2 / 3))
    # ratios 1, 1.25, 1.25: delta1 needs < 1.25 strictly
    assert m.delta1 == pytest.approx(1 / 3)
    assert m.delta2 == 1.0 and m.delta3 == 1.0


def test_clamping_and_range():
    gt = np.array([[1.0, 50.0, 100.0, 0.5]])
    pred = np.array([[0.0001, 60.0, 10.0, 0.5]])
    m = compute_metrics(pred, gt, min_depth=0.6, max_depth=55.0)
    # gt 100 and 0.5 are outside [0.6, 55] and not evaluated; the (valid, positive)
    # predictions 0.0001 and 60 are clamped to 0.6 and 55
    assert m.n_pixels == 2 and m.coverage == 1.0
    assert m.abs_rel == pytest.approx((0.4 / 1.0 + 5.0 / 50.0) / 2)
    neg = compute_metrics(np.array([[-1.0]]), np.array([[2.0]]), max_depth=10.0)
    assert neg.coverage == 0.0 and neg.abs_rel == pytest.approx(4.0)  # -1 is no prediction -> 10


def test_no_evaluated_pixel_and_bad_input():
    m = compute_metrics(np.ones((2, 2)), np.zeros((2, 2)))
    assert m.n_pixels == 0 and math.isnan(m.abs_rel)
    assert m.to_json()["abs_rel"] is None
    with pytest.raises(ShapeError):
        compute_metrics(np.ones((2, 2)), np.ones((2, 3)))
    with pytest.raises(InputError):
        compute_metrics(np.ones((2, 2)), np.ones((2, 2)), min_depth=5.0, max_depth=1.0)


def test_average_is_over_frames():
    a = compute_metrics(np.array([[2.0, 2.0]]), np.array([[1.0, 1.0]]), max_depth=10.0)  # abs_rel 1
    b = compute_metrics(np.array([[1.0]]), np.array([[1.0]]), max_depth=10.0)  # abs_rel 0
    empty = compute_metrics(np.ones((1, 1)), np.zeros((1, 1)))
    avg = average_metrics([a, b, empty])
    assert avg.abs_rel == pytest.approx(0.5)  # frame mean, not pixel mean (2/3)
    assert avg.n_frames == 2 and avg.n_pixels == 3
    again = average_metrics([avg, b])  # an average counts as its frames
    assert again.abs_rel == pytest.approx(1 / 3) and again.n_frames == 3
    with pytest.raises(InputError):
        average_metrics([empty])
    assert isinstance(avg, DepthMetrics)


def test_oracle_recovers_exact_parameters():
    rng = np.random.default_rng(0)
    gt = rng.uniform(2.0, 40.0, (30, 40))
    gt[rng.random(gt.shape) < 0.2] = 0.0  # missing ground truth
    alpha, beta = 0.07, -0.004
    with np.errstate(divide="ignore"):
        disparity = np.where(gt > 0, (1.0 / gt - beta) / alpha, 123.0)  # junk where gt is missing
    fit = oracle_fit(disparity, gt, 1e-3, 80.0)
    assert fit.status == FitStatus.OK
    assert fit.alpha == pytest.approx(alpha, rel=1e-9) and fit.beta == pytest.approx(beta, abs=1e-12)
    assert fit.r2 == pytest.approx(1.0) and fit.n_points == int((gt > 0).sum())
    depth = metric_depth(disparity, fit)
    np.testing.assert_allclose(depth[gt > 0], gt[gt > 0], rtol=1e-5)
    perfect = compute_metrics(depth, gt, 1e-3, 80.0)
    assert perfect.abs_rel < 1e-5 and perfect.delta1 == 1.0


def test_oracle_refusals():
    assert oracle_fit(np.ones((3, 3)), np.full((3, 3), 2.0)).status == FitStatus.TOO_FEW_POINTS
    gt = np.arange(1.0, 10.0).reshape(3, 3)
    assert oracle_fit(gt, gt).status == FitStatus.NO_CONSENSUS  # d grows with depth: alpha < 0
    assert oracle_fit(np.ones((2, 2)), np.zeros((2, 2))).status == FitStatus.TOO_FEW_POINTS


@pytest.mark.shared_data
def test_oracle_on_7scenes_ground_truth():
    folder = DATA / "7scenes_redkitchen"
    if not folder.is_dir():
        pytest.skip("../shared/data is absent")
    import cv2

    gt = cv2.imread(str(folder / "frame-000000.depth.png"), cv2.IMREAD_UNCHANGED).astype(np.float64)
    gt[gt == 65535] = 0
    gt /= 1000.0
    # an exactly affine disparity of the real depth: the oracle must give the real depth back
    with np.errstate(divide="ignore"):
        disparity = np.where(gt > 0, 3.0 / gt + 0.5, 0.0)
    fit = oracle_fit(disparity, gt, 1e-3, 10.0)
    assert fit.ok and fit.alpha == pytest.approx(1 / 3, rel=1e-6)
    m = compute_metrics(metric_depth(disparity, fit), gt, 1e-3, 10.0)
    assert m.abs_rel < 1e-5 and m.n_pixels > 100_000


def test_depth_reprojection_errors_zero_for_consistent_poses_and_catch_a_wrong_pose():
    from vio_core.camera import Camera
    from vio_core.geometry import make_transform
    from vio_depth.evaluation.metrics import depth_reprojection_errors

    cam = Camera(64, 48, 50.0, 50.0, 31.5, 23.5)
    wall_a = np.full((48, 64), 4.0)  # fronto-parallel wall 4 m ahead of camera a
    T_b_a = make_transform(np.eye(3), [0.0, 0.0, -1.0])  # camera b is 1 m closer to it
    wall_b = np.full((48, 64), 3.0)
    err = depth_reprojection_errors(wall_a, wall_b, cam, T_b_a)
    assert len(err) > 1000 and np.max(err) < 1e-12
    err_wrong = depth_reprojection_errors(wall_a, wall_b, cam, np.eye(4))
    assert np.median(err_wrong) == pytest.approx(1.0 / 3.0)
