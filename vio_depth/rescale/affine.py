"""The affine disparity model ``1/D = alpha*d + beta``: its fit settings, result type and point uncertainty.

The fitting itself is in :mod:`vio_depth.rescale.fit` (public) and
:mod:`vio_depth.rescale.msac` (the vectorised machinery).
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field

import numpy as np

from vio_core.checks import check_array
from vio_core.errors import SettingsError

_NAN_COV = np.full((2, 2), np.nan)
_NAN_COV.setflags(write=False)


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
            ``std(1/z) / mean(1/z)``). Below this value -> ``ILL_CONDITIONED``. The default
            0.075 is 1.5 x ``model_relative_sigma``: when the points' metric disparities
            spread barely more than the network's own (spatially correlated) relative
            error, scale and shift cannot be separated -- on the room sample a frame at
            0.060 fitted all 96 accurate points yet gave AbsRel 0.21 against the oracle's
            0.012. The same criterion is checked before sampling on the targets
            ``1/depth`` of all valid points.
        scale_only_min_points: fewer valid points than this -> the scale-only fallback fit
            (:func:`fit_scale_only`, 1-point samples) reports ``TOO_FEW_POINTS``.
        scale_confidence: the covariance is scaled by the residual scatter (reduced
            chi-square), which a fit on n inliers estimates from only ``n - p`` degrees of
            freedom (p = 2, or 1 for the scale-only fit): it is taken at its upper confidence
            bound at this probability, ``chi2 * dof / chi2_quantile(1 - scale_confidence,
            dof)`` (:func:`~vio_depth.rescale.msac.scale_inflation`), so that a fit on few
            points does not claim the certainty of its luckiest residuals. The factor on the
            variance is 2.9 for 10 inliers, 1.9 for 21, 1.3 for 100, 1.1 for 1000; 0 takes
            the point estimate. With the point estimate the actual error of a fit on 10-14
            points fell outside its predicted 95 % interval in 7-9 % of synthetic fits, and
            the street sample's first pair (21 inliers, r2 0.82) was written with AbsRel
            0.057 (oracle 0.017) against a predicted error of 0.027
            (tests/vio_depth/rescale/test_small_sample.py).
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
    scale_confidence: float = 0.95

    def __post_init__(self):
        positive = ("inlier_sigmas", "min_sigma_disparity", "batch_size", "max_iterations")
        for name in positive:
            if not getattr(self, name) > 0:
                raise SettingsError(f"RansacSettings.{name} must be > 0, got {getattr(self, name)!r}")
        if not 0.0 < self.confidence < 1.0:
            raise SettingsError(f"RansacSettings.confidence must be in (0, 1), got {self.confidence!r}")
        if not 0.0 <= self.scale_confidence < 1.0:
            raise SettingsError(f"RansacSettings.scale_confidence must be in [0, 1), got {self.scale_confidence!r}")
        if not 0.0 <= self.min_inlier_ratio <= 1.0:
            raise SettingsError(f"RansacSettings.min_inlier_ratio must be in [0, 1], got {self.min_inlier_ratio!r}")
        for name in ("model_relative_sigma", "min_iterations", "lo_iterations", "min_relative_spread",
                     "score_points", "reweight_tolerance"):
            if getattr(self, name) < 0:
                raise SettingsError(f"RansacSettings.{name} must be >= 0, got {getattr(self, name)!r}")
        if self.min_points < 2 or self.min_inliers < 2 or self.scale_only_min_points < 1:
            raise SettingsError("RansacSettings: min_points and min_inliers must be >= 2, scale_only_min_points >= 1")


class FitStatus(str, enum.Enum):
    """Outcome of one robust fit (:func:`fit_affine` / :func:`fit_scale_only`).

    Checked in this order: ``TOO_FEW_POINTS`` (fewer than ``min_points`` valid points),
    ``ILL_CONDITIONED`` (targets of all points nearly equal), ``NO_CONSENSUS`` (no
    hypothesis with alpha > 0, or too few inliers), ``ILL_CONDITIONED`` (inliers' spread
    too narrow), ``NO_CONSENSUS`` (R^2 <= 0: the line explains none of the inliers'
    spread), ``OK``. Fallback stages are :class:`~vio_depth.rescale.rescaler.FitSource` of the :class:`Rescaler`.
    """

    OK = "ok"
    TOO_FEW_POINTS = "too_few_points"
    ILL_CONDITIONED = "ill_conditioned"
    NO_CONSENSUS = "no_consensus"


@dataclass(frozen=True)
class AffineFit:
    """Result of fitting ``1/depth = alpha * d + beta``.

    Attributes:
        alpha: scale (1/m per unit of ``d``), > 0 when ``ok``; may be NaN when no
            hypothesis existed.
        beta: shift, 1/m.
        covariance: (2, 2) covariance of ``(alpha, beta)`` (weighted least squares on the
            inliers, scaled by the reduced chi-square of their standardised residuals at its
            upper confidence bound, :attr:`RansacSettings.scale_confidence`); NaN when
            unknown.
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
        shared_covariance: (2, 2) the part of ``covariance`` that comes from errors every
            point shares (a relative pose's error moves all its points together, so it does
            not average out over points; :func:`~vio_depth.rescale.fit.fit_affine`'s
            ``depth_shared``); zeros when none was given, NaN when unknown.
        model_relative_sd: robust standard deviation (1.4826 MAD) of the inliers' relative
            residuals ``(m - alpha*d - beta) / (alpha*d + beta)``: the disparity's own error,
            which no rescaling removes (the oracle's), plus the points' noise -- an estimate
            from above; NaN when unknown.
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
    shared_covariance: np.ndarray = field(default_factory=lambda: _NAN_COV, repr=False)
    model_relative_sd: float = math.nan

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
            "model_relative_sd": _json_float(self.model_relative_sd),
            "fit_status": self.status.value,
            "fit_reason": self.reason,
            "iterations": self.iterations,
        }


def _json_float(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


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

