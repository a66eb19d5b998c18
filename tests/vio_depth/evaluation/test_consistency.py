"""The NEES bounds (vio_depth.evaluation.consistency) hold what they promise: Monte Carlo
draws of a consistent estimator fall inside them at the stated rate, an over-confident
one (covariance / 9) does not."""

import numpy as np
import pytest

from vio_core.errors import InputError
from vio_depth.evaluation import mean_nees_bounds, median_nees_bounds, nees, within_fraction_bound


def test_nees_is_the_normalised_squared_error():
    rng = np.random.default_rng(0)
    A = rng.normal(size=(5, 3, 3))
    C = A @ A.transpose(0, 2, 1) + np.eye(3)
    e = rng.normal(size=(5, 3))
    expected = [x @ np.linalg.solve(c, x) for x, c in zip(e, C)]
    np.testing.assert_allclose(nees(e, C), expected, rtol=1e-12)


@pytest.mark.parametrize("dof, trials", [(1, 400), (3, 50), (6, 15)])
def test_bounds_cover_a_consistent_estimator_at_the_stated_rate(dof, trials):
    """4000 experiments of ``trials`` chi-square(dof) draws: the mean and the median fall in their
    95 % intervals 95 % of the time (+-2 %: the normal approximation of the median's level and
    the Monte Carlo error), the fraction below the 95 % quantile is above its one-sided 95 %
    bound at least 92 % of the time; an estimator whose covariance is 9x too small leaves
    the mean interval every time."""
    rng = np.random.default_rng(dof)
    draws = rng.chisquare(dof, size=(4000, trials))
    lo, hi = mean_nees_bounds(dof, trials, 0.95)
    means = draws.mean(1)
    assert abs(np.mean((means > lo) & (means < hi)) - 0.95) < 0.02
    assert np.all(9.0 * means > hi)
    mlo, mhi = median_nees_bounds(dof, trials, 0.95)
    medians = np.median(draws, axis=1)
    assert abs(np.mean((medians > mlo) & (medians < mhi)) - 0.95) < 0.03
    q95 = np.quantile(rng.chisquare(dof, 200000), 0.95)
    fractions = np.mean(draws <= q95, axis=1)
    assert np.mean(fractions >= within_fraction_bound(trials, 0.95, 0.95)) > 0.92


def test_bad_arguments_are_refused():
    with pytest.raises(InputError):
        mean_nees_bounds(0, 10)
    with pytest.raises(InputError):
        median_nees_bounds(3, 0)
    with pytest.raises(InputError):
        within_fraction_bound(10, probability=1.0)
