"""Memoised distribution quantiles shared by the layers that gate or bound with them."""

from __future__ import annotations

import functools

from scipy.stats import chi2


@functools.lru_cache(maxsize=1024)
def chi2_quantile(probability: float, dof: int) -> float:
    """``scipy.stats.chi2.ppf(probability, dof)``, memoised: scipy takes ~0.3 ms a call, and
    the pose-consistency gate and the fit's residual-scale bound ask for the same few values
    thousands of times a sequence."""
    return float(chi2.ppf(probability, dof))
