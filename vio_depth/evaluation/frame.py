"""Evaluating one frame's result against its ground-truth depth (dense metrics, oracle, points)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vio_core.checks import check_array, check_image

from ..rescale import metric_depth
from .metrics import DepthMetrics, _check_range, _gt_mask, metrics_on_pixels, oracle_fit
from .point_accuracy import PointAccuracy, point_depth_errors


@dataclass(frozen=True)
class FrameEvaluation:
    """One frame against ground truth.

    Attributes:
        metrics: dense metrics of the predicted depth (None without a prediction).
        oracle: dense metrics of the oracle rescaling of the same disparity (least squares
            on all ground-truth pixels: the best any rescaling can do), or None.
        points: accuracy of the metric points fed to the fit, or None when not evaluated.
        rescale_abs_rel: mean of ``|D / D_oracle - 1|`` over the evaluated pixels where both
            have depth: the error of the rescaling alone (what the fit's
            ``predicted_error`` predicts), without the disparity's own error; or None.
    """

    metrics: DepthMetrics | None = None
    oracle: DepthMetrics | None = None
    points: PointAccuracy | None = None
    rescale_abs_rel: float | None = None


def evaluate_frame(gt_depth, depth=None, disparity=None, points_uv=None, points_depth=None, *,
                   min_depth: float = 1e-3, max_depth: float = 80.0, points: bool = True) -> FrameEvaluation:
    """Evaluate a frame's outputs against its ground truth.

    Args:
        gt_depth: (H, W) metres, 0 = invalid.
        depth: (H, W) metres predicted (NaN = invalid), or None (no prediction, nor oracle).
        disparity: (H, W) the disparity that was rescaled (for the oracle), or None.
        points_uv: (N, 2) raw px / points_depth: (N,) metres: the metric points, or None.
        min_depth, max_depth: metres, the evaluated ground-truth range.
        points: evaluate the points (False for reference points sampled from this ground truth).
    """
    metrics = oracle = acc = rescale = None
    if depth is not None:
        # as compute_metrics(depth, gt) and compute_metrics(oracle depth, gt), with the mask, the
        # ground truth and its log computed once and the oracle's depth only where evaluated
        gt_depth = check_image("gt_depth", gt_depth)
        depth = check_array("depth", depth, gt_depth.shape)
        _check_range(min_depth, max_depth)
        mask = _gt_mask(gt_depth, min_depth, max_depth)
        g = gt_depth[mask].astype(np.float64)
        log_g = np.log(g)
        metrics = metrics_on_pixels(depth[mask], g, log_g, min_depth, max_depth)
        if disparity is not None:
            ofit = oracle_fit(disparity, gt_depth, min_depth=min_depth, max_depth=max_depth)
            if ofit.ok:
                oracle_depth = metric_depth(check_array("disparity", disparity, gt_depth.shape)[mask][None], ofit)[0]
                oracle = metrics_on_pixels(oracle_depth, g, log_g, min_depth, max_depth)
                ours = depth[mask].astype(np.float64)
                both = np.isfinite(ours) & np.isfinite(oracle_depth) & (oracle_depth > 0)
                if both.any():
                    rescale = float(np.mean(np.abs(ours[both] / oracle_depth[both] - 1.0)))
    if points and points_uv is not None and len(points_uv):
        acc = point_depth_errors(points_uv, points_depth, gt_depth)
    return FrameEvaluation(metrics, oracle, acc, rescale)


def aggregate_point_accuracy(rows) -> dict:
    """Medians over frames of the per-frame point accuracy (frames without points are left out)."""
    rows = [r for r in rows if r is not None and r.count > 0]
    if not rows:
        return {"frames": 0}
    return {
        "frames": len(rows),
        "points_per_frame_median": float(np.median([r.count for r in rows])),
        "rel_err_median_of_frames": float(np.median([r.median for r in rows])),
        "rel_err_p90_median_of_frames": float(np.median([r.p90 for r in rows])),
    }
