"""Tests of vio_depth/temporal.py: the anchored Kalman filter and its use by the Rescaler."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest
from scipy.stats import chi2

from vio_core.errors import InputError, SettingsError
from vio_depth.rescale import FitSource, Rescaler, RescalerSettings
from vio_depth.rescale.temporal import (
    AffineKalmanFilter,
    KalmanSettings,
    anchors_from_map,
    anchors_from_points,
    inflate_covariance,
)

ALPHA, BETA = 0.2, 0.01
ANCHORS = (0.2, 0.9)  # the frame's anchor disparities: m = 0.05 and 0.19 1/m there
SIGMA_A, SIGMA_B = 0.004, 0.0005  # per-frame measurement noise (2 % of alpha, 5 % of beta)
COV = np.diag([SIGMA_A**2, SIGMA_B**2])


@dataclass
class Measurement:
    alpha: float
    beta: float
    covariance: np.ndarray


def noisy(rng, alpha=ALPHA, beta=BETA) -> Measurement:
    return Measurement(alpha + SIGMA_A * rng.standard_normal(), beta + SIGMA_B * rng.standard_normal(), COV)


SLOW = KalmanSettings(process_sigma=0.003, measurement_floor=0.0)


def test_gate_threshold_is_the_chi2_quantile():
    for p in (0.95, 0.99, 0.999):
        assert KalmanSettings(gate_probability=p).gate_threshold == pytest.approx(chi2.ppf(p, 2), rel=1e-9)


def test_settings_are_validated():
    with pytest.raises(SettingsError):
        KalmanSettings(gate_probability=1.0)
    with pytest.raises(SettingsError):
        KalmanSettings(process_sigma=-0.1)
    with pytest.raises(SettingsError):
        KalmanSettings(reset_after_rejections=0)
    with pytest.raises(SettingsError):
        KalmanSettings(anchor_quantiles=(0.9, 0.1))


def test_anchors_are_quantiles_of_the_map_or_the_inliers():
    s = KalmanSettings(anchor_quantiles=(0.25, 0.75))
    d = np.arange(11, dtype=float)
    inl = np.ones(11, bool)
    inl[10] = False
    assert anchors_from_points(d, inl, s) == (2.25, 6.75)
    with pytest.raises(InputError):
        anchors_from_points(d, np.zeros(11, bool))
    disparity = np.arange(100, dtype=float).reshape(10, 10)
    disparity[0, 0] = np.nan  # ignored
    lo, hi = anchors_from_map(disparity, s)
    assert lo == pytest.approx(np.quantile(np.arange(1, 100), 0.25)) and hi == pytest.approx(74.5)
    big = np.tile(np.linspace(0.0, 1.0, 1000), (1000, 1))  # subsampled: quantiles barely move
    lo, hi = anchors_from_map(big, s)
    assert lo == pytest.approx(0.25, abs=0.005) and hi == pytest.approx(0.75, abs=0.005)
    with pytest.raises(InputError):
        anchors_from_map(np.ones((5, 5)), s)


def test_first_measurement_initialises():
    kf = AffineKalmanFilter(SLOW)
    assert kf.step(None) is None and not kf.initialized
    m = noisy(np.random.default_rng(0))
    est = kf.step(m, ANCHORS)
    assert kf.initialized and est.reset and est.accepted
    assert est.alpha == pytest.approx(m.alpha) and est.beta == pytest.approx(m.beta)
    np.testing.assert_allclose(est.covariance, m.covariance, rtol=1e-9, atol=1e-15)
    with pytest.raises(InputError):
        kf.step(m, None)


def test_reduces_variance_of_constant_parameters():
    rng = np.random.default_rng(1)
    kf = AffineKalmanFilter(SLOW)
    raw, filt = [], []
    for _ in range(200):
        m = noisy(rng)
        est = kf.step(m, ANCHORS)
        raw.append((m.alpha, m.beta))
        filt.append((est.alpha, est.beta))
    raw, filt = np.array(raw[50:]), np.array(filt[50:])  # after warm-up
    # process noise 0.3 %/frame vs ~2 % measurement noise at the anchors: strong smoothing
    assert filt[:, 0].var() < raw[:, 0].var() / 3
    assert filt[:, 1].var() < raw[:, 1].var() / 3
    assert abs(filt[:, 0].mean() - ALPHA) < 3 * SIGMA_A / math.sqrt(10)
    assert est.covariance[0, 0] < SIGMA_A**2 / 3  # and says so


def test_invariant_to_per_frame_renormalisation():
    # The network rescales and shifts its output every frame (d = s_t q + h_t): the correct
    # (alpha_t, beta_t) = (1/s_t, -h_t/s_t) jump, the anchors move with d. The filter must
    # neither gate these jumps nor lag behind them, yet still smooth the noise.
    rng = np.random.default_rng(2)
    kf = AffineKalmanFilter(SLOW)
    q_anchor = np.array([0.05, 0.19])  # true metric disparity at the anchors (static scene)
    err_raw, err_filt, gated = [], [], 0
    for t in range(150):
        s_t = rng.uniform(5.0, 20.0)
        h_t = rng.uniform(0.005, 0.03) * s_t * 0.3
        a_t, b_t = 1.0 / s_t, -h_t / s_t
        cov = np.diag([(0.02 * a_t) ** 2, (0.002 * 0.2) ** 2])
        meas = Measurement(a_t * (1 + 0.02 * rng.standard_normal()), b_t + 0.0004 * rng.standard_normal(), cov)
        est = kf.step(meas, tuple(s_t * q_anchor + h_t))
        assert t == 0 or not est.reset  # never taken for a scene change
        gated += not est.accepted
        if t >= 30:
            err_raw.append(meas.alpha / a_t - 1)
            err_filt.append(est.alpha / a_t - 1)
    # a consistent measurement is gated out with probability 1 - gate_probability = 0.1 %
    assert gated <= 3
    assert np.std(err_filt) < 0.6 * np.std(err_raw)
    assert abs(np.mean(err_filt)) < 0.01


def test_gates_a_single_outlier_measurement():
    rng = np.random.default_rng(3)
    kf = AffineKalmanFilter(SLOW)
    for _ in range(30):
        kf.step(noisy(rng), ANCHORS)
    before = kf.step(noisy(rng), ANCHORS)
    est = kf.step(Measurement(0.3, BETA, COV), ANCHORS)  # +50 % scale for one frame
    assert not est.accepted and not est.reset and est.mahalanobis2 > SLOW.gate_threshold
    assert abs(est.alpha - before.alpha) / before.alpha < 0.01  # the prediction is used
    after = kf.step(noisy(rng), ANCHORS)
    assert after.accepted and not after.reset  # one rejection does not restart the filter
    assert abs(after.alpha - ALPHA) / ALPHA < 0.03


def test_follows_a_step_change_after_reset():
    rng = np.random.default_rng(4)
    kf = AffineKalmanFilter(SLOW)  # two gated measurements in a row restart the filter
    for _ in range(30):
        kf.step(noisy(rng), ANCHORS)
    first = kf.step(noisy(rng, alpha=0.3), ANCHORS)  # a scene change: the true line moves
    assert not first.accepted
    second = kf.step(noisy(rng, alpha=0.3), ANCHORS)
    assert second.reset and second.accepted
    assert abs(second.alpha - 0.3) / 0.3 < 0.05
    for _ in range(10):
        est = kf.step(noisy(rng, alpha=0.3), ANCHORS)
        assert est.accepted and not est.reset
    assert abs(est.alpha - 0.3) / 0.3 < 0.03


def test_prediction_inflates_covariance_and_stale_state_restarts():
    rng = np.random.default_rng(5)
    s = KalmanSettings(process_sigma=0.01, measurement_floor=0.0, max_steps_without_update=3)
    kf = AffineKalmanFilter(s)
    last = kf.step(noisy(rng), ANCHORS)
    pred = kf.step(None)
    assert not pred.accepted and pred.alpha == pytest.approx(last.alpha)
    expected = inflate_covariance(last.alpha, last.beta, last.covariance, 1, ANCHORS, s)
    np.testing.assert_allclose(pred.covariance, expected, rtol=1e-9)
    assert pred.covariance[0, 0] > last.covariance[0, 0]
    for _ in range(3):
        kf.step(None)
    est = kf.step(noisy(rng, alpha=0.25), ANCHORS)
    assert est.reset and "no update for 4 frames" in est.reason
    assert est.alpha == pytest.approx(0.25, rel=0.05)


def test_inflate_covariance_adds_relative_process_noise_at_the_anchors():
    s = KalmanSettings(process_sigma=0.1)
    out = inflate_covariance(ALPHA, BETA, np.zeros((2, 2)), 4, ANCHORS, s)
    # back at the anchors, m = alpha d + beta has standard deviation 0.1 * sqrt(4) * m
    m = ALPHA * np.array(ANCHORS) + BETA
    A = np.array([[ANCHORS[0], 1.0], [ANCHORS[1], 1.0]])
    np.testing.assert_allclose(np.sqrt(np.diag(A @ out @ A.T)), 0.2 * m, rtol=1e-9)


def test_explicit_reset():
    kf = AffineKalmanFilter(SLOW)
    kf.step(noisy(np.random.default_rng(6)), ANCHORS)
    kf.reset()
    assert not kf.initialized and kf.step(None) is None


def _scene(rng, n_pixels=4000):
    """True metric disparity q of a static scene's pixels (depths 3-50 m)."""
    return 1.0 / rng.uniform(3.0, 50.0, n_pixels)


def _frame(rng, q_scene, n_points=80):
    """One frame: a renormalised disparity of the scene (d = s q + h, per-frame s, h) and
    n_points noisy metric points at random pixels."""
    s_t = rng.uniform(5.0, 20.0)
    h_t = rng.uniform(0.0, 0.3)
    d_map = s_t * q_scene + h_t
    idx = rng.choice(len(q_scene), n_points, replace=False)
    depth = 1.0 / (q_scene[idx] * (1 + 0.05 * rng.standard_normal(n_points)))
    return d_map, d_map[idx], depth


def test_rescaler_filter_reduces_frame_to_frame_jitter_of_median_depth():
    rng = np.random.default_rng(7)
    q = _scene(rng)
    plain = Rescaler(RescalerSettings(temporal=None))
    # a static scene: the anchors' metric disparities barely move, so a small process noise
    filtered = Rescaler(RescalerSettings(temporal=KalmanSettings(process_sigma=0.01)))
    med_plain, med_filt = [], []
    for _ in range(60):
        d_map, d, depth = _frame(rng, q)
        r1, r2 = plain.update(d, depth), filtered.update(d, depth, disparity_map=d_map[None])
        assert r1.source == FitSource.FRAME and r2.source == FitSource.FRAME
        assert r2.filtered is not None and r2.filtered.accepted and r2.raw.alpha == r1.raw.alpha
        med_plain.append(np.median(r1.metric_depth(d_map[None])))
        med_filt.append(np.median(r2.metric_depth(d_map[None])))
    true_median = np.median(1.0 / q)
    jitter_plain = np.std(np.diff(med_plain[10:]))
    jitter_filt = np.std(np.diff(med_filt[10:]))
    assert jitter_filt < 0.5 * jitter_plain
    assert abs(np.mean(med_filt[10:]) / true_median - 1) < 0.02


def test_rescaler_previous_fit_covariance_grows_with_the_filter():
    rng = np.random.default_rng(8)
    q = _scene(rng)
    r = Rescaler(RescalerSettings(temporal=KalmanSettings(), max_fit_error=0.10))
    d_map, d, depth = _frame(rng, q, n_points=200)
    ok = r.update(d, depth, disparity_map=d_map[None])
    assert ok.source == FitSource.FRAME
    prev = r.update(np.zeros(0), np.zeros(0))
    assert prev.source == FitSource.PREVIOUS_FIT and prev.age == 1
    assert prev.fit.alpha == ok.fit.alpha
    assert prev.fit.covariance[0, 0] > ok.fit.covariance[0, 0]
