"""evaluate_frame: the shared-mask evaluation equals compute_metrics on the whole maps, bit for bit."""

import numpy as np

from vio_depth.evaluation import compute_metrics, evaluate_frame, oracle_fit
from vio_depth.rescale import metric_depth


def _scene(seed: int = 0):
    rng = np.random.default_rng(seed)
    h, w = 48, 64
    gt = rng.uniform(1.0, 60.0, (h, w)).astype(np.float32)
    gt[rng.random((h, w)) < 0.3] = 0.0  # no ground truth
    gt[0, :5] = 95.0  # beyond max_depth
    disparity = (1.0 / np.where(gt > 0, gt, 30.0) * 4.0 + rng.normal(0, 0.002, (h, w))).astype(np.float32)
    disparity[5, :7] = np.nan  # masked disparity
    depth = (gt * rng.uniform(0.9, 1.1, (h, w))).astype(np.float32)
    depth[10, :9] = np.nan  # no prediction
    depth[11, :3] = -1.0
    return gt, depth, disparity


def test_shared_mask_evaluation_equals_the_whole_map_metrics():
    for seed in range(3):
        gt, depth, disparity = _scene(seed)
        ev = evaluate_frame(gt, depth, disparity, min_depth=1e-3, max_depth=80.0, points=False)
        assert ev.metrics == compute_metrics(depth, gt, 1e-3, 80.0)
        ofit = oracle_fit(disparity, gt, 1e-3, 80.0)
        assert ofit.ok and ev.oracle == compute_metrics(metric_depth(disparity, ofit), gt, 1e-3, 80.0)
        assert ev.metrics.n_pixels > 1000 and ev.metrics.coverage < 1.0


def test_no_evaluated_pixel_gives_empty_metrics():
    gt, depth, disparity = _scene()
    ev = evaluate_frame(np.zeros_like(gt), depth, disparity, points=False)
    assert ev.metrics.n_pixels == 0 and ev.oracle is None
