"""Robust per-image fits of ``1/D = alpha*d + beta`` against sparse metric points.

Model (the paper's Method section): the metric disparity of a pixel is affine in the
network's affine-invariant disparity ``d``::

    1 / D = alpha * d + beta,    alpha > 0

``(alpha, beta)`` are fitted per image against sparse metric points (triangulated by the
SfM front end, or simulated LiDAR / random ground-truth samples). The regression target is
the *metric disparity* ``m = 1 / depth`` (1/m).

What differs from the paper's ``sklearn.linear_model.RANSACRegressor`` at its defaults:

* **Vectorised MSAC with local optimisation** (:func:`fit_affine`): 2-point minimal samples
  are drawn and scored in batches (one ``(B, n)`` array per batch, no Python loop per
  hypothesis) with the truncated-quadratic MSAC cost; the best hypothesis is refined by
  iteratively reweighted least squares on its inliers over all points; the number of
  hypotheses adapts to the inlier ratio and ``confidence``; everything is deterministic
  under ``seed``. About 20x faster than the paper's scikit-learn call at 1 000 points, with
  smaller errors (``docs/benchmarks.md``).
* **Stated threshold**: a point is an inlier when ``|r_i| <= inlier_sigmas * sigma_i``, with
  ``sigma_i`` its uncertainty in metric-disparity units (see :func:`metric_disparity_sigma`),
  not the median absolute deviation of the targets.
* **Weights from geometry**: per-point depth uncertainty ``sigma_depth`` (triangulation) and
  optional extra weights (matcher confidence) enter the score and the least squares.
* **alpha > 0** is enforced for every hypothesis and the final fit. Negative or zero
  disparities ``d`` are legitimate input (``d`` is affine-invariant) and are never hidden
  with ``abs()``.
* **Diagnostics and refusal** (:class:`FitStatus`): too few points, a disparity spread too
  narrow to separate scale from shift, or no consensus are reported with a reason; the
  :class:`Rescaler` then falls back in a documented order (see its docstring) and never
  produces a silently wrong map.

Per-pixel uncertainty of the metric depth follows from the (alpha, beta) covariance
(:func:`depth_sigma_map`).
"""


from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from vio_core.checks import check_array
from vio_core.errors import InputError

from .affine import AffineFit, FitStatus, RansacSettings
from .msac import (
    ONE,
    PAIR_DIFF,
    D,
    M,
    exclusion_note,
    failed_fit,
    fall,
    fany,
    finish,
    fsum,
    needed_iterations,
    observed_std,
    prepare,
    refine,
    seed_least_squares,
    uniform_table,
)


def fit_affine(d, depth, sigma_depth=None, weights=None, settings: RansacSettings = RansacSettings(),
               depth_shared=None) -> AffineFit:
    """Robust fit of ``1/depth = alpha * d + beta`` (alpha > 0), vectorised MSAC + LO.

    Hypotheses come from 2-point minimal samples (index pairs from a fixed table of
    uniforms for ``settings.seed``); those with alpha <= 0 are dropped, the others are scored
    ``batch_size`` at a time with the MSAC cost ``sum_i c_i * min((r_i / sigma_i)**2,
    inlier_sigmas**2)`` on at most ``score_points`` points, until ``confidence`` is reached
    for the best one's inlier ratio. The best hypothesis is then refined over all points by
    iteratively reweighted least squares on its inliers (:func:`refine`, :func:`irls`).

    Args:
        d: (N,) affine-invariant disparity at the points (any sign; never ``abs()``-ed).
        depth: (N,) metres, metric depth (camera z) of the points. Points with depth <= 0
            or non-finite values are *excluded* (counted in ``n_excluded`` and the reason),
            not an error, because this runs inside the per-frame loop.
        sigma_depth: (N,) metres, standard deviation of each depth (e.g. triangulation), or
            None; see :class:`RansacSettings` for how it enters sigma_i.
        weights: (N,) extra multiplicative weights ``c_i > 0`` (e.g. matcher confidence), or
            None. They multiply each point's MSAC cost and least-squares weight.
        settings: :class:`RansacSettings`.
        depth_shared: (N, K) metres, or None: the points' depth sensitivities to K
            independent unit-variance errors they share (e.g. the relative pose of the pair
            they were triangulated with, :func:`shared_depth_errors`). ``sigma_depth`` is
            each point's whole (marginal) uncertainty, used for the threshold and the
            weights; these rows say which part of it moves the points together, which the
            least squares cannot average out. Their effect on ``(alpha, beta)`` is added to
            ``covariance`` and reported in ``shared_covariance``.

    Returns:
        :class:`AffineFit`; ``status`` says whether it can be used (never raises on bad data,
        only on wrong shapes).
    """
    s = settings
    pts = prepare(d, depth, sigma_depth, weights, s)
    n = pts.n
    note = exclusion_note(pts)
    if n < s.min_points:
        return failed_fit(FitStatus.TOO_FEW_POINTS, f"{n} valid point(s), need {s.min_points}{note}",
                           pts.n_input, n, pts.n_excluded)
    _, sum_d, sum_m, sum_dd, _, sum_mm = fsum(pts.basis, axis=1).tolist()
    mean_d = sum_d / n
    if sum_dd / n - mean_d * mean_d <= 1e-12 * (sum_dd / n):
        return failed_fit(FitStatus.ILL_CONDITIONED, f"all {n} disparities are (nearly) equal{note}",
                           pts.n_input, n, pts.n_excluded)
    mean_m = sum_m / n
    target_spread = math.sqrt(max(sum_mm / n - mean_m * mean_m, 0.0)) / mean_m
    if target_spread < s.min_relative_spread:
        return failed_fit(
            FitStatus.ILL_CONDITIONED,
            f"points lie at nearly one depth: std/mean of 1/depth = {target_spread:.3g} "
            f"< min_relative_spread {s.min_relative_spread:g}{note}",
            pts.n_input, n, pts.n_excluded)

    t2 = s.inlier_sigmas**2
    c = pts.c
    if 0 < s.score_points < n:  # score hypotheses on an evenly strided subset of the points
        sl = slice(None, None, -(-n // s.score_points))
        std_s, c_s = observed_std(pts, s, sl), None if c is None else c[sl]
    else:
        std_s, c_s = observed_std(pts, s), c
    ab_s, y_s = std_s[:2], std_s[2]  # standardised residual of h = (beta, alpha): y - h @ ab
    n_s = std_s.shape[1]
    dm = pts.basis[D:M + 1]  # (2, N) view: d, m
    table = uniform_table(s.seed, s.max_iterations)
    best_score = math.inf
    best = None  # (beta, alpha) of the best hypothesis
    drawn = 0
    needed = max(s.min_iterations, 1)
    while drawn < min(math.ceil(needed), s.max_iterations):
        size = min(s.batch_size, s.max_iterations - drawn)
        ij = (table[drawn: drawn + size] * n).astype(np.intp)  # (B, 2); i == j is dropped below
        drawn += size
        p = dm[:, ij]  # (2, B, 2): [d, m] x hypothesis x [i, j]
        dd, dmm = p @ PAIR_DIFF  # (B,) each: d_i - d_j, m_i - m_j
        keep = dd * dmm > 0  # slope alpha > 0 (and d_i != d_j, so i != j)
        if not fall(keep):
            if not fany(keep):
                if best is None:  # no usable hypothesis yet: keep drawing up to max_iterations
                    needed = s.max_iterations
                continue
            dd, dmm, p = dd[keep], dmm[keep], p[:, keep]
        hyp = np.empty((2, len(dd)))  # rows beta, alpha
        np.divide(dmm, dd, out=hyp[1])
        np.subtract(p[1, :, 0], hyp[1] * p[0, :, 0], out=hyp[0])  # beta = m_i - alpha d_i
        z = hyp.T @ ab_s  # (B, n_score)
        np.subtract(y_s, z, out=z)
        np.square(z, out=z)
        np.minimum(z, t2, out=z)
        score = fsum(z, axis=1) if c_s is None else z @ c_s
        k = int(score.argmin())
        if score[k] < best_score:
            best_score = float(score[k])
            best_inl = z[k] < t2
            best = hyp[:, k].tolist()
            needed = max(s.min_iterations, needed_iterations(int(fsum(best_inl)) / n_s, 2, s.confidence))
    if best is None:
        return failed_fit(FitStatus.NO_CONSENSUS, f"no hypothesis with alpha > 0 among {drawn} drawn{note}",
                           pts.n_input, n, pts.n_excluded, drawn)
    beta0, alpha0 = seed_least_squares(best, best_inl, std_s, c_s)
    sd_d = math.sqrt(max(sum_dd / n - mean_d * mean_d, 0.0))
    beta_hat, alpha_hat, inl, w, sums = refine(beta0, alpha0, pts, s, False, (mean_d - sd_d, mean_d + sd_d))
    fit = finish(pts, alpha_hat, beta_hat, inl, w, sums, drawn, s, note, n_params=2)
    return _with_shared(fit, pts, inl, w, depth_shared, fixed_beta=False)



def fit_scale_only(d, depth, beta: float, beta_variance: float = 0.0, sigma_depth=None, weights=None,
                   settings: RansacSettings = RansacSettings(), depth_shared=None) -> AffineFit:
    """Robust fit of the scale alone, ``1/depth - beta = alpha * d``, with ``beta`` known.

    The first fallback of the :class:`Rescaler`: ``beta`` comes from the previous good
    frame. 1-point hypotheses ``alpha = (1/depth_i - beta) / d_i`` (alpha > 0 only) are scored
    with the same MSAC cost and refined by IRLS; inlier threshold, weights and statuses as in
    :func:`fit_affine`, except that ``scale_only_min_points`` replaces both ``min_points`` and
    ``min_inliers``, and there is no spread check (one parameter is not ill-conditioned by a
    narrow depth range).

    Args:
        d: (N,) affine-invariant disparity.
        depth: (N,) metres.
        beta: known shift, 1/m.
        beta_variance: variance of ``beta`` in (1/m)^2, propagated into the covariance.
        sigma_depth: (N,) metres or None.
        weights: (N,) extra weights > 0 or None.
        settings: :class:`RansacSettings`.
        depth_shared: (N, K) metres or None, as in :func:`fit_affine`.

    Returns:
        :class:`AffineFit` with ``beta`` as given.
    """
    s = settings
    if not np.isfinite(beta):
        raise InputError(f"fit_scale_only: beta must be finite, got {beta!r}")
    beta = float(beta)
    pts = prepare(d, depth, sigma_depth, weights, s)
    n = pts.n
    note = exclusion_note(pts)
    if n < s.scale_only_min_points:
        return failed_fit(FitStatus.TOO_FEW_POINTS, f"{n} valid point(s), scale-only fit needs "
                           f"{s.scale_only_min_points}{note}", pts.n_input, n, pts.n_excluded)
    t2 = s.inlier_sigmas**2
    std = observed_std(pts, s)  # 1/sigma, d/sigma, m/sigma
    a = std[D]
    ys = std[M] - beta * std[ONE]  # (m - beta) / sigma
    dv, yv, c = pts.d, pts.m - beta, pts.c
    table = uniform_table(s.seed, s.max_iterations)[:, 0]
    best_score = math.inf
    best, drawn, needed = None, 0, max(s.min_iterations, 1)
    while drawn < min(math.ceil(needed), s.max_iterations):
        size = min(s.batch_size, s.max_iterations - drawn)
        i = (table[drawn: drawn + size] * n).astype(np.intp)
        drawn += size
        keep = yv[i] * dv[i] > 0  # alpha = y_i / d_i > 0
        i = i[keep]
        if len(i) == 0:
            if best is None:  # no usable hypothesis yet: keep drawing up to max_iterations
                needed = s.max_iterations
            continue
        alpha = yv[i] / dv[i]
        z = np.multiply.outer(alpha, a)
        np.subtract(ys, z, out=z)
        np.square(z, out=z)
        np.minimum(z, t2, out=z)
        score = z.sum(axis=1) if c is None else z @ c
        k = int(score.argmin())
        if score[k] < best_score:
            best_score = float(score[k])
            best = float(alpha[k])
            needed = max(s.min_iterations, needed_iterations(np.count_nonzero(z[k] < t2) / n, 1, s.confidence))
    if best is None:
        return failed_fit(FitStatus.NO_CONSENSUS, f"no scale hypothesis alpha > 0 among {drawn} drawn{note}",
                           pts.n_input, n, pts.n_excluded, drawn)
    d_mean, d_std = float(dv.mean()), float(dv.std())
    _, alpha_hat, inl, w, sums = refine(beta, best, pts, s, True, (d_mean - d_std, d_mean + d_std))
    fit = finish(pts, alpha_hat, beta, inl, w, sums, drawn, s, note, n_params=1, beta_variance=beta_variance)
    return _with_shared(fit, pts, inl, w, depth_shared, fixed_beta=True)


def shared_depth_errors(depth_pose_jacobian, covariance) -> np.ndarray:
    """(N, 6) metres: depth sensitivities to six independent unit-variance errors that
    reproduce a pose covariance: ``J L`` with ``L L^T = covariance``.

    Args:
        depth_pose_jacobian: (N, 6) metres per (rad, m), d depth / d pose (e.g.
            :attr:`triangulation.TriangulatedPoints.depth_pose_jacobian`).
        covariance: (6, 6) covariance of that pose (positive semi-definite).
    """
    J = check_array("depth_pose_jacobian", depth_pose_jacobian, (None, 6))
    C = check_array("covariance", covariance, (6, 6), finite=True)
    lam, V = np.linalg.eigh(0.5 * (C + C.T))
    return J @ (V * np.sqrt(np.maximum(lam, 0.0)))


def _with_shared(fit: AffineFit, pts, inl, w, depth_shared, fixed_beta: bool) -> AffineFit:
    """``fit`` with the shared errors' covariance added (see :func:`fit_affine`)."""
    if depth_shared is None or not np.isfinite(fit.covariance).all():
        return fit
    S = check_array("depth_shared", depth_shared, (pts.n_input, None))
    if pts.index is not None:
        S = S[pts.index]
    S = np.where(np.isfinite(S), S, 0.0)[inl]
    m = pts.m[inl]
    G = -S * (m * m)[:, None]  # (n_in, K): d metric disparity / d shared error
    wi = w[inl]
    d = pts.d[inl]
    if fixed_beta:
        swdd = float(wi @ (d * d))
        if not swdd > 0:
            return fit
        row = (wi * d) @ G / swdd  # d alpha / d error
        shared = np.zeros((2, 2))
        shared[0, 0] = float(row @ row)
    else:
        A = np.column_stack([d, np.ones_like(d)])
        N = A.T @ (wi[:, None] * A)
        if not np.linalg.det(N) > 0:
            return fit
        H = np.linalg.solve(N, (wi[:, None] * A).T)  # (2, n_in)
        HG = H @ G
        shared = HG @ HG.T
    return replace(fit, covariance=fit.covariance + shared, shared_covariance=shared)

