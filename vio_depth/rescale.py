"""Robust per-image rescaling of an affine-invariant disparity to metric depth.

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

import enum
import functools
import math
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np

from vio_core.checks import check_array, check_image
from vio_core.errors import InputError, lookup
from .temporal import (
    AffineKalmanFilter,
    KalmanEstimate,
    KalmanSettings,
    anchors_from_map,
    anchors_from_points,
    inflate_covariance,
)

if TYPE_CHECKING:  # pragma: no cover
    from .types import FrameStatus

_sum, _min, _max = np.add.reduce, np.minimum.reduce, np.maximum.reduce
_all, _any = np.logical_and.reduce, np.logical_or.reduce

_NAN_COV = np.full((2, 2), np.nan)
_NAN_COV.setflags(write=False)


# ----------------------------------------------------------------------------- sampling


def sample_bilinear(image, uv) -> tuple[np.ndarray, np.ndarray]:
    """Bilinear interpolation of ``image`` at sub-pixel positions.

    Pixel centres lie at integer coordinates: ``image[v, u]`` is the value at ``(u, v)``.

    Args:
        image: (H, W) float, e.g. a disparity map. May contain NaN/inf (invalid pixels).
        uv: (N, 2) px, ``(x, y)`` = (column, row) coordinates in ``image``'s pixel grid
            (scale keypoints first when the map has another resolution than the image).

    Returns:
        values: (N,) float64 interpolated values (NaN where invalid).
        valid: (N,) bool, False where ``uv`` is non-finite, outside
            ``[0, W-1] x [0, H-1]``, or any of the 4 neighbours used is non-finite.
    """
    img = check_image("image", image)
    uv = check_array("uv", uv, (None, 2))
    h, w = img.shape
    u = uv[:, 0]
    v = uv[:, 1]
    with np.errstate(invalid="ignore"):
        inside = np.isfinite(u) & np.isfinite(v) & (u >= 0) & (u <= w - 1) & (v >= 0) & (v <= h - 1)
    uu = np.where(inside, u, 0.0)
    vv = np.where(inside, v, 0.0)
    # x0 in [0, W-2] so that x0 + 1 stays inside (weight 1 on x1 at the right border).
    x0 = np.clip(np.floor(uu).astype(np.intp), 0, max(w - 2, 0))
    y0 = np.clip(np.floor(vv).astype(np.intp), 0, max(h - 2, 0))
    x1 = np.minimum(x0 + 1, w - 1)
    y1 = np.minimum(y0 + 1, h - 1)
    fx = uu - x0
    fy = vv - y0
    i00 = img[y0, x0].astype(np.float64)
    i01 = img[y0, x1].astype(np.float64)
    i10 = img[y1, x0].astype(np.float64)
    i11 = img[y1, x1].astype(np.float64)
    valid = inside & np.isfinite(i00) & np.isfinite(i01) & np.isfinite(i10) & np.isfinite(i11)
    with np.errstate(invalid="ignore"):
        values = (i00 * (1 - fx) + i01 * fx) * (1 - fy) + (i10 * (1 - fx) + i11 * fx) * fy
    values = np.where(valid, values, np.nan)
    return values, valid


# ----------------------------------------------------------------------------- settings


@dataclass(frozen=True)
class RansacSettings:
    """Every knob of :func:`fit_affine` (no hidden defaults).

    Point uncertainty (metric-disparity units, 1/m) used for the threshold and the weights::

        sigma_i**2 = (sigma_depth_i / depth_i**2)**2          # the point's own (geometry)
                     + (model_relative_sigma * mhat_i)**2      # the depth network's error
                     + min_sigma_disparity**2                  # numerical floor

    ``mhat_i`` is a metric disparity at the point: the observed ``1/depth_i`` while scoring
    minimal-sample hypotheses (cheap, computed once), then ``alpha*d_i + beta`` of the best
    hypothesis for its local optimisation (recomputed from the refined line when that moved
    by more than ``reweight_tolerance``); the final inliers, covariance and diagnostics use
    the latter. Weights from the observed value would bias the least squares towards small
    disparities, by about ``2 * model_relative_sigma**2`` in scale; a hypothesis' prediction
    does not depend on the other points' noise.

    Attributes:
        inlier_sigmas: inlier threshold in standardised residuals: point i is an inlier of
            ``(alpha, beta)`` when ``|1/depth_i - (alpha*d_i + beta)| <= inlier_sigmas * sigma_i``.
            Also the MSAC truncation: each point costs ``min((r_i/sigma_i)**2, inlier_sigmas**2)``.
        model_relative_sigma: relative depth error of the depth network itself (after the best
            affine fit), added in quadrature to the point's own uncertainty; it is the whole
            uncertainty when ``sigma_depth`` is not given. 0.05 = 5 % of depth.
        min_sigma_disparity: floor on ``sigma_i`` in 1/m, added in quadrature (numerical
            safety only).
        confidence: probability that at least one all-inlier minimal sample was drawn; sets
            the adaptive number of hypotheses ``log(1-confidence) / log(1-eps**2)`` (eps =
            inlier ratio of the best hypothesis so far on the scored points).
        min_iterations: hypotheses drawn at least (rounded up to whole batches).
        max_iterations: hypotheses drawn at most (also when none has alpha > 0).
        batch_size: hypotheses scored together in one (batch_size, score_points) array.
        score_points: hypotheses are scored on every ``ceil(N / score_points)``-th point
            (at most this many points), or on all points when N <= score_points or it is 0.
            The subset only picks the best minimal sample and estimates its inlier ratio;
            the local optimisation and everything reported use all points.
        lo_iterations: maximum iteratively-reweighted-least-squares rounds of the local
            optimisation (stops earlier when the inlier set no longer changes). It starts
            from one weighted least squares on the best hypothesis' inliers among the
            scored points.
        reweight_tolerance: the local optimisation computes sigma_i's model term from the
            best hypothesis; when the refined line's metric disparity differs from the
            hypothesis' by more than this fraction at ``mean(d) +- std(d)``, sigma_i is
            recomputed from the refined line and the optimisation repeated (at most twice).
        seed: seed of the minimal-sample generator (same input + seed = same output).
        min_points: fewer valid points than this -> ``TOO_FEW_POINTS``.
        min_inliers: fewer inliers than this -> ``NO_CONSENSUS``.
        min_inlier_ratio: inliers / valid points below this -> ``NO_CONSENSUS``.
        min_relative_spread: ill-conditioning criterion. ``relative_spread`` is the
            coefficient of variation of the fitted metric disparity over the inliers,
            ``alpha * std(d_inliers) / mean(alpha * d_inliers + beta)`` (unit-free and
            independent of the arbitrary normalisation of ``d``; about
            ``std(1/z) / mean(1/z)``). Below this value -> ``DEGENERATE_SPREAD``. The default
            0.075 is 1.5 x ``model_relative_sigma``: when the points' metric disparities
            spread barely more than the network's own (spatially correlated) relative
            error, scale and shift cannot be separated -- on the room sample a frame at
            0.060 fitted all 96 accurate points yet gave AbsRel 0.21 against the oracle's
            0.012. The same criterion is checked before sampling on the targets
            ``1/depth`` of all valid points.
        scale_only_min_points: fewer valid points than this -> the scale-only fallback fit
            (:func:`fit_scale_only`, 1-point samples) reports ``TOO_FEW_POINTS``.
    """

    inlier_sigmas: float = 3.0
    model_relative_sigma: float = 0.05
    min_sigma_disparity: float = 1e-6
    confidence: float = 0.999
    min_iterations: int = 8
    max_iterations: int = 1000
    batch_size: int = 8
    score_points: int = 128
    lo_iterations: int = 10
    reweight_tolerance: float = 0.1
    seed: int = 0
    min_points: int = 10
    min_inliers: int = 8
    min_inlier_ratio: float = 0.25
    min_relative_spread: float = 0.075
    scale_only_min_points: int = 3

    def __post_init__(self):
        positive = ("inlier_sigmas", "min_sigma_disparity", "batch_size", "max_iterations")
        for name in positive:
            if not getattr(self, name) > 0:
                raise InputError(f"RansacSettings.{name} must be > 0, got {getattr(self, name)!r}")
        if not 0.0 < self.confidence < 1.0:
            raise InputError(f"RansacSettings.confidence must be in (0, 1), got {self.confidence!r}")
        if not 0.0 <= self.min_inlier_ratio <= 1.0:
            raise InputError(f"RansacSettings.min_inlier_ratio must be in [0, 1], got {self.min_inlier_ratio!r}")
        for name in ("model_relative_sigma", "min_iterations", "lo_iterations", "min_relative_spread",
                     "score_points", "reweight_tolerance"):
            if getattr(self, name) < 0:
                raise InputError(f"RansacSettings.{name} must be >= 0, got {getattr(self, name)!r}")
        if self.min_points < 2 or self.min_inliers < 2 or self.scale_only_min_points < 1:
            raise InputError("RansacSettings: min_points and min_inliers must be >= 2, scale_only_min_points >= 1")


class FitStatus(str, enum.Enum):
    """Outcome of one robust fit (:func:`fit_affine` / :func:`fit_scale_only`).

    Checked in this order: ``TOO_FEW_POINTS`` (fewer than ``min_points`` valid points),
    ``DEGENERATE_SPREAD`` (targets of all points nearly equal), ``NO_CONSENSUS`` (no
    hypothesis with alpha > 0, or too few inliers), ``DEGENERATE_SPREAD`` (inliers' spread
    too narrow), ``OK``. Fallback stages are :class:`RescaleStatus` of the :class:`Rescaler`.
    """

    OK = "ok"
    TOO_FEW_POINTS = "too_few_points"
    DEGENERATE_SPREAD = "degenerate_spread"
    NO_CONSENSUS = "no_consensus"


@dataclass(frozen=True)
class AffineFit:
    """Result of fitting ``1/depth = alpha * d + beta``.

    Attributes:
        alpha: scale (1/m per unit of ``d``), > 0 when ``ok``; may be NaN when no
            hypothesis existed.
        beta: shift, 1/m.
        covariance: (2, 2) covariance of ``(alpha, beta)`` (weighted least squares on the
            inliers, scaled by the reduced chi-square of their standardised residuals);
            NaN when unknown.
        inliers: (N,) bool over the input points (excluded points are False).
        n_points: valid points used (input points minus ``n_excluded``).
        n_inliers: inliers among them.
        inlier_ratio: ``n_inliers / n_points`` (0 without points).
        r2: coefficient of determination of the metric disparity on the inliers,
            ``1 - sum(r**2) / sum((m - mean(m))**2)`` (unweighted, as the paper's R^2).
        disparity_spread: standard deviation of ``d`` over the inliers (units of ``d``).
        relative_spread: ``alpha * disparity_spread / mean_metric_disparity`` (unit-free,
            see :attr:`RansacSettings.min_relative_spread`).
        mean_metric_disparity: mean of ``alpha * d + beta`` over the inliers, 1/m.
        status: :class:`FitStatus`.
        reason: human-readable explanation (empty-ish when OK).
        iterations: hypotheses drawn.
        n_excluded: input points excluded before fitting (non-finite ``d`` or depth,
            depth <= 0, non-finite or negative ``sigma_depth``, weight <= 0 or non-finite).
    """

    alpha: float
    beta: float
    covariance: np.ndarray = field(repr=False)
    inliers: np.ndarray = field(repr=False)
    n_points: int
    n_inliers: int
    inlier_ratio: float
    r2: float
    disparity_spread: float
    relative_spread: float
    mean_metric_disparity: float
    status: FitStatus
    reason: str = ""
    iterations: int = 0
    n_excluded: int = 0

    @property
    def ok(self) -> bool:
        return self.status == FitStatus.OK

    @property
    def sigma_alpha(self) -> float:
        return float(math.sqrt(self.covariance[0, 0])) if np.isfinite(self.covariance[0, 0]) else math.nan

    @property
    def sigma_beta(self) -> float:
        return float(math.sqrt(self.covariance[1, 1])) if np.isfinite(self.covariance[1, 1]) else math.nan

    def to_json(self) -> dict:
        """Scalars of the fit for ``frames.jsonl`` (no arrays)."""
        return {
            "alpha": _json_float(self.alpha),
            "beta": _json_float(self.beta),
            "sigma_alpha": _json_float(self.sigma_alpha),
            "sigma_beta": _json_float(self.sigma_beta),
            "n_points": self.n_points,
            "n_inliers": self.n_inliers,
            "inlier_ratio": _json_float(self.inlier_ratio),
            "r2": _json_float(self.r2),
            "disparity_spread": _json_float(self.disparity_spread),
            "relative_spread": _json_float(self.relative_spread),
            "fit_status": self.status.value,
            "fit_reason": self.reason,
            "iterations": self.iterations,
        }


def _json_float(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def _failed_fit(status: FitStatus, reason: str, n_input: int, n_points: int, n_excluded: int,
                iterations: int = 0) -> AffineFit:
    return AffineFit(
        alpha=math.nan, beta=math.nan, covariance=_NAN_COV, inliers=np.zeros(n_input, bool),
        n_points=n_points, n_inliers=0, inlier_ratio=0.0, r2=math.nan, disparity_spread=math.nan,
        relative_spread=math.nan, mean_metric_disparity=math.nan, status=status, reason=reason,
        iterations=iterations, n_excluded=n_excluded,
    )


# ----------------------------------------------------------------------------- fitting


def metric_disparity_sigma(depth, sigma_depth=None, settings: RansacSettings = RansacSettings(),
                           predicted_disparity=None) -> np.ndarray:
    """Uncertainty of each point's metric disparity, as used by the fits.

    Args:
        depth: (N,) metres, > 0.
        sigma_depth: (N,) metres, standard deviation of each depth (triangulation), or None.
        settings: uses ``model_relative_sigma`` and ``min_sigma_disparity``.
        predicted_disparity: (N,) 1/m, the metric disparity a model predicts at the points
            (``alpha * d + beta``), or None to use the observed ``1/depth``.

    Returns:
        (N,) 1/m: ``sqrt((sigma_depth/depth**2)**2 + (model_relative_sigma *
        predicted_disparity)**2 + min_sigma_disparity**2)`` (see :class:`RansacSettings`).
    """
    depth = check_array("depth", depth, (None,))
    m = 1.0 / depth
    ref = m if predicted_disparity is None else check_array("predicted_disparity", predicted_disparity, (len(m),))
    var = (settings.model_relative_sigma * ref) ** 2 + settings.min_sigma_disparity**2
    if sigma_depth is not None:
        sd = check_array("sigma_depth", sigma_depth, (len(depth),))
        var = var + (sd * m * m) ** 2
    return np.sqrt(var)


# Rows of the per-point basis matrix: every (weighted) sum over an inlier mask is one
# matrix-vector product, ``basis @ mask`` or ``basis @ (w * mask)``.
_ONE, _D, _M, _DD, _DM, _MM = range(6)


@dataclass
class _Points:
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
        return self.basis[_D]

    @property
    def m(self) -> np.ndarray:
        return self.basis[_M]

    @property
    def n_excluded(self) -> int:
        return self.n_input - self.n

    def full_mask(self, inliers: np.ndarray) -> np.ndarray:
        if self.index is None:
            return inliers
        out = np.zeros(self.n_input, bool)
        out[self.index[inliers]] = True
        return out


def _prepare(d, depth, sigma_depth, weights, settings: RansacSettings) -> _Points:
    d = check_array("d", d, (None,))
    n = len(d)
    depth = check_array("depth", depth, (n,))
    sd = None if sigma_depth is None else check_array("sigma_depth", sigma_depth, (n,))
    c = None if weights is None else check_array("weights", weights, (n,))
    # Fast path, a few reductions and no warnings: NaN makes every comparison False; a
    # positive array with a finite sum has no inf. (ufunc reductions are called directly:
    # the ndarray methods add a Python-level wrapper per call.)
    fast = n == 0 or (-math.inf < _min(d) and _max(d) < math.inf and _min(depth) > 0 and _sum(depth) < math.inf)
    if fast and n and sd is not None:
        fast = _min(sd) >= 0 and _sum(sd) < math.inf
    if fast and n and c is not None:
        fast = _min(c) > 0 and _sum(c) < math.inf
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
    basis[_ONE] = 1.0
    dv = basis[_D]
    dv[:] = d
    m = basis[_M]
    np.divide(1.0, depth, out=m)
    np.multiply(dv, dv, out=basis[_DD])
    np.multiply(dv, m, out=basis[_DM])
    mm = np.multiply(m, m, out=basis[_MM])
    # variance of m that does not depend on the model: geometric term + floor (in quadrature)
    floor2 = float(settings.min_sigma_disparity) ** 2
    if sd is not None:
        g2 = sd * mm
        g2 *= g2
        g2 += floor2
    else:
        g2 = floor2
    return _Points(n, index, basis, g2, c)


def _weights(pts: _Points, alpha: float, beta: float, s: RansacSettings) -> tuple[np.ndarray, np.ndarray]:
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


def _observed_std(pts: _Points, s: RansacSettings, sl: slice = slice(None)) -> np.ndarray:
    """(3, n) rows 1, d, m of the points ``sl`` divided by sigma_i with the model term at the
    observed metric disparity (for scoring hypotheses)."""
    g2 = pts.g2 if isinstance(pts.g2, float) else pts.g2[sl]
    var = pts.basis[_MM, sl] * s.model_relative_sigma**2
    var += g2
    return pts.basis[:_DD, sl] * np.power(var, -0.5, out=var)


@functools.lru_cache(maxsize=8)
def _uniform_table(seed: int, size: int) -> np.ndarray:
    """Read-only ``(size, 2)`` table of uniforms in [0, 1) for ``seed`` (cached: creating a
    generator per fit costs more than a whole small fit)."""
    table = np.random.default_rng(seed).random((size, 2))
    table.setflags(write=False)
    return table


def _needed_iterations(inlier_ratio: float, sample_size: int, confidence: float) -> float:
    """Hypotheses needed to draw one all-inlier sample with probability ``confidence``."""
    p_good = inlier_ratio**sample_size
    if p_good >= 1.0:
        return 0.0
    if p_good <= 0.0:
        return math.inf
    return math.log(1.0 - confidence) / math.log1p(-p_good)


def _exclusion_note(pts: _Points) -> str:
    return f"; {pts.n_excluded} point(s) excluded (non-finite, depth <= 0 or weight <= 0)" if pts.n_excluded else ""


def fit_affine(d, depth, sigma_depth=None, weights=None, settings: RansacSettings = RansacSettings()) -> AffineFit:
    """Robust fit of ``1/depth = alpha * d + beta`` (alpha > 0), vectorised MSAC + LO.

    Hypotheses come from 2-point minimal samples (index pairs from a fixed table of
    uniforms for ``settings.seed``); those with alpha <= 0 are dropped, the others are scored
    ``batch_size`` at a time with the MSAC cost ``sum_i c_i * min((r_i / sigma_i)**2,
    inlier_sigmas**2)`` on at most ``score_points`` points, until ``confidence`` is reached
    for the best one's inlier ratio. The best hypothesis is then refined over all points by
    iteratively reweighted least squares on its inliers (:func:`_refine`, :func:`_irls`).

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

    Returns:
        :class:`AffineFit`; ``status`` says whether it can be used (never raises on bad data,
        only on wrong shapes).
    """
    s = settings
    pts = _prepare(d, depth, sigma_depth, weights, s)
    n = pts.n
    note = _exclusion_note(pts)
    if n < s.min_points:
        return _failed_fit(FitStatus.TOO_FEW_POINTS, f"{n} valid point(s), need {s.min_points}{note}",
                           pts.n_input, n, pts.n_excluded)
    _, sum_d, sum_m, sum_dd, _, sum_mm = _sum(pts.basis, axis=1).tolist()
    mean_d = sum_d / n
    if sum_dd / n - mean_d * mean_d <= 1e-12 * (sum_dd / n):
        return _failed_fit(FitStatus.DEGENERATE_SPREAD, f"all {n} disparities are (nearly) equal{note}",
                           pts.n_input, n, pts.n_excluded)
    mean_m = sum_m / n
    target_spread = math.sqrt(max(sum_mm / n - mean_m * mean_m, 0.0)) / mean_m
    if target_spread < s.min_relative_spread:
        return _failed_fit(
            FitStatus.DEGENERATE_SPREAD,
            f"points lie at nearly one depth: std/mean of 1/depth = {target_spread:.3g} "
            f"< min_relative_spread {s.min_relative_spread:g}{note}",
            pts.n_input, n, pts.n_excluded)

    t2 = s.inlier_sigmas**2
    c = pts.c
    if 0 < s.score_points < n:  # score hypotheses on an evenly strided subset of the points
        sl = slice(None, None, -(-n // s.score_points))
        std_s, c_s = _observed_std(pts, s, sl), None if c is None else c[sl]
    else:
        std_s, c_s = _observed_std(pts, s), c
    ab_s, y_s = std_s[:2], std_s[2]  # standardised residual of h = (beta, alpha): y - h @ ab
    n_s = std_s.shape[1]
    dm = pts.basis[_D:_M + 1]  # (2, N) view: d, m
    table = _uniform_table(s.seed, s.max_iterations)
    best_score = math.inf
    best = None  # (beta, alpha) of the best hypothesis
    drawn = 0
    needed = max(s.min_iterations, 1)
    while drawn < min(math.ceil(needed), s.max_iterations):
        size = min(s.batch_size, s.max_iterations - drawn)
        ij = (table[drawn: drawn + size] * n).astype(np.intp)  # (B, 2); i == j is dropped below
        drawn += size
        p = dm[:, ij]  # (2, B, 2): [d, m] x hypothesis x [i, j]
        dd, dmm = p @ _PAIR_DIFF  # (B,) each: d_i - d_j, m_i - m_j
        keep = dd * dmm > 0  # slope alpha > 0 (and d_i != d_j, so i != j)
        if not _all(keep):
            if not _any(keep):
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
        score = _sum(z, axis=1) if c_s is None else z @ c_s
        k = int(score.argmin())
        if score[k] < best_score:
            best_score = float(score[k])
            best_inl = z[k] < t2
            best = hyp[:, k].tolist()
            needed = max(s.min_iterations, _needed_iterations(int(_sum(best_inl)) / n_s, 2, s.confidence))
    if best is None:
        return _failed_fit(FitStatus.NO_CONSENSUS, f"no hypothesis with alpha > 0 among {drawn} drawn{note}",
                           pts.n_input, n, pts.n_excluded, drawn)
    beta0, alpha0 = _seed_least_squares(best, best_inl, std_s, c_s)
    sd_d = math.sqrt(max(sum_dd / n - mean_d * mean_d, 0.0))
    beta_hat, alpha_hat, inl, w, sums = _refine(beta0, alpha0, pts, s, False, (mean_d - sd_d, mean_d + sd_d))
    return _finish(pts, alpha_hat, beta_hat, inl, w, sums, drawn, s, note, n_params=2)


_PAIR_DIFF = np.array([1.0, -1.0])


def _seed_least_squares(best: list[float], inl_s: np.ndarray, std_s: np.ndarray,
                        c_s: np.ndarray | None) -> tuple[float, float]:
    """``(beta, alpha)``: one weighted least squares on the best hypothesis' inliers among
    the scored points (a better seed for :func:`_refine` than a 2-point line), or the
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


def _irls(beta: float, alpha: float, basis: np.ndarray, std: np.ndarray, w: np.ndarray, t2: float, rounds: int,
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
        if not _any(inl_new != inl):  # same inliers: converged, `sums` still belong to them
            break
        inl = inl_new
        sums = (basis @ (w * inl)).tolist()
    return beta, alpha, inl, sums


def _refine(beta: float, alpha: float, pts: _Points, s: RansacSettings, fixed_beta: bool,
            d_ref: tuple[float, float]):
    """Local optimisation of the best hypothesis ``(beta, alpha)``.

    sigma_i's model term is taken at the metric disparity predicted by the hypothesis
    (:func:`_weights`), then :func:`_irls` runs with those weights. If the refined line's
    metric disparity differs from the seed's by more than ``s.reweight_tolerance``
    (relative) at either reference disparity ``d_ref``, the weights are recomputed from the
    refined line and the IRLS repeated (at most twice).

    Returns ``(beta, alpha, inliers (N,) bool, weights w (N,), weighted sums or None)``.
    """
    t2 = s.inlier_sigmas**2
    lo, hi = d_ref
    tol = s.reweight_tolerance
    basis3 = pts.basis[:_DD]
    for _ in range(3):
        inv_sigma, w = _weights(pts, alpha, beta, s)
        seed_lo, seed_hi = alpha * lo + beta, alpha * hi + beta
        beta, alpha, inl, sums = _irls(beta, alpha, pts.basis, basis3 * inv_sigma, w, t2, s.lo_iterations,
                                       fixed_beta)
        new_lo, new_hi = alpha * lo + beta, alpha * hi + beta
        if abs(seed_lo - new_lo) <= tol * abs(new_lo) and abs(seed_hi - new_hi) <= tol * abs(new_hi):
            break
    return beta, alpha, inl, w, sums


def _finish(pts: _Points, alpha: float, beta: float, inl: np.ndarray, w_pts: np.ndarray, w_sums: list | None,
            drawn: int, s: RansacSettings, note: str, n_params: int, beta_variance: float = 0.0) -> AffineFit:
    """Diagnostics, covariance and status of a refined estimate (shared by both fits).

    All inlier sums come from matrix-vector products of ``pts.basis``: with the mask
    (unweighted) and with ``w_pts * mask`` (the weights the estimate was refined with; given
    as ``w_sums`` when the refinement already computed them).
    """
    n = pts.n
    u = (pts.basis @ inl).tolist()
    w = w_sums if w_sums is not None else (pts.basis @ (w_pts * inl)).tolist()
    n_in = int(round(u[_ONE]))
    ratio = n_in / n
    a, b = alpha, beta
    # sum of (weighted) squared residuals r = m - a d - b from the sums (clamped against rounding)
    chi2_sum = max(w[_MM] - 2 * a * w[_DM] - 2 * b * w[_M] + a * a * w[_DD] + 2 * a * b * w[_D] + b * b * w[_ONE], 0.0)
    ss_res = max(u[_MM] - 2 * a * u[_DM] - 2 * b * u[_M] + a * a * u[_DD] + 2 * a * b * u[_D] + b * b * u[_ONE], 0.0)
    if n_in > 0:
        mean_d = u[_D] / n_in
        spread = math.sqrt(max(u[_DD] / n_in - mean_d * mean_d, 0.0))
        ss_tot = u[_MM] - u[_M] * u[_M] / n_in
        r2 = 1.0 - ss_res / ss_tot if ss_tot > 0 else math.nan
        mean_fit = a * mean_d + b
        rel_spread = a * spread / mean_fit if mean_fit > 0 else math.nan
    else:
        r2 = spread = mean_fit = rel_spread = math.nan
    cov = _NAN_COV
    if n_in > n_params:
        chi2 = chi2_sum / (n_in - n_params)
        sw, swd, swdd = w[_ONE], w[_D], w[_DD]
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
        status, reason = FitStatus.DEGENERATE_SPREAD, (
            f"inliers span too narrow a disparity range to separate scale from shift: relative "
            f"spread {rel_spread:.3g} < min_relative_spread {s.min_relative_spread:g}")
    else:
        status, reason = FitStatus.OK, f"{n_in}/{n} inliers"
    return AffineFit(alpha, beta, cov, pts.full_mask(inl), n, n_in, ratio, r2, spread, rel_spread, mean_fit, status,
                     reason + note, drawn, pts.n_excluded)


def fit_scale_only(d, depth, beta: float, beta_variance: float = 0.0, sigma_depth=None, weights=None,
                   settings: RansacSettings = RansacSettings()) -> AffineFit:
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

    Returns:
        :class:`AffineFit` with ``beta`` as given.
    """
    s = settings
    if not np.isfinite(beta):
        raise InputError(f"fit_scale_only: beta must be finite, got {beta!r}")
    beta = float(beta)
    pts = _prepare(d, depth, sigma_depth, weights, s)
    n = pts.n
    note = _exclusion_note(pts)
    if n < s.scale_only_min_points:
        return _failed_fit(FitStatus.TOO_FEW_POINTS, f"{n} valid point(s), scale-only fit needs "
                           f"{s.scale_only_min_points}{note}", pts.n_input, n, pts.n_excluded)
    t2 = s.inlier_sigmas**2
    std = _observed_std(pts, s)  # 1/sigma, d/sigma, m/sigma
    a = std[_D]
    ys = std[_M] - beta * std[_ONE]  # (m - beta) / sigma
    dv, yv, c = pts.d, pts.m - beta, pts.c
    table = _uniform_table(s.seed, s.max_iterations)[:, 0]
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
            needed = max(s.min_iterations, _needed_iterations(np.count_nonzero(z[k] < t2) / n, 1, s.confidence))
    if best is None:
        return _failed_fit(FitStatus.NO_CONSENSUS, f"no scale hypothesis alpha > 0 among {drawn} drawn{note}",
                           pts.n_input, n, pts.n_excluded, drawn)
    d_mean, d_std = float(dv.mean()), float(dv.std())
    _, alpha_hat, inl, w, sums = _refine(beta, best, pts, s, True, (d_mean - d_std, d_mean + d_std))
    return _finish(pts, alpha_hat, beta, inl, w, sums, drawn, s, note, n_params=1, beta_variance=beta_variance)


# ----------------------------------------------------------------------------- maps


def _usable(fit) -> tuple[float, float]:
    alpha, beta = float(fit.alpha), float(fit.beta)
    status = getattr(fit, "status", FitStatus.OK)
    if status != FitStatus.OK or not (np.isfinite(alpha) and np.isfinite(beta) and alpha > 0):
        raise InputError(f"metric depth needs an OK fit with finite alpha > 0, got status "
                         f"{getattr(status, 'value', status)} alpha={alpha!r} beta={beta!r}")
    return alpha, beta


def metric_depth(disparity, fit: AffineFit, max_depth: float | None = None) -> np.ndarray:
    """Metric depth map ``D = 1 / (alpha * d + beta)``.

    Args:
        disparity: (H, W) affine-invariant disparity (NaN = invalid).
        fit: an OK :class:`AffineFit` (e.g. ``RescaleResult.fit``).
        max_depth: metres, or None. Pixels deeper than this are marked invalid (NaN), since
            depth grows without bound as ``alpha*d + beta`` approaches 0.

    Returns:
        (H, W) float32 metres; NaN where ``alpha*d + beta <= 0`` or non-finite (no ``abs()``:
        such pixels have no metric depth under the fit), or beyond ``max_depth``.

    Raises:
        InputError: ``fit`` is not OK (a fallback decision belongs to the :class:`Rescaler`).
    """
    disp = check_image("disparity", disparity)
    alpha, beta = _usable(fit)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        md = alpha * disp.astype(np.float64) + beta
        depth = np.where(md > 0, 1.0 / md, np.nan)
        if max_depth is not None:
            depth = np.where(depth <= max_depth, depth, np.nan)
    return depth.astype(np.float32)


def depth_sigma_map(disparity, fit: AffineFit, max_depth: float | None = None) -> np.ndarray:
    """Per-pixel standard deviation of the metric depth from the (alpha, beta) covariance.

    First order: ``m = alpha*d + beta``, ``D = 1/m``,
    ``sigma_m**2 = [d, 1] Sigma [d, 1]^T``, ``sigma_D = sigma_m / m**2``.

    Args:
        disparity: (H, W) affine-invariant disparity.
        fit: an OK :class:`AffineFit` with a finite ``covariance`` (2, 2).
        max_depth: metres or None; same invalid mask as :func:`metric_depth`.

    Returns:
        (H, W) float32 metres; NaN where :func:`metric_depth` is NaN or the covariance is
        unknown.
    """
    disp = check_image("disparity", disparity).astype(np.float64)
    alpha, beta = _usable(fit)
    cov = check_array("fit.covariance", fit.covariance, (2, 2))
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        md = alpha * disp + beta
        var_m = disp * disp * cov[0, 0] + 2.0 * disp * cov[0, 1] + cov[1, 1]
        sigma = np.sqrt(np.maximum(var_m, 0.0)) / (md * md)
        ok = md > 0
        if max_depth is not None:
            ok &= 1.0 / md <= max_depth
        sigma = np.where(ok, sigma, np.nan)
    return sigma.astype(np.float32)


# ----------------------------------------------------------------------------- rescaler


class RescaleStatus(str, enum.Enum):
    """Which stage of the :class:`Rescaler`'s fallback order produced the fit used."""

    OK = "ok"  # this frame's full fit (filtered when the temporal filter is on)
    SCALE_ONLY = "scale_only"  # alpha fitted now, beta from the previous good frame
    PREVIOUS_FIT = "previous_fit"  # the last fit that gave depth, reused
    NONE = "none"  # no metric depth for this frame


@dataclass(frozen=True)
class RescalerSettings:
    """Settings of the streaming :class:`Rescaler`.

    Attributes:
        ransac: :class:`RansacSettings` of every fit.
        fallback: when False, a failed fit gives ``NONE`` directly (the paper's behaviour).
        max_fallback_age: frames since the last ``OK`` frame after which neither fallback
            is used (the previous beta / fit is considered stale).
        temporal: :class:`vio_depth.temporal.KalmanSettings` of the (alpha, beta) filter
            (on by default), or None to use each frame's fit as is.
    """

    ransac: RansacSettings = RansacSettings()
    fallback: bool = True
    max_fallback_age: int = 10
    temporal: KalmanSettings | None = KalmanSettings()

    def __post_init__(self):
        if self.max_fallback_age < 1:
            raise InputError(f"RescalerSettings.max_fallback_age must be >= 1, got {self.max_fallback_age!r}")

    @classmethod
    def default(cls, seed: int = 0, temporal: bool = True) -> "RescalerSettings":
        """Defaults with RANSAC ``seed`` and the temporal filter on or off (CLI helper)."""
        return cls(ransac=RansacSettings(seed=seed), temporal=KalmanSettings() if temporal else None)


_RESCALER_PRESETS = {
    "streaming": lambda: RescalerSettings(),  # fallbacks + temporal filter (the default)
    "per_frame": lambda: RescalerSettings(temporal=None),  # fallbacks, no filter
    "paper": lambda: RescalerSettings(fallback=False, temporal=None),  # each frame alone
}


def available_rescaler_presets() -> list[str]:
    return sorted(_RESCALER_PRESETS)


def rescaler_preset(name: str) -> RescalerSettings:
    """Named :class:`RescalerSettings`: ``streaming`` (fallbacks + Kalman filter, the default
    for sequences), ``per_frame`` (fallbacks, no filter) or ``paper`` (no fallback, no filter).

    Raises:
        UnknownNameError: unknown name (lists the valid ones).
    """
    return lookup("rescaler preset", name, _RESCALER_PRESETS)()


@dataclass(frozen=True)
class RescaleResult:
    """What the :class:`Rescaler` decided for one frame.

    Attributes:
        status: :class:`RescaleStatus` (fallback stage).
        fit: the :class:`AffineFit` to use (status OK), or None when ``status`` is NONE.
            For ``OK`` with the temporal filter on, the filtered (alpha, beta, covariance)
            with the raw fit's diagnostics.
        raw: this frame's full fit (:func:`fit_affine`).
        scale_only: the scale-only fallback fit when one was attempted, else None.
        filtered: the filter's output for this frame when the filter is on, else None.
        age: frames between this frame and the one whose fit is used (0 = this frame).
        reason: why this stage was chosen (joined reasons of the failed stages).
    """

    status: RescaleStatus
    fit: AffineFit | None
    raw: AffineFit
    scale_only: AffineFit | None = None
    filtered: KalmanEstimate | None = None
    age: int = 0
    reason: str = ""

    @property
    def has_depth(self) -> bool:
        return self.fit is not None

    @property
    def n_inliers(self) -> int:
        """Inliers of the fit used (of the raw fit when there is none)."""
        return (self.fit if self.fit is not None else self.raw).n_inliers

    @property
    def frame_status(self) -> "FrameStatus":
        """The pipeline's :class:`~vio_depth.types.FrameStatus` for this result."""
        from .types import FrameStatus

        if self.status == RescaleStatus.OK:
            return FrameStatus.OK
        if self.status == RescaleStatus.SCALE_ONLY:
            return FrameStatus.FALLBACK_SCALE_ONLY
        if self.status == RescaleStatus.PREVIOUS_FIT:
            return FrameStatus.FALLBACK_PREVIOUS_FIT
        return {
            FitStatus.TOO_FEW_POINTS: FrameStatus.TOO_FEW_POINTS,
            FitStatus.DEGENERATE_SPREAD: FrameStatus.ILL_CONDITIONED,
            FitStatus.NO_CONSENSUS: FrameStatus.NO_CONSENSUS,
        }.get(self.raw.status, FrameStatus.NO_CONSENSUS)

    def metric_depth(self, disparity, max_depth: float | None = None) -> np.ndarray | None:
        """(H, W) float32 metres (NaN invalid) from :func:`metric_depth`, or None without depth."""
        return None if self.fit is None else metric_depth(disparity, self.fit, max_depth)

    def depth_sigma(self, disparity, max_depth: float | None = None) -> np.ndarray | None:
        """(H, W) float32 metres from :func:`depth_sigma_map`, or None without depth."""
        return None if self.fit is None else depth_sigma_map(disparity, self.fit, max_depth)


class Rescaler:
    """Per-frame rescaling with state across frames: fallbacks and temporal filtering.

    Fallback order for a frame whose full fit (:func:`fit_affine`) is not OK (only when
    ``settings.fallback`` is on and the last OK frame is at most ``max_fallback_age`` frames
    old):

    1. ``SCALE_ONLY``: :func:`fit_scale_only` with beta (and its variance) of the fit used at
       the last ``OK`` frame; used when it is OK.
    2. ``PREVIOUS_FIT``: the last fit that gave depth (``OK`` or ``SCALE_ONLY``), reused
       unchanged; with the temporal filter on, its covariance is inflated by the filter's
       process noise for every frame of age.
    3. ``NONE``: no metric depth for this frame (``RescaleResult.fit is None``).

    With ``settings.temporal`` set, every OK full fit is a measurement of an
    :class:`~vio_depth.temporal.AffineKalmanFilter` (anchored at the 25 % / 75 % quantiles of
    the disparity map, see :mod:`vio_depth.temporal`: pass ``disparity_map``); the frame
    uses the filtered estimate (or the prediction when the measurement is gated out). Fallback frames are
    not fed to the filter (a scale-only fit reuses the last beta), but each frame is one
    prediction step. Call :meth:`reset` on a known scene change.

    Both fallbacks assume that the network normalised this frame like the last good one
    (beta, or alpha and beta, carried over). That holds for consecutive video frames of a
    network whose normalisation follows the scene's disparity range, not across cuts.
    """

    def __init__(self, settings: RescalerSettings = RescalerSettings()):
        self.settings = settings
        self._filter = None
        if settings.temporal is not None:
            self._filter = AffineKalmanFilter(settings.temporal)
        self.reset()

    def reset(self) -> None:
        """Forget all history (previous fits and the filter state)."""
        self._frame = -1
        self._last_ok_frame: int | None = None
        self._last_ok_fit: AffineFit | None = None
        self._last_used_frame: int | None = None
        self._last_used_fit: AffineFit | None = None
        self._last_used_anchors: tuple[float, float] | None = None
        if self._filter is not None:
            self._filter.reset()

    def _anchors(self, d: np.ndarray, inliers: np.ndarray, disparity_map) -> tuple[float, float]:
        if disparity_map is not None:
            return anchors_from_map(disparity_map, self.settings.temporal)
        return anchors_from_points(d, inliers, self.settings.temporal)

    def update(self, d, depth, sigma_depth=None, weights=None, disparity_map=None) -> RescaleResult:
        """Rescale one frame (call once per frame, in order, even with no points).

        Args:
            d: (N,) affine-invariant disparity at the points (N may be 0).
            depth: (N,) metres.
            sigma_depth: (N,) metres or None.
            weights: (N,) extra weights > 0 or None.
            disparity_map: (H, W) this frame's disparity map, or None. Used only by the
                temporal filter, for its anchors (:func:`~vio_depth.temporal.anchors_from_map`);
                without it the anchors come from the inliers' ``d`` (noisier).

        Returns:
            :class:`RescaleResult`.
        """
        s = self.settings
        self._frame += 1
        raw = fit_affine(d, depth, sigma_depth, weights, s.ransac)
        d = np.asarray(d, dtype=np.float64)
        estimate = anchors = None
        if self._filter is not None:
            if raw.ok:
                try:
                    anchors = self._anchors(d, raw.inliers, disparity_map)
                except InputError:  # e.g. a constant disparity map: use this frame's fit unfiltered
                    anchors = None
            estimate = self._filter.step(raw if anchors is not None else None, anchors)

        if raw.ok:
            used = raw
            reason = raw.reason
            if estimate is not None and anchors is not None:
                used = replace(raw, alpha=estimate.alpha, beta=estimate.beta, covariance=estimate.covariance)
                reason = f"{raw.reason}; filter: {estimate.reason}"
            self._last_ok_frame = self._last_used_frame = self._frame
            self._last_ok_fit = self._last_used_fit = used
            self._last_used_anchors = anchors
            return RescaleResult(RescaleStatus.OK, used, raw, filtered=estimate, reason=reason)

        reasons = [f"fit {raw.status.value}: {raw.reason}"]
        age_ok = None if self._last_ok_frame is None else self._frame - self._last_ok_frame
        if not s.fallback:
            reasons.append("fallbacks disabled")
        elif age_ok is None:
            reasons.append("no previous good frame to fall back on")
        elif age_ok > s.max_fallback_age:
            reasons.append(f"last good frame is {age_ok} frames old (> max_fallback_age {s.max_fallback_age})")
        else:
            prev = self._last_ok_fit
            beta_var = float(prev.covariance[1, 1]) if np.isfinite(prev.covariance[1, 1]) else 0.0
            scale = fit_scale_only(d, depth, prev.beta, beta_var, sigma_depth, weights, s.ransac)
            if scale.ok:
                self._last_used_frame = self._frame
                self._last_used_fit = scale
                if self._filter is not None:
                    try:
                        self._last_used_anchors = self._anchors(d, scale.inliers, disparity_map)
                    except InputError:
                        self._last_used_anchors = None
                return RescaleResult(RescaleStatus.SCALE_ONLY, scale, raw, scale_only=scale, filtered=estimate,
                                     reason="; ".join(reasons + [f"scale-only fit with beta of frame "
                                                                 f"{self._last_ok_frame}: {scale.reason}"]))
            reasons.append(f"scale-only {scale.status.value}: {scale.reason}")
            age = self._frame - self._last_used_frame
            used = self._last_used_fit
            if self._filter is not None and self._last_used_anchors is not None:
                cov = inflate_covariance(used.alpha, used.beta, used.covariance, age, self._last_used_anchors,
                                         s.temporal)
                used = replace(used, covariance=cov)
            reasons.append(f"reusing the fit of frame {self._last_used_frame} ({age} frame(s) old)")
            return RescaleResult(RescaleStatus.PREVIOUS_FIT, used, raw, scale_only=scale, filtered=estimate,
                                 age=age, reason="; ".join(reasons))
        return RescaleResult(RescaleStatus.NONE, None, raw, filtered=estimate, reason="; ".join(reasons))
