"""A fit on few points: its covariance must cover the actual error at the stated rate.

The covariance of ``(alpha, beta)`` is scaled by the residual scatter (the reduced
chi-square), which a fit on n points estimates from only n - 2 degrees of freedom. Taken at
face value, the actual error of a fit on 10-14 points falls outside its predicted 95 %
interval in 7-9 % of fits (Student t with n - 2 degrees of freedom, not a Gaussian). The street sample's
first pair (21 inliers) was written with AbsRel 0.057 against a predicted error of 0.027.
"""

import math

import numpy as np
import pytest

from vio_depth.rescale import RansacSettings, fit_affine
from vio_depth.rescale.affine import metric_disparity_sigma
from vio_depth.rescale.depthmap import expected_relative_error
from vio_depth.rescale.msac import scale_inflation

ALPHA, BETA = 0.4, 0.02  # 1/m per unit d, 1/m: depths 2-24 m over d in [0.1, 1.0]
Z95 = 1.959963984540054
K_TRI = 0.02  # 1/m: a triangulated depth's sigma is K z^2 (z^2 sigma_px / (baseline f))


def _coverage(n: int, trials: int, settings: RansacSettings, seed: int = 0) -> float:
    """Fraction of ``trials`` fits on ``n`` points whose actual relative depth error at the
    extreme disparities (where the line is least certain) lies within 1.96 predicted sigma.

    Each point's metric disparity has Gaussian noise 0.3 x its stated sigma (stated sigmas
    are pessimistic, as the triangulation's are: chi2/dof ~ 0.05-0.1 on the street sample);
    the fit must learn the scale from the residuals.
    """
    rng = np.random.default_rng(seed)
    probe = np.array([[0.1, 1.0]])  # (1, 2) disparities at which the error is predicted
    m_true = ALPHA * probe[0] + BETA
    covered = total = 0
    for _ in range(trials):
        d = rng.uniform(0.1, 1.0, n)
        m = ALPHA * d + BETA
        sigma_m = metric_disparity_sigma(1.0 / m, K_TRI / m**2, settings, predicted_disparity=m)
        depth = 1.0 / (m + 0.3 * sigma_m * rng.standard_normal(n))
        # stated as a triangulation states it: sigma_z = K z^2 at the triangulated z
        fit = fit_affine(d, depth, K_TRI * depth**2, settings=settings)
        if not fit.ok:
            continue
        for j in range(probe.shape[1]):
            one = probe[:, j:j + 1]
            predicted = expected_relative_error(one, fit.alpha, fit.beta, fit.covariance)
            sigma_rel = predicted / math.sqrt(2.0 / math.pi)  # E|e| = sqrt(2/pi) sigma
            m_hat = fit.alpha * one[0, 0] + fit.beta
            actual = abs(m_hat - m_true[j]) / m_hat
            covered += actual <= Z95 * sigma_rel
            total += 1
    assert total >= trials  # nearly every fit is OK
    return covered / total


@pytest.mark.parametrize("n", [10, 14])
def test_few_point_fit_covers_the_actual_error_at_the_stated_rate(n):
    # 1500 fits x 2 probes: the coverage's standard error is ~0.004; the point estimate of
    # the scale gives 0.911 (n=10) and 0.927 (n=14), the t distribution's rate at 1.96
    coverage = _coverage(n, 1500, RansacSettings())
    assert coverage >= 0.95 - 0.01


def test_the_point_estimate_of_the_scale_undercovers():
    """What the test above guards against: without the inflation the rate is the t's."""
    coverage = _coverage(10, 1500, RansacSettings(scale_confidence=0.0))
    assert coverage < 0.93


def test_scale_inflation_values():
    assert scale_inflation(10, 0.0) == 1.0
    # chi-square(19) 5 % quantile is 10.117: 19 / 10.117 = 1.878
    assert scale_inflation(19, 0.95) == pytest.approx(1.878, abs=1e-3)
    # it vanishes with many degrees of freedom and grows with fewer
    assert scale_inflation(5, 0.95) > scale_inflation(19, 0.95) > scale_inflation(98, 0.95) > 1.0
    assert scale_inflation(100_000, 0.95) == pytest.approx(1.0, abs=0.02)
