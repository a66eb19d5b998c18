"""Standard depth metrics (Eigen et al.; Depth Anything's evaluation) and the oracle rescaling.

Protocol of :func:`compute_metrics`, stated once:

* Evaluated pixels ``Omega``: ground truth finite and within ``[min_depth, max_depth]``
  (0 = no ground truth).
* Predictions are clamped to ``[min_depth, max_depth]`` as in Depth Anything's evaluation;
  a prediction that is *invalid* (NaN, inf or <= 0: no metric depth there) inside ``Omega``
  is set to ``max_depth`` before clamping, so a method cannot improve its scores by
  leaving hard pixels out. ``coverage`` reports the fraction of ``Omega`` that had a valid
  prediction.
* ``abs_rel = mean(|p - g| / g)``, ``sq_rel = mean((p - g)**2 / g)``,
  ``rmse = sqrt(mean((p - g)**2))``, ``rmse_log = sqrt(mean((ln p - ln g)**2))``,
  ``delta_k = mean(max(p/g, g/p) < 1.25**k)``.
* :func:`average_metrics` averages per-frame values over frames (Eigen protocol), not
  over pixels.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from vio_core.checks import check_array, check_image
from vio_core.errors import InputError, ShapeError
from vio_core.geometry import transform_points

from ..rescale import AffineFit, FitStatus


@dataclass(frozen=True)
class DepthMetrics:
    """Depth errors of one frame, or their frame average.

    Attributes:
        abs_rel, sq_rel (metres), rmse (metres), rmse_log, delta1, delta2, delta3: see
            the module docstring; NaN when no pixel was evaluated.
        n_pixels: evaluated pixels (summed over frames for an average).
        coverage: fraction of evaluated pixels with a valid prediction (frame-averaged).
        n_frames: frames averaged (1 for a single frame; frames with no evaluated pixel
            are not counted).
    """

    abs_rel: float
    sq_rel: float
    rmse: float
    rmse_log: float
    delta1: float
    delta2: float
    delta3: float
    n_pixels: int
    coverage: float
    n_frames: int = 1

    def to_json(self) -> dict:
        return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in asdict(self).items()}


_EMPTY = dict(abs_rel=math.nan, sq_rel=math.nan, rmse=math.nan, rmse_log=math.nan, delta1=math.nan,
              delta2=math.nan, delta3=math.nan, n_pixels=0, coverage=math.nan)


def _check_range(min_depth: float, max_depth: float) -> None:
    if not 0 < min_depth < max_depth:
        raise InputError(f"depth range must satisfy 0 < min_depth < max_depth, got [{min_depth}, {max_depth}]")


def _gt_mask(gt: np.ndarray, min_depth: float, max_depth: float) -> np.ndarray:
    with np.errstate(invalid="ignore"):
        return np.isfinite(gt) & (gt >= min_depth) & (gt <= max_depth)


def compute_metrics(pred, gt, min_depth: float = 1e-3, max_depth: float = 80.0) -> DepthMetrics:
    """Depth metrics of one frame.

    Args:
        pred: (H, W) metres, predicted depth; NaN (or inf, <= 0) = no prediction.
        gt: (H, W) metres, ground-truth depth; 0 (or NaN) = no ground truth.
        min_depth: metres, evaluation range lower bound (> 0).
        max_depth: metres, evaluation range upper bound (80 m for KITTI, 10 m for indoor).

    Returns:
        :class:`DepthMetrics` (all NaN with ``n_pixels = 0`` when no pixel is evaluated).

    Raises:
        ShapeError: ``pred`` and ``gt`` differ in shape or are not (H, W).
        InputError: invalid depth range.
    """
    pred = check_image("pred", pred)
    gt = check_image("gt", gt)
    if pred.shape != gt.shape:
        raise ShapeError(f"pred: shape {pred.shape} differs from gt {gt.shape}")
    _check_range(min_depth, max_depth)
    mask = _gt_mask(gt, min_depth, max_depth)
    g = gt[mask].astype(np.float64)
    return metrics_on_pixels(pred[mask], g, np.log(g), min_depth, max_depth)


def metrics_on_pixels(p, g, log_g, min_depth: float, max_depth: float) -> DepthMetrics:
    """:func:`compute_metrics` on the evaluated pixels only (the ground-truth mask applied
    once by the caller and shared between several predictions of one frame).

    Args:
        p: (n,) predicted metres at the evaluated pixels (NaN, inf, <= 0 = no prediction).
        g: (n,) float64 ground-truth metres there; log_g: ``np.log(g)``.
        min_depth, max_depth: metres, the evaluated range.
    """
    n = len(g)
    if n == 0:
        return DepthMetrics(**_EMPTY)
    p = np.asarray(p).astype(np.float64)
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(p) & (p > 0)
    p = np.clip(np.where(valid, p, max_depth), min_depth, max_depth)
    diff = p - g
    ratio = np.maximum(p / g, g / p)
    return DepthMetrics(
        abs_rel=float(np.mean(np.abs(diff) / g)),
        sq_rel=float(np.mean(diff * diff / g)),
        rmse=float(np.sqrt(np.mean(diff * diff))),
        rmse_log=float(np.sqrt(np.mean((np.log(p) - log_g) ** 2))),
        delta1=float(np.mean(ratio < 1.25)),
        delta2=float(np.mean(ratio < 1.25**2)),
        delta3=float(np.mean(ratio < 1.25**3)),
        n_pixels=n,
        coverage=float(np.count_nonzero(valid)) / n,
    )


def average_metrics(frames) -> DepthMetrics:
    """Frame average of per-frame :class:`DepthMetrics` (Eigen protocol).

    Frames with ``n_pixels == 0`` are skipped. Errors and coverage are averaged with each
    frame weighted by its ``n_frames`` (so averages of averages stay frame averages);
    ``n_pixels`` and ``n_frames`` are summed.

    Raises:
        InputError: no frame with evaluated pixels.
    """
    frames = [f for f in frames if f.n_pixels > 0]
    if not frames:
        raise InputError("average_metrics: no frame with evaluated pixels")
    weights = np.array([f.n_frames for f in frames], dtype=np.float64)

    def mean(name: str) -> float:
        return float(np.average([getattr(f, name) for f in frames], weights=weights))

    return DepthMetrics(
        abs_rel=mean("abs_rel"), sq_rel=mean("sq_rel"), rmse=mean("rmse"), rmse_log=mean("rmse_log"),
        delta1=mean("delta1"), delta2=mean("delta2"), delta3=mean("delta3"),
        n_pixels=int(sum(f.n_pixels for f in frames)), coverage=mean("coverage"),
        n_frames=int(weights.sum()),
    )


def oracle_fit(disparity, gt, min_depth: float = 1e-3, max_depth: float = 80.0) -> AffineFit:
    """The best affine rescaling of ``disparity`` given the ground truth.

    Ordinary least squares of the metric disparity ``1/gt`` on ``d`` over every pixel with
    finite ``d`` and ground truth in ``[min_depth, max_depth]`` (no robust loss, no weights):
    the reference for what any rescaling of this disparity map can reach.

    Args:
        disparity: (H, W) affine-invariant disparity.
        gt: (H, W) metres, 0 = invalid.
        min_depth, max_depth: metres, evaluated range.

    Returns:
        :class:`~vio_depth.rescale.AffineFit` over the valid pixels in row-major order
        (``inliers`` all True); status OK, or TOO_FEW_POINTS (< 2 valid pixels or constant
        ``d``) / NO_CONSENSUS (least squares gives alpha <= 0), with a reason.
    """
    disp = check_image("disparity", disparity)
    gt = check_image("gt", gt)
    if disp.shape != gt.shape:
        raise ShapeError(f"disparity: shape {disp.shape} differs from gt {gt.shape}")
    _check_range(min_depth, max_depth)
    mask = _gt_mask(gt, min_depth, max_depth) & np.isfinite(disp)
    d = disp[mask].astype(np.float64)
    m = 1.0 / gt[mask].astype(np.float64)
    n = len(d)
    nan_cov = np.full((2, 2), np.nan)

    def failed(status: FitStatus, reason: str) -> AffineFit:
        return AffineFit(math.nan, math.nan, nan_cov, np.ones(n, bool), n, n, 1.0 if n else 0.0, math.nan,
                         math.nan, math.nan, math.nan, status, reason)

    if n < 3:
        return failed(FitStatus.TOO_FEW_POINTS, f"{n} valid pixel(s), need 3")
    d_mean, m_mean = d.mean(), m.mean()
    dc, mc = d - d_mean, m - m_mean
    sdd = float(dc @ dc)
    if not sdd > 0:
        return failed(FitStatus.TOO_FEW_POINTS, "disparity is constant over the valid pixels")
    alpha = float(dc @ mc) / sdd
    beta = float(m_mean - alpha * d_mean)
    r = mc - alpha * dc
    ss_res = float(r @ r)
    ss_tot = float(mc @ mc)
    s2 = ss_res / (n - 2)
    cov = s2 * np.array([[1.0 / sdd, -d_mean / sdd], [-d_mean / sdd, 1.0 / n + d_mean**2 / sdd]])
    spread = float(np.sqrt(sdd / n))
    mean_fit = alpha * float(d_mean) + beta
    status, reason = FitStatus.OK, f"least squares over {n} ground-truth pixels"
    if not alpha > 0:
        status, reason = FitStatus.NO_CONSENSUS, f"least squares gives alpha = {alpha:.4g} <= 0"
    return AffineFit(
        alpha=alpha, beta=beta, covariance=cov, inliers=np.ones(n, bool), n_points=n, n_inliers=n,
        inlier_ratio=1.0, r2=1.0 - ss_res / ss_tot if ss_tot > 0 else math.nan, disparity_spread=spread,
        relative_spread=alpha * spread / mean_fit if mean_fit > 0 else math.nan, mean_metric_disparity=mean_fit,
        status=status, reason=reason,
    )


def depth_reprojection_errors(depth_a, depth_b, camera, T_b_a) -> np.ndarray:
    """Relative errors of frame a's depth moved into frame b with the poses, against b's depth.

    A consistency check of ground-truth depth and poses (e.g. OXTS poses against projected
    LiDAR): every valid pixel of ``depth_a`` is back-projected, transformed with ``T_b_a``,
    projected into b and compared with ``depth_b`` at the nearest pixel.

    Args:
        depth_a: (H, W) metres, 0 / NaN = invalid.
        depth_b: (H, W) metres, 0 / NaN = invalid.
        camera: :class:`~vio_core.camera.Camera` of both (undistorted) depth maps.
        T_b_a: (4, 4) frame-a-camera to frame-b-camera transform, metres.

    Returns:
        (M,) ``|z_ab - z_b| / z_b`` for the points landing on a valid pixel of b.
    """
    da = check_image("depth_a", depth_a).astype(np.float64)
    db = check_image("depth_b", depth_b).astype(np.float64)
    if da.shape != db.shape or da.shape != (camera.height, camera.width):
        raise ShapeError(f"depth maps {da.shape} / {db.shape} do not match the camera "
                         f"({camera.height}, {camera.width})")
    T = check_array("T_b_a", T_b_a, (4, 4), finite=True)
    with np.errstate(invalid="ignore"):
        v, u = np.nonzero(da > 0)
    points_b = transform_points(T, camera.backproject(np.stack([u, v], 1).astype(float), da[v, u]))
    uv, z = camera.project(points_b)
    c, r = np.round(uv[:, 0]), np.round(uv[:, 1])
    with np.errstate(invalid="ignore"):
        ok = (z > 0) & (c >= 0) & (c < camera.width) & (r >= 0) & (r < camera.height)
    g = db[r[ok].astype(int), c[ok].astype(int)]
    with np.errstate(invalid="ignore"):
        hit = g > 0
    return np.abs(z[ok][hit] - g[hit]) / g[hit]
