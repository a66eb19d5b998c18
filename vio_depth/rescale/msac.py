"""Vectorised MSAC + IRLS machinery shared by :func:`~vio_depth.rescale.fit.fit_affine` and
:func:`~vio_depth.rescale.fit.fit_scale_only` (internal: no public names)."""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from vio_core.checks import check_array
from vio_core.stats import chi2_quantile

from .affine import _NAN_COV, AffineFit, FitStatus, RansacSettings

fsum, fmin, fmax = np.add.reduce, np.minimum.reduce, np.maximum.reduce
fall, fany = np.logical_and.reduce, np.logical_or.reduce

# Rows of the per-point basis matrix: every (weighted) sum over an inlier mask is one
# matrix-vector product, ``basis @ mask`` or ``basis @ (w * mask)``.
ONE, D, M, DD, DM, MM = range(6)


def failed_fit(status: FitStatus, reason: str, n_input: int, n_points: int, n_excluded: int,
                iterations: int = 0) -> AffineFit:
    return AffineFit(
        alpha=math.nan, beta=math.nan, covariance=_NAN_COV, inliers=np.zeros(n_input, bool),
        n_points=n_points, n_inliers=0, inlier_ratio=0.0, r2=math.nan, disparity_spread=math.nan,
        relative_spread=math.nan, mean_metric_disparity=math.nan, status=status, reason=reason,
        iterations=iterations, n_excluded=n_excluded,
    )



@dataclass
class Points:
    """Valid points prepared for fitting (internal)."""

    n_input: int
    index: np.ndarray | None  # indices of valid points in the input, None = all valid
    basis: np.ndarray  # (6, N) rows 1, d, m, d^2, d m, m^2 (m = 1/depth)
    g2: np.ndarray | float  # (N,) (sigma_depth / depth^2)^2 + min_sigma_disparity^2, or the floor alone
    c: np.ndarray | None  # (N,) extra weights, None = all ones

    @property
    def n(self) -> int:
        return self.basis.shape[1]

    @property
    def d(self) -> np.ndarray:
        return self.basis[D]

    @property
    def m(self) -> np.ndarray:
        return self.basis[M]

    @property
    def n_excluded(self) -> int:
        return self.n_input - self.n

    def full_mask(self, inliers: np.ndarray) -> np.ndarray:
        if self.index is None:
            return inliers
        out = np.zeros(self.n_input, bool)
        out[self.index[inliers]] = True
        return out


def prepare(d, depth, sigma_depth, weights, settings: RansacSettings) -> Points:
    d = check_array("d", d, (None,))
    n = len(d)
    depth = check_array("depth", depth, (n,))
    sd = None if sigma_depth is None else check_array("sigma_depth", sigma_depth, (n,))
    c = None if weights is None else check_array("weights", weights, (n,))
    # Fast path, a few reductions and no warnings: NaN makes every comparison False; a
    # positive array with a finite sum has no inf. (ufunc reductions are called directly:
    # the ndarray methods add a Python-level wrapper per call.)
    fast = n == 0 or (-math.inf < fmin(d) and fmax(d) < math.inf and fmin(depth) > 0 and fsum(depth) < math.inf)
    if fast and n and sd is not None:
        fast = fmin(sd) >= 0 and fsum(sd) < math.inf
    if fast and n and c is not None:
        fast = fmin(c) > 0 and fsum(c) < math.inf
    index = None
    if not fast:
        # NaN compares False without a warning; inf is caught by the "< inf" tests.
        valid = np.isfinite(d)
        valid &= depth > 0
        valid &= depth < np.inf
        if sd is not None:
            valid &= sd >= 0
            valid &= sd < np.inf
        if c is not None:
            valid &= c > 0
            valid &= c < np.inf
        if not valid.all():
            index = np.flatnonzero(valid)
            d, depth = d[index], depth[index]
            sd = None if sd is None else sd[index]
            c = None if c is None else c[index]
    basis = np.empty((6, len(d)))
    basis[ONE] = 1.0
    dv = basis[D]
    dv[:] = d
    m = basis[M]
    np.divide(1.0, depth, out=m)
    np.multiply(dv, dv, out=basis[DD])
    np.multiply(dv, m, out=basis[DM])
    mm = np.multiply(m, m, out=basis[MM])
    # variance of m that does not depend on the model: geometric term + floor (in quadrature)
    floor2 = float(settings.min_sigma_disparity) ** 2
    if sd is not None:
        g2 = sd * mm
        g2 *= g2
        g2 += floor2
    else:
        g2 = floor2
    return Points(n, index, basis, g2, c)


def model_weights(pts: Points, alpha: float, beta: float, s: RansacSettings) -> tuple[np.ndarray, np.ndarray]:
    """``(inv_sigma (N,), w = c / sigma**2 (N,))`` with the model term of sigma taken at the
    metric disparity ``alpha * d + beta`` predicted by a hypothesis (not the observed one,
    which would bias the weighted fit towards small disparities, i.e. large depths)."""
    k = s.model_relative_sigma
    var = pts.d * (alpha * k)
    var += beta * k
    var *= var
    var += pts.g2
    w = np.divide(1.0, var, out=var)
    inv_sigma = np.sqrt(w)
    if pts.c is not None:
        w *= pts.c
    return inv_sigma, w


def observed_std(pts: Points, s: RansacSettings, sl: slice = slice(None)) -> np.ndarray:
    """(3, n) rows 1, d, m of the points ``sl`` divided by sigma_i with the model term at the
    observed metric disparity (for scoring hypotheses)."""
    g2 = pts.g2 if isinstance(pts.g2, float) else pts.g2[sl]
    var = pts.basis[MM, sl] * s.model_relative_sigma**2
    var += g2
    return pts.basis[:DD, sl] * np.power(var, -0.5, out=var)


@functools.lru_cache(maxsize=8)
def uniform_table(seed: int, size: int) -> np.ndarray:
    """Read-only ``(size, 2)`` table of uniforms in [0, 1) for ``seed`` (cached: creating a
    generator per fit costs more than a whole small fit)."""
    table = np.random.default_rng(seed).random((size, 2))
    table.setflags(write=False)
    return table


def needed_iterations(inlier_ratio: float, sample_size: int, confidence: float) -> float:
    """Hypotheses needed to draw one all-inlier sample with probability ``confidence``."""
    p_good = inlier_ratio**sample_size
    if p_good >= 1.0:
        return 0.0
    if p_good <= 0.0:
        return math.inf
    return math.log(1.0 - confidence) / math.log1p(-p_good)


def scale_inflation(dof: int, confidence: float) -> float:
    """Factor on a reduced chi-square estimated from ``dof`` degrees of freedom that gives
    its upper confidence bound at ``confidence``: ``dof / q`` with ``q`` the chi-square(dof)
    quantile at ``1 - confidence`` (:func:`vio_core.stats.chi2_quantile`); 1 for
    ``confidence`` 0 (the point estimate). Under Gaussian residuals, the residual variance is
    at most ``chi2 * scale_inflation(dof, confidence)`` with probability ``confidence``.

    Args:
        dof: degrees of freedom, >= 1 (inliers minus fitted parameters).
        confidence: in [0, 1).
    """
    if confidence <= 0.0:
        return 1.0
    return float(dof / chi2_quantile(1.0 - confidence, dof))


def exclusion_note(pts: Points) -> str:
    return f"; {pts.n_excluded} point(s) excluded (non-finite, depth <= 0 or weight <= 0)" if pts.n_excluded else ""


PAIR_DIFF = np.array([1.0, -1.0])


def seed_least_squares(best: list[float], inl_s: np.ndarray, std_s: np.ndarray,
                        c_s: np.ndarray | None) -> tuple[float, float]:
    """``(beta, alpha)``: one weighted least squares on the best hypothesis' inliers among
    the scored points (a better seed for :func:`refine` than a 2-point line), or the
    hypothesis itself when that is degenerate or gives alpha <= 0.

    ``std_s``: (3, n) rows 1, d, m divided by sigma_i of the scored points.
    """
    a = std_s[:2] * inl_s if c_s is None else std_s[:2] * (inl_s * c_s)  # rows 1/sigma, d/sigma, masked
    (n11, n12, r1), (_, n22, r2) = (a @ std_s.T).tolist()  # normal equations [[n11, n12], [n12, n22]]
    det = n11 * n22 - n12 * n12
    if det > 0:
        alpha = (n11 * r2 - n12 * r1) / det
        if 0 < alpha < math.inf:
            return (r1 - n12 * alpha) / n11, alpha
    return best[0], best[1]


def irls(beta: float, alpha: float, basis: np.ndarray, std: np.ndarray, w: np.ndarray, t2: float, rounds: int,
          fixed_beta: bool):
    """Local optimisation: iteratively reweighted least squares of the MSAC cost.

    From ``(beta, alpha)``: select the inliers (standardised residual**2 <= t2), solve the
    weighted least squares on them, re-select, and repeat until the inlier set no longer
    changes or ``rounds`` times. With fixed sigma_i each round cannot increase the MSAC
    cost. A round that would give alpha <= 0 or a singular system stops and keeps the
    previous estimate. With ``fixed_beta`` only alpha is solved for.

    Args:
        basis: (6, N) rows 1, d, m, d^2, d m, m^2.
        std: (3, N) rows 1, d, m divided by sigma_i.
        w: (N,) least-squares weights c_i / sigma_i**2.

    Returns:
        ``(beta, alpha, inliers (N,) bool, sums)`` with ``sums`` the six weighted sums
        ``basis @ (w * inliers)`` of the returned inliers.
    """
    ab, y = std[:2], std[2]
    h = np.array([beta, alpha])
    z2 = y - h @ ab
    z2 *= z2
    inl = z2 <= t2
    sums = (basis @ (w * inl)).tolist()  # sums of w, w d, w m, w d^2, w d m, w m^2 over the inliers
    for _ in range(rounds):
        sw, swd, swm, swdd, swdm, _ = sums
        if fixed_beta:
            if not swdd > 0:
                break
            a_new = (swdm - beta * swd) / swdd
            b_new = beta
        else:
            det = sw * swdd - swd * swd
            if not det > 0:
                break
            a_new = (sw * swdm - swd * swm) / det
            b_new = (swm - a_new * swd) / sw
        if not 0 < a_new < math.inf:
            break
        beta, alpha = b_new, a_new  # least squares on `inl`
        h[0], h[1] = b_new, a_new
        z2 = y - h @ ab
        z2 *= z2
        inl_new = z2 <= t2
        if not fany(inl_new != inl):  # same inliers: converged, `sums` still belong to them
            break
        inl = inl_new
        sums = (basis @ (w * inl)).tolist()
    return beta, alpha, inl, sums


def refine(beta: float, alpha: float, pts: Points, s: RansacSettings, fixed_beta: bool,
            d_ref: tuple[float, float]):
    """Local optimisation of the best hypothesis ``(beta, alpha)``.

    sigma_i's model term is taken at the metric disparity predicted by the hypothesis
    (:func:`model_weights`), then :func:`irls` runs with those weights. If the refined line's
    metric disparity differs from the seed's by more than ``s.reweight_tolerance``
    (relative) at either reference disparity ``d_ref``, the weights are recomputed from the
    refined line and the IRLS repeated (at most twice).

    Returns ``(beta, alpha, inliers (N,) bool, weights w (N,), weighted sums or None)``.
    """
    t2 = s.inlier_sigmas**2
    lo, hi = d_ref
    tol = s.reweight_tolerance
    basis3 = pts.basis[:DD]
    for _ in range(3):
        inv_sigma, w = model_weights(pts, alpha, beta, s)
        seed_lo, seed_hi = alpha * lo + beta, alpha * hi + beta
        beta, alpha, inl, sums = irls(beta, alpha, pts.basis, basis3 * inv_sigma, w, t2, s.lo_iterations,
                                       fixed_beta)
        new_lo, new_hi = alpha * lo + beta, alpha * hi + beta
        if abs(seed_lo - new_lo) <= tol * abs(new_lo) and abs(seed_hi - new_hi) <= tol * abs(new_hi):
            break
    return beta, alpha, inl, w, sums


def finish(pts: Points, alpha: float, beta: float, inl: np.ndarray, w_pts: np.ndarray, w_sums: list | None,
            drawn: int, s: RansacSettings, note: str, n_params: int, beta_variance: float = 0.0) -> AffineFit:
    """Diagnostics, covariance and status of a refined estimate (shared by both fits).

    All inlier sums come from matrix-vector products of ``pts.basis``: with the mask
    (unweighted) and with ``w_pts * mask`` (the weights the estimate was refined with; given
    as ``w_sums`` when the refinement already computed them).
    """
    n = pts.n
    u = (pts.basis @ inl).tolist()
    w = w_sums if w_sums is not None else (pts.basis @ (w_pts * inl)).tolist()
    n_in = int(round(u[ONE]))
    ratio = n_in / n
    a, b = alpha, beta
    # sum of (weighted) squared residuals r = m - a d - b from the sums (clamped against rounding)
    chi2_sum = max(w[MM] - 2 * a * w[DM] - 2 * b * w[M] + a * a * w[DD] + 2 * a * b * w[D] + b * b * w[ONE], 0.0)
    ss_res = max(u[MM] - 2 * a * u[DM] - 2 * b * u[M] + a * a * u[DD] + 2 * a * b * u[D] + b * b * u[ONE], 0.0)
    if n_in > 0:
        mean_d = u[D] / n_in
        spread = math.sqrt(max(u[DD] / n_in - mean_d * mean_d, 0.0))
        ss_tot = u[MM] - u[M] * u[M] / n_in
        r2 = 1.0 - ss_res / ss_tot if ss_tot > 0 else math.nan
        mean_fit = a * mean_d + b
        rel_spread = a * spread / mean_fit if mean_fit > 0 else math.nan
    else:
        r2 = spread = mean_fit = rel_spread = math.nan
    cov = _NAN_COV
    if n_in > n_params:
        dof = n_in - n_params
        # the scatter's upper confidence bound: a few residuals may be luckily small
        chi2 = chi2_sum / dof * scale_inflation(dof, s.scale_confidence)
        sw, swd, swdd = w[ONE], w[D], w[DD]
        if n_params == 2:
            det = sw * swdd - swd * swd
            if det > 0:
                f = chi2 / det
                cov = np.array([[f * sw, -f * swd], [-f * swd, f * swdd]])
        elif swdd > 0:
            # alpha = sum w d (m - beta) / sum w d^2 with beta known up to beta_variance
            g = swd / swdd  # -d alpha / d beta
            vb = beta_variance if np.isfinite(beta_variance) and beta_variance > 0 else 0.0
            cov = np.array([[chi2 / swdd + g * g * vb, -g * vb], [-g * vb, vb]])
    need = max(s.min_inliers if n_params == 2 else s.scale_only_min_points, math.ceil(s.min_inlier_ratio * n))
    if n_in < need:
        status, reason = FitStatus.NO_CONSENSUS, f"{n_in} inlier(s) of {n} points (ratio {ratio:.2f}), need {need}"
    elif not alpha > 0:
        status, reason = FitStatus.NO_CONSENSUS, f"alpha = {alpha:.4g} is not > 0"
    elif n_params == 2 and not rel_spread >= s.min_relative_spread:
        status, reason = FitStatus.ILL_CONDITIONED, (
            f"inliers span too narrow a disparity range to separate scale from shift: relative "
            f"spread {rel_spread:.3g} < min_relative_spread {s.min_relative_spread:g}")
    elif not r2 > 0:
        status, reason = FitStatus.NO_CONSENSUS, (
            f"R^2 = {r2:.3g} <= 0: the line explains none of the inliers' spread of 1/depth")
    else:
        status, reason = FitStatus.OK, f"{n_in}/{n} inliers"
    return AffineFit(alpha, beta, cov, pts.full_mask(inl), n, n_in, ratio, r2, spread, rel_spread, mean_fit, status,
                     reason + note, drawn, pts.n_excluded, np.zeros((2, 2)) if np.isfinite(cov).all() else _NAN_COV,
                     model_relative_sd(pts, alpha, beta, inl))


def model_relative_sd(pts: Points, alpha: float, beta: float, inl: np.ndarray) -> float:
    """Robust sd (1.4826 MAD) of the inliers' relative residuals ``(m - alpha*d - beta) /
    (alpha*d + beta)`` (see :attr:`AffineFit.model_relative_sd`); NaN with fewer than 3 inliers."""
    if fsum(inl) < 3 or not (np.isfinite(alpha) and np.isfinite(beta)):
        return math.nan
    d, m = pts.d[inl], pts.m[inl]
    with np.errstate(invalid="ignore", divide="ignore"):
        pred = alpha * d + beta
        rel = np.abs(m - pred) / pred
    total = 1.4826 * float(np.median(rel))
    return total if math.isfinite(total) else math.nan
