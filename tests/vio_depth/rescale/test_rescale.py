"""Tests of vio_depth/rescale.py: robust affine fit, diagnostics, maps and the Rescaler.

Synthetic problems with known (alpha, beta); every tolerance is stated next to its check.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from vio_core.errors import InputError, SettingsError, ShapeError, UnknownNameError
from vio_depth.pipeline import FrameStatus, decide_frame_status
from vio_depth.rescale import (
    RESCALER_PRESETS,
    FitSource,
    FitStatus,
    RansacSettings,
    Rescaler,
    RescalerSettings,
    depth_sigma_map,
    fit_affine,
    fit_scale_only,
    metric_depth,
    metric_disparity_sigma,
    sample_bilinear,
)


def _status(result):
    """The frame status the pipeline gives a frame whose points were fine."""
    return decide_frame_status(FrameStatus.OK, result.source, result.raw.status)

ALPHA, BETA = 0.3, 0.02  # 1/m per unit of d, 1/m


def make_points(rng, n=500, alpha=ALPHA, beta=BETA, rel_sigma=0.03, outliers=0.0, d_range=(0.1, 1.0)):
    """d, depth, sigma_depth with metric-disparity noise rel_sigma * m and a fraction of
    outliers uniform over [0.5 min m, 1.5 max m]."""
    d = rng.uniform(*d_range, n)
    m_true = alpha * d + beta
    sigma_m = rel_sigma * m_true
    m = m_true + sigma_m * rng.standard_normal(n)
    k = int(round(outliers * n))
    out = rng.permutation(n)[:k]
    m[out] = rng.uniform(0.5 * m_true.min(), 1.5 * m_true.max(), k)
    depth = 1.0 / m
    return d, depth, sigma_m * depth**2, out


# ----------------------------------------------------------------------------- sampling


def test_sample_bilinear_exact_on_a_plane_and_invalid_cases():
    h, w = 6, 8
    vv, uu = np.mgrid[0:h, 0:w]
    image = (2.0 * uu + 3.0 * vv + 1.0).astype(np.float32)  # bilinear interpolation is exact on a plane
    uv = np.array([[0.0, 0.0], [3.25, 2.5], [7.0, 5.0], [6.9, 0.1], [-0.01, 1.0], [7.01, 1.0], [np.nan, 1.0]])
    values, valid = sample_bilinear(image, uv)
    assert valid.tolist() == [True, True, True, True, False, False, False]
    expected = 2.0 * uv[:4, 0] + 3.0 * uv[:4, 1] + 1.0
    np.testing.assert_allclose(values[:4], expected, atol=1e-5)
    assert np.all(np.isnan(values[~valid]))


def test_sample_bilinear_non_finite_neighbour_invalidates():
    image = np.ones((4, 4))
    image[1, 2] = np.nan
    values, valid = sample_bilinear(image, np.array([[1.5, 0.5], [2.5, 1.5], [0.2, 2.2], [2.0, 1.0]]))
    assert valid.tolist() == [False, False, True, False]
    assert values[2] == pytest.approx(1.0)


def test_sample_bilinear_checks_shapes():
    with pytest.raises(ShapeError):
        sample_bilinear(np.ones((4, 4)), np.ones((3, 3)))
    with pytest.raises(ShapeError):
        sample_bilinear(np.ones((4, 4, 3)), np.ones((3, 2)))


# ----------------------------------------------------------------------------- fit


def test_recovers_parameters_with_30_percent_outliers():
    rng = np.random.default_rng(1)
    d, depth, sd, out = make_points(rng, n=500, outliers=0.3)
    fit = fit_affine(d, depth, sd)
    assert fit.ok, fit.reason
    # 350 inliers with 3 % noise: the standard error of alpha is ~0.3 %; allow 2 %.
    assert abs(fit.alpha - ALPHA) / ALPHA < 0.02
    assert abs(fit.beta - BETA) < 0.002
    # ... and within 4 reported standard deviations
    assert abs(fit.alpha - ALPHA) < 4 * fit.sigma_alpha
    assert abs(fit.beta - BETA) < 4 * fit.sigma_beta
    # most outliers are rejected, almost all inliers kept
    true_in = np.ones(len(d), bool)
    true_in[out] = False
    assert np.mean(fit.inliers[true_in]) > 0.97
    assert np.mean(fit.inliers[out]) < 0.25
    assert fit.n_inliers == int(fit.inliers.sum()) and fit.n_points == 500
    assert fit.inlier_ratio == pytest.approx(fit.n_inliers / 500)
    assert fit.r2 > 0.9
    assert fit.relative_spread > 0.3


def test_negative_disparities_are_used_not_hidden():
    rng = np.random.default_rng(2)
    # d is affine-invariant: a shifted network output may be negative where the scene is far
    d, depth, sd, _ = make_points(rng, n=400, alpha=0.2, beta=0.25, d_range=(-1.0, 1.0))
    assert np.mean(d < 0) > 0.4
    fit = fit_affine(d, depth, sd)
    assert fit.ok, fit.reason
    assert abs(fit.alpha - 0.2) / 0.2 < 0.02
    assert abs(fit.beta - 0.25) < 0.005
    assert np.mean(fit.inliers[d < 0]) > 0.95
    # the points with negative d alone determine the same line
    neg = fit_affine(d[d < 0], depth[d < 0], sd[d < 0])
    assert neg.ok and abs(neg.alpha - 0.2) / 0.2 < 0.05
    depth_map = metric_depth(d.reshape(20, 20), fit)
    np.testing.assert_allclose(depth_map.ravel(), 1.0 / (fit.alpha * d + fit.beta), rtol=1e-5)


def test_too_few_points():
    rng = np.random.default_rng(3)
    d, depth, sd, _ = make_points(rng, n=9)
    fit = fit_affine(d, depth, sd, settings=RansacSettings(min_points=10))
    assert fit.status == FitStatus.TOO_FEW_POINTS and not fit.ok
    assert "9 valid point" in fit.reason
    assert np.isnan(fit.alpha) and fit.n_inliers == 0 and fit.inliers.shape == (9,)
    assert fit_affine(np.zeros(0), np.zeros(0)).status == FitStatus.TOO_FEW_POINTS


def test_excluded_points_count_and_can_make_too_few():
    rng = np.random.default_rng(4)
    d, depth, sd, _ = make_points(rng, n=100)
    depth[:5] = -1.0
    depth[5:8] = np.nan
    d[8] = np.inf
    d[9] = -np.inf
    sd[10] = np.nan
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # bad values are excluded quietly, not with numpy warnings
        fit = fit_affine(d, depth, sd)
    assert fit.ok and fit.n_excluded == 11 and fit.n_points == 89
    assert not fit.inliers[:11].any() and fit.inliers.shape == (100,)
    assert "11 point(s) excluded" in fit.reason
    depth[11:95] = 0.0
    assert fit_affine(d, depth, sd).status == FitStatus.TOO_FEW_POINTS


def test_degenerate_spread_all_points_at_one_depth():
    rng = np.random.default_rng(5)
    d = rng.uniform(0.1, 1.0, 300)
    depth = 10.0 * (1 + 0.01 * rng.standard_normal(300))  # a wall facing the camera
    fit = fit_affine(d, depth)
    assert fit.status == FitStatus.ILL_CONDITIONED, fit.reason
    assert "nearly one depth" in fit.reason
    assert fit_affine(np.full(50, 0.5), np.linspace(2, 20, 50)).status == FitStatus.ILL_CONDITIONED


def test_spread_comparable_to_the_network_error_is_refused():
    """Regression (room sample, frame 3): 96 accurate points whose metric disparities spread
    by only ~6 % (std/mean) -- about the network's own relative error -- were accepted and
    the correlated disparity error tilted the fit (AbsRel 0.21 vs oracle 0.012)."""
    rng = np.random.default_rng(11)
    n = 96
    m_true = 0.4 * (1.0 + 0.06 * rng.standard_normal(n))  # 1/m, relative spread ~0.06
    d = (m_true - BETA) / ALPHA
    d = d + 0.3 * (d - d.mean())  # a smooth, correlated distortion of the disparity
    fit = fit_affine(d, 1.0 / m_true)
    assert fit.status == FitStatus.ILL_CONDITIONED, fit.reason
    wide = fit_affine(*make_points(np.random.default_rng(12), n=n)[:2])
    assert wide.ok, wide.reason  # the same number of points with a wide spread is fine


def test_degenerate_spread_of_the_inliers_behind_wide_outliers():
    rng = np.random.default_rng(6)
    n_in, n_out = 300, 40
    d_in = rng.uniform(0.50, 0.52, n_in)  # consensus only within a tiny disparity range
    m_in = (ALPHA * d_in + BETA) * (1 + 0.005 * rng.standard_normal(n_in))
    d_out = rng.uniform(0.1, 1.0, n_out)
    m_out = (ALPHA * d_out + BETA) * rng.uniform(1.6, 3.0, n_out)  # far off the line
    d = np.r_[d_in, d_out]
    depth = 1.0 / np.r_[m_in, m_out]
    fit = fit_affine(d, depth)
    assert fit.status == FitStatus.ILL_CONDITIONED, fit.reason
    assert fit.relative_spread < RansacSettings().min_relative_spread
    assert "too narrow" in fit.reason
    # the slope through the narrow cluster is ill-determined: a few far-off points may fit it
    assert fit.inliers[:n_in].mean() > 0.9 and fit.inliers[n_in:].mean() < 0.25


def test_all_outliers_give_no_consensus():
    rng = np.random.default_rng(7)
    d = rng.uniform(0.1, 1.0, 500)
    depth = np.exp(rng.uniform(np.log(1.0), np.log(80.0), 500))  # unrelated to d
    fit = fit_affine(d, depth)
    assert fit.status == FitStatus.NO_CONSENSUS, fit.reason
    assert fit.inlier_ratio < RansacSettings().min_inlier_ratio


def test_alpha_must_be_positive():
    rng = np.random.default_rng(8)
    d = rng.uniform(0.0, 1.0, 300)
    m = (-0.2 * d + 0.3) * (1 + 0.02 * rng.standard_normal(300))  # bigger d = farther: wrong sign
    fit = fit_affine(d, 1.0 / m)
    # a positive slope through this cloud either explains too few points or too narrow a band
    assert fit.status in (FitStatus.NO_CONSENSUS, FitStatus.ILL_CONDITIONED), fit.reason
    assert not (fit.alpha <= 0)  # never a non-positive alpha (NaN when there was no hypothesis)
    # noise-free: no pair has a positive slope, so no hypothesis at all after max_iterations
    exact = fit_affine(d, 1.0 / (-0.2 * d + 0.3))
    assert exact.status == FitStatus.NO_CONSENSUS and np.isnan(exact.alpha)
    assert exact.iterations == RansacSettings().max_iterations


def test_deterministic_under_seed():
    rng = np.random.default_rng(9)
    d, depth, sd, _ = make_points(rng, n=300, outliers=0.4)
    a = fit_affine(d, depth, sd, settings=RansacSettings(seed=5))
    b = fit_affine(d, depth, sd, settings=RansacSettings(seed=5))
    assert a.alpha == b.alpha and a.beta == b.beta and np.array_equal(a.inliers, b.inliers)
    c = fit_affine(d, depth, sd, settings=RansacSettings(seed=6))
    assert c.ok and abs(c.alpha - a.alpha) / a.alpha < 0.02


def test_sigma_depth_weights_remove_a_bias():
    # Far points (d < 0.35) come with a large reported uncertainty (30 % in metric disparity)
    # and are systematically 5 % too near; near points are precise (1 %). The network error
    # is set small (2 %) so that the points' own uncertainties dominate the weights.
    settings = RansacSettings(model_relative_sigma=0.02)
    rng = np.random.default_rng(10)
    d = rng.uniform(0.05, 1.0, 600)
    m = ALPHA * d + BETA
    far = d < 0.35
    sigma_m = np.where(far, 0.30, 0.01) * m
    m_obs = m * (1 + 0.01 * rng.standard_normal(600))
    m_obs[far] *= 1.05
    depth = 1.0 / m_obs
    weighted = fit_affine(d, depth, sigma_m * depth**2, settings=settings)
    unweighted = fit_affine(d, depth, settings=settings)
    assert weighted.ok and unweighted.ok
    # the biased far points sit inside the unweighted inlier band and pull beta up by ~16 %
    assert abs(unweighted.beta - BETA) / BETA > 0.10
    assert abs(weighted.beta - BETA) / BETA < 0.07
    assert abs(weighted.alpha - ALPHA) / ALPHA < 0.008
    assert abs(weighted.alpha - ALPHA) < 0.5 * abs(unweighted.alpha - ALPHA)


def test_extra_weights_remove_a_bias():
    # a cluster with a systematic +8 % error (inside the inlier band) but low matcher confidence
    rng = np.random.default_rng(11)
    d = rng.uniform(0.1, 1.0, 600)
    m = (ALPHA * d + BETA) * (1 + 0.01 * rng.standard_normal(600))
    bad = d > 0.7
    m[bad] *= 1.08
    confidence = np.where(bad, 0.01, 1.0)
    weighted = fit_affine(d, 1.0 / m, weights=confidence)
    plain = fit_affine(d, 1.0 / m)
    assert weighted.ok and plain.ok
    assert abs(weighted.alpha - ALPHA) / ALPHA < 0.01
    assert abs(plain.alpha - ALPHA) / ALPHA > 0.03


def test_covariance_is_calibrated_by_monte_carlo():
    rng = np.random.default_rng(12)
    alphas, betas, sa, sb = [], [], [], []
    for _ in range(150):
        d, depth, sd, _ = make_points(rng, n=150, rel_sigma=0.03)
        fit = fit_affine(d, depth, sd)
        assert fit.ok
        alphas.append(fit.alpha)
        betas.append(fit.beta)
        sa.append(fit.sigma_alpha)
        sb.append(fit.sigma_beta)
    # empirical spread over 150 draws vs the reported one: within 25 %
    assert np.std(alphas) / np.median(sa) == pytest.approx(1.0, abs=0.25)
    assert np.std(betas) / np.median(sb) == pytest.approx(1.0, abs=0.25)
    # and unbiased within 3 standard errors of the mean
    assert abs(np.mean(alphas) - ALPHA) < 3 * np.std(alphas) / np.sqrt(150)


def test_metric_disparity_sigma_formula():
    depth = np.array([2.0, 10.0])
    sd = np.array([0.1, 5.0])
    s = RansacSettings(model_relative_sigma=0.05, min_sigma_disparity=1e-6)
    got = metric_disparity_sigma(depth, sd, s)
    expected = np.sqrt((sd / depth**2) ** 2 + (0.05 / depth) ** 2 + 1e-12)
    np.testing.assert_allclose(got, expected, rtol=1e-12)
    pred = np.array([0.4, 0.2])
    np.testing.assert_allclose(metric_disparity_sigma(depth, None, s, pred), np.sqrt((0.05 * pred) ** 2 + 1e-12))


def test_settings_are_validated():
    with pytest.raises(SettingsError):
        RansacSettings(confidence=1.0)
    with pytest.raises(SettingsError):
        RansacSettings(inlier_sigmas=0)
    with pytest.raises(SettingsError):
        RansacSettings(min_points=1)


def test_wrong_shapes_raise():
    with pytest.raises(ShapeError):
        fit_affine(np.ones(5), np.ones(4))
    with pytest.raises(ShapeError):
        fit_affine(np.ones((5, 1)), np.ones(5))
    with pytest.raises(ShapeError):
        fit_affine(np.ones(5), np.ones(5), sigma_depth=np.ones(3))


# ----------------------------------------------------------------------------- scale only


def test_scale_only_fit_recovers_alpha_and_propagates_beta_variance():
    rng = np.random.default_rng(13)
    d, depth, sd, out = make_points(rng, n=200, outliers=0.2)
    fit = fit_scale_only(d, depth, beta=BETA, beta_variance=0.0, sigma_depth=sd)
    assert fit.ok and fit.beta == BETA
    assert abs(fit.alpha - ALPHA) / ALPHA < 0.01
    with_var = fit_scale_only(d, depth, beta=BETA, beta_variance=1e-6, sigma_depth=sd)
    assert with_var.covariance[1, 1] == pytest.approx(1e-6)
    assert with_var.covariance[0, 0] > fit.covariance[0, 0]
    assert with_var.covariance[0, 1] < 0  # a larger beta means a smaller alpha
    # works from 3 (inlier) points, where the full fit refuses
    three = np.setdiff1d(np.arange(len(d)), out)[:3]
    few = fit_scale_only(d[three], depth[three], beta=BETA)
    assert few.ok and abs(few.alpha - ALPHA) / ALPHA < 0.1
    assert fit_affine(d[three], depth[three]).status == FitStatus.TOO_FEW_POINTS
    assert fit_scale_only(d[three[:2]], depth[three[:2]], beta=BETA).status == FitStatus.TOO_FEW_POINTS


# ----------------------------------------------------------------------------- maps


def _ok_fit():
    rng = np.random.default_rng(14)
    d, depth, sd, _ = make_points(rng, n=300)
    fit = fit_affine(d, depth, sd)
    assert fit.ok
    return fit


def test_metric_depth_marks_non_positive_and_far_as_nan():
    fit = _ok_fit()
    disparity = np.array([[0.5, 1.0], [-fit.beta / fit.alpha - 0.1, np.nan]], dtype=np.float32)
    depth = metric_depth(disparity, fit)
    assert depth.dtype == np.float32
    assert depth[0, 0] == pytest.approx(1.0 / (fit.alpha * 0.5 + fit.beta), rel=1e-5)
    assert np.isnan(depth[1, 0]) and np.isnan(depth[1, 1])  # alpha*d + beta < 0, NaN input
    capped = metric_depth(disparity, fit, max_depth=float(depth[0, 1]) + 0.01)
    assert np.isnan(capped[0, 0]) and np.isfinite(capped[0, 1])


def test_metric_depth_refuses_a_failed_fit():
    bad = fit_affine(np.ones(3), np.ones(3))
    with pytest.raises(InputError):
        metric_depth(np.ones((2, 2)), bad)
    with pytest.raises(InputError):
        depth_sigma_map(np.ones((2, 2)), bad)


def test_depth_sigma_map_matches_sampling_of_the_parameters():
    fit = _ok_fit()
    disparity = np.array([[0.1, 0.5, 1.0]])
    sigma = depth_sigma_map(disparity, fit)
    rng = np.random.default_rng(15)
    ab = rng.multivariate_normal([fit.alpha, fit.beta], fit.covariance, size=20000)
    samples = 1.0 / (ab[:, :1] * disparity[0] + ab[:, 1:])
    # first-order propagation vs the sampled spread: within 5 % (parameters are ~1 % uncertain)
    np.testing.assert_allclose(sigma[0], samples.std(axis=0), rtol=0.05)
    assert np.isnan(depth_sigma_map(np.array([[-10.0]]), fit)[0, 0])


# ----------------------------------------------------------------------------- rescaler


def _frame(rng, kind, alpha=ALPHA, beta=BETA):
    if kind == "good":
        return make_points(rng, n=300, alpha=alpha, beta=beta)[:3]
    if kind == "narrow":  # only a narrow depth band: ill-conditioned for (alpha, beta)
        return make_points(rng, n=300, alpha=alpha, beta=beta, d_range=(0.60, 0.61))[:3]
    if kind == "two":
        return make_points(rng, n=2, alpha=alpha, beta=beta)[:3]
    raise ValueError(kind)


def test_rescaler_fallback_order():
    rng = np.random.default_rng(16)
    # the fallback mechanism, under a bound loose enough for the carried fit (0.10, the bound
    # before issue 20; the default 0.03 refuses carried fits older than about a frame)
    r = Rescaler(RescalerSettings(temporal=None, max_fallback_age=3, max_fit_error=0.10))
    first = r.update(*_frame(rng, "good"))
    assert first.source == FitSource.FRAME and _status(first) == FrameStatus.OK
    # 1. ill-conditioned frame: scale-only with beta of the last good frame (alpha has changed)
    second = r.update(*_frame(rng, "narrow", alpha=0.36))
    assert second.raw.status == FitStatus.ILL_CONDITIONED
    assert second.source == FitSource.SCALE_ONLY and _status(second) == FrameStatus.FALLBACK_SCALE_ONLY
    assert second.fit.beta == first.fit.beta
    assert abs(second.fit.alpha - 0.36) / 0.36 < 0.02
    # 2. too few points even for the scale-only fit: the previous fit (the scale-only one)
    third = r.update(*_frame(rng, "two"))
    assert third.raw.status == FitStatus.TOO_FEW_POINTS
    assert third.scale_only.status == FitStatus.TOO_FEW_POINTS
    assert third.source == FitSource.PREVIOUS_FIT and third.age == 1
    assert third.n_inliers == second.fit.n_inliers and third.raw.n_inliers == 0
    assert third.fit.alpha == second.fit.alpha and _status(third) == FrameStatus.FALLBACK_PREVIOUS_FIT
    assert third.has_depth and third.metric_depth(np.ones((2, 2))) is not None
    # 3. once the last good frame is older than max_fallback_age: no metric depth
    r.update(np.zeros(0), np.zeros(0))  # age 3: still previous fit
    fifth = r.update(np.zeros(0), np.zeros(0))  # age 4 > 3
    assert fifth.source == FitSource.NONE and fifth.fit is None and not fifth.has_depth
    assert _status(fifth) == FrameStatus.TOO_FEW_POINTS
    assert fifth.metric_depth(np.ones((2, 2))) is None
    assert "max_fallback_age" in fifth.reason


def test_rescaler_without_history_or_fallback_gives_none():
    rng = np.random.default_rng(17)
    r = Rescaler(RescalerSettings(temporal=None))
    res = r.update(*_frame(rng, "narrow"))
    assert res.source == FitSource.NONE and _status(res) == FrameStatus.ILL_CONDITIONED
    paper = Rescaler(RESCALER_PRESETS["paper"])
    assert paper.update(*_frame(rng, "good")).source == FitSource.FRAME
    res = paper.update(*_frame(rng, "narrow"))
    assert res.source == FitSource.NONE and "fallbacks disabled" in res.reason


def test_rescaler_no_consensus_maps_to_frame_status():
    rng = np.random.default_rng(18)
    d = rng.uniform(0.1, 1.0, 300)
    depth = np.exp(rng.uniform(0.0, np.log(80.0), 300))
    res = Rescaler(RescalerSettings(temporal=None)).update(d, depth)
    assert res.source == FitSource.NONE and _status(res) == FrameStatus.NO_CONSENSUS


def test_rescaler_presets():
    assert RESCALER_PRESETS.get_preset("per_frame", ransac=RansacSettings(seed=3)) == \
        RescalerSettings(RansacSettings(seed=3), temporal=None)
    assert set(RESCALER_PRESETS) == {"paper", "per_frame", "streaming"}
    assert RESCALER_PRESETS["streaming"].temporal is not None
    assert RESCALER_PRESETS["per_frame"].temporal is None and RESCALER_PRESETS["per_frame"].fallback
    with pytest.raises(UnknownNameError) as info:
        RESCALER_PRESETS["kalman"]
    assert "streaming" in str(info.value)
