"""The fits that variants and robustness studies compare, on the same points.

* :func:`least_squares_fit` -- ordinary least squares of ``1/z`` on ``d`` over every point
  (no RANSAC, no weights): the paper's RANSAC ablation;
* :class:`PooledSums` -- the same least squares pooled over many frames (one
  ``(alpha, beta)`` per sequence: the paper's "fixed parameters" ablation);
* :func:`fit_and_depth` -- one of :data:`FIT_METHODS` on points, and the depth map it gives:
  ``ours`` (:func:`~vio_depth.rescale.fit_affine`: MSAC + IRLS, ``1/D = alpha d + beta``),
  ``paper-reference`` (scikit-learn ``RANSACRegressor`` at its defaults and the published
  ``D = 1/(|alpha d + beta| + 1e-3)``), ``least-squares``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from vio_core.checks import check_array

from ..baselines.paper_reference import fit_sklearn_ransac, published_depth
from ..rescale import FitStatus, RansacSettings, fit_affine, metric_depth

#: point-fit methods of the robustness studies
FIT_METHODS = ("ours", "paper-reference", "least-squares")
#: fewest points of a least-squares fit (the same floor as our RANSAC's ``min_points``)
MIN_POINTS = RansacSettings().min_points


@dataclass(frozen=True)
class LinearFit:
    """``1/D = alpha d + beta`` (1/m) from least squares; ``status`` OK only when ``alpha > 0``."""

    alpha: float
    beta: float
    r2: float
    n_points: int
    status: FitStatus
    reason: str = ""

    @property
    def ok(self) -> bool:
        return self.status == FitStatus.OK


def _from_moments(n: int, sd: float, sm: float, sdd: float, sdm: float, smm: float) -> LinearFit:
    if n < 2:
        return LinearFit(np.nan, np.nan, np.nan, n, FitStatus.TOO_FEW_POINTS, f"{n} point(s)")
    var_d = sdd - sd * sd / n
    if not var_d > 1e-12 * max(sdd, 1e-300):
        return LinearFit(np.nan, np.nan, np.nan, n, FitStatus.ILL_CONDITIONED, "constant disparity")
    alpha = (sdm - sd * sm / n) / var_d
    beta = (sm - alpha * sd) / n
    ss_tot = smm - sm * sm / n
    ss_res = max(ss_tot - alpha * (sdm - sd * sm / n), 0.0)
    r2 = 1.0 - ss_res / ss_tot if ss_tot > 0 else np.nan
    if not alpha > 0:
        return LinearFit(alpha, beta, r2, n, FitStatus.NO_CONSENSUS, f"least squares gives alpha = {alpha:.4g} <= 0")
    return LinearFit(float(alpha), float(beta), float(r2), n, FitStatus.OK)


def least_squares_fit(d, depth, min_points: int = MIN_POINTS) -> LinearFit:
    """Ordinary least squares of ``1/depth`` on ``d`` over the finite points with ``depth > 0``.

    Args:
        d: (N,) disparity at the points.
        depth: (N,) metres.
        min_points: fewer valid points -> ``TOO_FEW_POINTS``.
    """
    d = check_array("d", d, (None,)).astype(np.float64)
    z = check_array("depth", depth, (len(d),)).astype(np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        ok = np.isfinite(d) & np.isfinite(z) & (z > 0)
    d, m = d[ok], 1.0 / z[ok]
    if len(d) < min_points:
        return LinearFit(np.nan, np.nan, np.nan, len(d), FitStatus.TOO_FEW_POINTS,
                         f"{len(d)} valid point(s), need {min_points}")
    n = len(d)
    dc, mc = d - d.mean(), m - m.mean()  # centred sums: no cancellation
    sdd = float(dc @ dc)
    if not sdd > 0:
        return LinearFit(np.nan, np.nan, np.nan, n, FitStatus.ILL_CONDITIONED, "constant disparity")
    alpha = float(dc @ mc) / sdd
    beta = float(m.mean() - alpha * d.mean())
    r = mc - alpha * dc
    ss_tot = float(mc @ mc)
    r2 = 1.0 - float(r @ r) / ss_tot if ss_tot > 0 else np.nan
    if not alpha > 0:
        return LinearFit(alpha, beta, r2, n, FitStatus.NO_CONSENSUS, f"least squares gives alpha = {alpha:.4g} <= 0")
    return LinearFit(alpha, beta, r2, n, FitStatus.OK)


@dataclass
class PooledSums:
    """Running sums of ``d`` and ``m = 1/depth`` over many frames, for one pooled least squares.

    :meth:`add` takes a disparity map and the (masked) ground truth; pixels with finite
    ``d`` and ground truth in ``[min_depth, max_depth]`` count. Sums are float64, added
    frame by frame in a fixed order (the result does not depend on who computes it).
    """

    min_depth: float
    max_depth: float
    sums: list = field(default_factory=lambda: [0, 0.0, 0.0, 0.0, 0.0, 0.0])

    def add(self, disparity, gt_depth) -> None:
        """Add one frame: ``disparity: (H, W)``, ``gt_depth: (H, W)`` metres (0 = invalid)."""
        d = np.asarray(disparity, dtype=np.float64)
        g = np.asarray(gt_depth, dtype=np.float64)
        with np.errstate(invalid="ignore"):
            ok = np.isfinite(d) & np.isfinite(g) & (g >= self.min_depth) & (g <= self.max_depth)
        d, m = d[ok], 1.0 / g[ok]
        for k, v in enumerate((len(d), d.sum(), m.sum(), d @ d, d @ m, m @ m)):
            self.sums[k] += v

    def fit(self) -> LinearFit:
        return _from_moments(int(self.sums[0]), *(float(v) for v in self.sums[1:]))


def fit_and_depth(method: str, disparity, d, depth, seed: int) -> tuple[np.ndarray | None, str]:
    """Fit ``method`` (:data:`FIT_METHODS`) on points; ``(depth map or None, status)``.

    Args:
        method: ``ours``, ``paper-reference`` or ``least-squares``.
        disparity: (H, W) the frame's disparity.
        d: (N,) disparity at the points.
        depth: (N,) metres of the points.
        seed: RANSAC seed (ours, paper-reference).
    """
    if method == "ours":
        fit = fit_affine(d, depth, settings=RansacSettings(seed=int(seed)))
    elif method == "least-squares":
        fit = least_squares_fit(d, depth)
    else:
        d = np.asarray(d, dtype=np.float64)
        z = np.asarray(depth, dtype=np.float64)
        with np.errstate(invalid="ignore"):
            keep = np.isfinite(d) & np.isfinite(z) & (z > 0)
        if keep.sum() < 2:
            return None, "too_few_points"
        try:
            sk = fit_sklearn_ransac(d[keep], z[keep], seed)
        except ValueError:
            return None, "fit_failed"
        return published_depth(disparity, sk.alpha, sk.beta), "ok"
    return (metric_depth(disparity, fit) if fit.ok else None), fit.status.value
