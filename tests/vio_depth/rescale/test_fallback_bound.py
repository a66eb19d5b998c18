"""Issue 12, case 6 (fallbacks): a frame that reuses an older fit says so, follows the
network's renormalisation of this frame, and is written only while its predicted error
stays within the same bound as every frame's own fit, ``RescalerSettings.max_fit_error``.

The scene: a fixed metric disparity map ``q`` (a tilted plane, 2-20 m). Each frame's
affine-invariant disparity is ``d_t = s_t * q + h_t`` with a random per-frame scale and
shift, as Depth Anything (and the SIMULATED disparity) renormalise every frame. Frames
0-4 have metric points; later frames have none, so they fall back.
"""

import numpy as np
import pytest

from vio_core.errors import SettingsError
from vio_depth.rescale import (
    FitSource,
    Rescaler,
    RescalerSettings,
    expected_relative_error,
    metric_depth,
    predicted_relative_error,
)

H, W = 48, 64


def _scene():
    vv, uu = np.mgrid[0:H, 0:W]
    depth = 2.0 + 18.0 * (vv / (H - 1)) * (0.6 + 0.4 * uu / (W - 1))  # metres, 2 .. 20
    return depth, 1.0 / depth


def _frame(rng, q, with_points: bool):
    s, h = rng.uniform(5.0, 20.0), rng.uniform(-0.05, 0.05)
    d_map = (s * q + h).astype(np.float32)
    if not with_points:
        return d_map, np.zeros(0), np.zeros(0), np.zeros(0)
    v, u = rng.integers(0, H, 300), rng.integers(0, W, 300)
    depth = 1.0 / q[v, u] * (1 + 0.01 * rng.standard_normal(300))
    return d_map, d_map[v, u].astype(np.float64), depth, 0.01 * depth


@pytest.mark.parametrize("temporal", [True, False])
def test_previous_fit_follows_the_renormalisation_and_stops_at_the_bound(temporal):
    rng = np.random.default_rng(3)
    gt, q = _scene()
    # the mechanism, under the bound before issue 20 (0.10): the default 0.03 refuses carried
    # fits older than about a frame
    settings = RescalerSettings(max_fit_error=0.10) if temporal else RescalerSettings(temporal=None, max_fit_error=0.10)
    r = Rescaler(settings)
    for _ in range(5):
        d_map, d, depth, sigma = _frame(rng, q, True)
        assert r.update(d, depth, sigma, disparity_map=d_map).source == FitSource.FRAME
    errors, predicted, ages = [], [], []
    for _ in range(10):
        d_map, d, depth, sigma = _frame(rng, q, False)
        res = r.update(d, depth, sigma, disparity_map=d_map)
        if res.source == FitSource.NONE:
            assert "fallback refused: predicted relative depth error" in res.reason
            assert res.predicted_error > settings.max_fit_error
            break
        assert res.source == FitSource.PREVIOUS_FIT and "previous fit" in res.reason
        depth_map = metric_depth(d_map, res.fit)
        errors.append(float(np.nanmean(np.abs(depth_map - gt) / gt)))
        predicted.append(res.predicted_error)
        ages.append(res.age)
        assert res.predicted_error == pytest.approx(
            expected_relative_error(d_map, res.fit.alpha, res.fit.beta, res.fit.covariance), rel=1e-6)
    # the scene did not change, only the network's normalisation: the carried fit stays exact
    # (a reused alpha, beta would be off by the ratio of the per-frame scales, 0.25x-4x)
    assert max(errors) < 0.02, errors
    # the predicted error grows with age (random-walk model), and ends the fallback
    assert predicted == sorted(predicted) and all(p <= settings.max_fit_error for p in predicted)
    assert 2 <= len(ages) < 10 and ages == list(range(1, len(ages) + 1))


def test_the_bound_is_a_validated_setting():
    with pytest.raises(SettingsError, match="max_fallback_error"):
        RescalerSettings(max_fallback_error=0.0)
    with pytest.raises(SettingsError, match="max_fallback_error"):
        RescalerSettings(max_fallback_error=float("nan"))
    with pytest.raises(SettingsError, match="max_fit_error"):
        RescalerSettings(max_fit_error=0.0)
    # a fallback obeys the same bound as the frame's own fit, never a looser one
    with pytest.raises(SettingsError, match="must not exceed max_fit_error"):
        RescalerSettings(max_fit_error=0.05, max_fallback_error=0.1)
    assert RescalerSettings().max_fallback_error is None
    assert RescalerSettings(max_fit_error=0.05).fallback_bound == 0.05
    assert RescalerSettings(max_fit_error=0.05, max_fallback_error=0.02).fallback_bound == 0.02


def test_expected_relative_error_is_sqrt_2_over_pi_times_the_median_sigma():
    from vio_depth.rescale import AffineFit, FitStatus

    d = np.linspace(1.0, 3.0, 200).reshape(10, 20).astype(np.float32)
    cov = np.diag([1e-4, 1e-6])
    m = 0.1 * d.astype(np.float64) + 0.01
    rel2 = (d.astype(np.float64) ** 2 * 1e-4 + 1e-6) / m**2
    want = np.sqrt(2 / np.pi) * np.sqrt(np.median(rel2))
    assert expected_relative_error(d, 0.1, 0.01, cov) == pytest.approx(want, rel=1e-6)
    # an error no rescaling removes adds in quadrature, pixel by pixel
    want = np.sqrt(2 / np.pi) * np.sqrt(np.median(rel2 + 0.02**2))
    assert expected_relative_error(d, 0.1, 0.01, cov, 0.02) == pytest.approx(want, rel=1e-6)
    fit = AffineFit(0.1, 0.01, np.full((2, 2), np.nan), np.zeros(0, bool), 0, 0, 0.0, 0.0, 0.0, 0.0, 0.0,
                    FitStatus.OK)
    assert expected_relative_error(d, fit.alpha, fit.beta, fit.covariance) == float("inf")


def test_predicted_relative_error_is_the_median_relative_sigma():
    from vio_depth.rescale import AffineFit, FitStatus

    d = np.linspace(1.0, 3.0, 200).reshape(10, 20).astype(np.float32)
    cov = np.diag([1e-4, 1e-6])
    fit = AffineFit(0.1, 0.01, cov, np.zeros(0, bool), 0, 0, 0.0, 0.0, 0.0, 0.0, 0.0, FitStatus.OK)
    m = 0.1 * d.astype(np.float64) + 0.01
    rel = np.sqrt(d.astype(np.float64) ** 2 * 1e-4 + 1e-6) / m
    assert predicted_relative_error(d, fit) == pytest.approx(float(np.median(rel)), rel=1e-6)
