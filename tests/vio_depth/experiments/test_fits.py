"""Least squares per frame and pooled over frames; the three fits of the studies on the same points."""

import numpy as np
import pytest

from vio_depth.experiments import FIT_METHODS, PooledSums, fit_and_depth, least_squares_fit
from vio_depth.rescale import FitStatus


def test_least_squares_recovers_an_exact_line_and_refuses_bad_input():
    rng = np.random.default_rng(0)
    d = rng.uniform(0.1, 1.0, 50)
    z = 1.0 / (0.3 * d + 0.02)
    fit = least_squares_fit(d, z)
    assert fit.ok and fit.alpha == pytest.approx(0.3, rel=1e-12) and fit.beta == pytest.approx(0.02, rel=1e-10)
    assert fit.r2 == pytest.approx(1.0)
    assert least_squares_fit(d[:5], z[:5]).status == FitStatus.TOO_FEW_POINTS
    assert least_squares_fit(np.full(20, 0.5), z[:20]).status == FitStatus.ILL_CONDITIONED
    assert least_squares_fit(d, 1.0 / (0.5 - 0.3 * d)).status == FitStatus.NO_CONSENSUS  # alpha < 0


def test_pooled_sums_equal_one_least_squares_over_all_frames():
    rng = np.random.default_rng(1)
    frames = []
    for k in range(3):
        d = rng.uniform(0.1, 1.0, (20, 30))
        gt = 1.0 / (0.25 * d + 0.05 + rng.normal(0, 0.002, d.shape))
        gt[rng.random(d.shape) < 0.2] = 0.0  # invalid ground truth
        d[0, :5] = np.nan
        frames.append((d, gt))
    pooled = PooledSums(1e-3, 80.0)
    for d, gt in frames:
        pooled.add(d, gt)
    ok = [np.isfinite(d) & (gt > 0) for d, gt in frames]
    ref = least_squares_fit(np.concatenate([d[m] for (d, _), m in zip(frames, ok, strict=True)]),
                            np.concatenate([gt[m] for (_, gt), m in zip(frames, ok, strict=True)]))
    fit = pooled.fit()
    assert fit.ok and fit.alpha == pytest.approx(ref.alpha, rel=1e-9) and fit.beta == pytest.approx(ref.beta, rel=1e-8)
    assert fit.r2 == pytest.approx(ref.r2, rel=1e-8)


def test_the_three_fits_agree_on_clean_points_and_only_robust_ones_survive_outliers():
    rng = np.random.default_rng(2)
    disparity = rng.uniform(0.1, 1.0, (40, 60)).astype(np.float32)
    truth = 1.0 / (0.2 * disparity + 0.01)
    idx = rng.choice(disparity.size, 400, replace=False)
    d, z = disparity.ravel()[idx].astype(np.float64), truth.ravel()[idx].astype(np.float64)
    published = 1.0 / (1.0 / truth + 1e-3)  # the published depth adds 1e-3 1/m before inverting
    for method in FIT_METHODS:
        depth, status = fit_and_depth(method, disparity, d, z, seed=0)
        expected = published if method == "paper-reference" else truth
        assert status == "ok" and np.nanmedian(np.abs(depth - expected) / expected) < 2e-3, method
    z_bad = z.copy()
    z_bad[:120] = rng.uniform(0.5, 80.0, 120)  # 30 % outliers
    err = {m: np.nanmedian(np.abs(fit_and_depth(m, disparity, d, z_bad, seed=0)[0] - truth) / truth)
           for m in FIT_METHODS}
    assert err["ours"] < 0.01 and err["least-squares"] > 5 * err["ours"]
