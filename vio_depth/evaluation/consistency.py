"""Bounds that a consistent estimator's NEES meets (the normalised estimation error squared).

An estimator is consistent when its errors ``e`` (D-dof) and covariances ``C`` agree:
``e^T C^-1 e`` is then chi-square with D degrees of freedom. Over N independent trials:

* the mean NEES is ``chi2(D N) / N``: :func:`mean_nees_bounds`;
* the median lies between the chi-square(D) quantiles at ``1/2 -+ z / (2 sqrt(N))`` (the
  sample median's quantile level is about normal with variance ``1 / (4 N)``):
  :func:`median_nees_bounds`;
* the fraction of trials below the chi-square(D) quantile ``q`` is binomial ``(N, q)``:
  :func:`within_fraction_bound`.

An over-confident estimator (covariance too small by ``k^2``) multiplies every NEES by
``k^2`` and leaves these bounds; the tests apply the same bound to the covariance divided by
9 (sigma / 3) to show that it fails (tests/vio_depth/vio/test_estimator.py and the others).
"""

from __future__ import annotations

import numpy as np
from scipy.stats import chi2, norm

from vio_core.checks import check_array
from vio_core.errors import InputError


def nees(errors, covariances) -> np.ndarray:
    """``errors: (N, D)``, ``covariances: (N, D, D)`` -> (N,) ``e^T C^-1 e``."""
    e = check_array("errors", errors, (None, None), finite=True)
    C = check_array("covariances", covariances, (len(e), e.shape[1], e.shape[1]), finite=True)
    return np.einsum("nd,nd->n", e, np.linalg.solve(C, e[:, :, None])[:, :, 0])


def _check(dof: int, trials: int, probability: float) -> None:
    if dof < 1 or trials < 1 or not 0.0 < probability < 1.0:
        raise InputError(f"need dof >= 1, trials >= 1 and 0 < probability < 1, got {dof}, {trials}, {probability}")


def mean_nees_bounds(dof: int, trials: int, probability: float = 0.95) -> tuple[float, float]:
    """Two-sided interval holding the mean NEES of ``trials`` independent ``dof``-dof trials of
    a consistent estimator with ``probability``."""
    _check(dof, trials, probability)
    a = (1.0 - probability) / 2.0
    return float(chi2.ppf(a, dof * trials) / trials), float(chi2.ppf(1.0 - a, dof * trials) / trials)


def median_nees_bounds(dof: int, trials: int, probability: float = 0.95) -> tuple[float, float]:
    """Two-sided interval holding the median NEES of ``trials`` independent ``dof``-dof trials of
    a consistent estimator with ``probability`` (normal approximation of the median's level)."""
    _check(dof, trials, probability)
    half = norm.ppf(0.5 + probability / 2.0) * 0.5 / np.sqrt(trials)
    return float(chi2.ppf(max(0.5 - half, 1e-12), dof)), float(chi2.ppf(min(0.5 + half, 1.0 - 1e-12), dof))


def within_fraction_bound(trials: int, quantile: float = 0.95, probability: float = 0.95) -> float:
    """Smallest fraction of ``trials`` independent NEES below the chi-square ``quantile`` of a
    consistent estimator, one-sided with ``probability`` (normal approximation of the binomial)."""
    _check(1, trials, probability)
    return float(quantile - norm.ppf(probability) * np.sqrt(quantile * (1.0 - quantile) / trials))


__all__ = ["mean_nees_bounds", "median_nees_bounds", "nees", "within_fraction_bound"]
