"""Accuracy of the sparse metric points themselves against ground-truth depth.

This is separate from the error of the rescaled dense depth: it says how good the
triangulated points (the input of the robust fit) are, per frame.

Robust reference: the ground truth of a point is the **median of the valid
ground-truth depths in a small window** around its pixel (default 5 x 5), not the single
pixel under it. This tolerates sparse ground truth (KITTI LiDAR leaves most pixels
empty) and a depth camera that is not registered to the colour camera (7-Scenes: depth
edges shifted by 10-20 px). Near depth discontinuities the window may still mix
foreground and background; the per-frame **median** and 90th percentile are meant to
be read with that in mind, and points without any valid ground truth in their window
are not counted.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from vio_core.checks import check_array
from vio_core.errors import InputError


@dataclass(frozen=True)
class PointAccuracy:
    """Relative depth error of one frame's points.

    Attributes:
        count: number of points with a ground-truth reference.
        median: median of ``|z - z_gt| / z_gt`` over those points (NaN when count is 0).
        p90: 90th percentile of the same (NaN when count is 0).
        bias: median of the signed ``(z - z_gt) / z_gt`` (NaN when count is 0).
        evaluated: (N,) bool, which input points had a reference.
        gt_depth: (N,) metres, the window-median reference (NaN where not evaluated).
    """

    count: int
    median: float
    p90: float
    bias: float
    evaluated: np.ndarray = field(repr=False)
    gt_depth: np.ndarray = field(repr=False)

    def to_json(self) -> dict:
        def r(x):
            return None if not np.isfinite(x) else round(float(x), 5)

        return {"points_evaluated": self.count, "points_rel_err_median": r(self.median),
                "points_rel_err_p90": r(self.p90), "points_rel_err_bias": r(self.bias)}


def window_median_depth(uv, gt_depth, window: int = 2, min_valid: int = 1) -> np.ndarray:
    """Median of the valid ground truth in a ``(2 window + 1)^2`` pixel window around each point.

    Args:
        uv: (N, 2) pixels (x right, y down) in the pixel grid of ``gt_depth``.
        gt_depth: (H, W) metres, 0 (or NaN / negative) = invalid.
        window: half-width in pixels (0 = the pixel itself).
        min_valid: fewest valid pixels in the window for a reference.

    Returns:
        (N,) metres, NaN where the point is outside the image or has fewer than
        ``min_valid`` valid ground-truth pixels in its window.
    """
    uv = check_array("uv", uv, (None, 2))
    gt = check_array("gt_depth", gt_depth, (None, None))
    if window < 0 or min_valid < 1:
        raise InputError(f"window must be >= 0 and min_valid >= 1, got {window}, {min_valid}")
    H, W = gt.shape
    n = len(uv)
    out = np.full(n, np.nan)
    if n == 0:
        return out
    with np.errstate(invalid="ignore"):
        col = np.round(uv[:, 0])
        row = np.round(uv[:, 1])
    inside = np.isfinite(col) & np.isfinite(row) & (col >= 0) & (col < W) & (row >= 0) & (row < H)
    if not inside.any():
        return out
    c = col[inside].astype(np.int64)
    r = row[inside].astype(np.int64)
    d = np.arange(-window, window + 1)
    dr, dc = np.meshgrid(d, d, indexing="ij")
    rr = r[:, None] + dr.ravel()[None, :]
    cc = c[:, None] + dc.ravel()[None, :]
    in_img = (rr >= 0) & (rr < H) & (cc >= 0) & (cc < W)
    vals = gt[np.clip(rr, 0, H - 1), np.clip(cc, 0, W - 1)].astype(np.float64)
    valid = in_img & np.isfinite(vals) & (vals > 0)
    vals = np.where(valid, vals, np.nan)
    enough = valid.sum(axis=1) >= min_valid
    med = np.full(len(c), np.nan)
    if enough.any():
        med[enough] = np.nanmedian(vals[enough], axis=1)
    out[inside] = med
    return out


def point_depth_errors(uv, depth, gt_depth, window: int = 2, min_valid: int = 1) -> PointAccuracy:
    """Relative depth error of sparse metric points against a ground-truth depth map.

    Args:
        uv: (N, 2) pixels of the points in the pixel grid of ``gt_depth``.
        depth: (N,) metres, the points' depths (camera z). Non-positive or non-finite
            depths are not evaluated.
        gt_depth: (H, W) metres, 0 = invalid.
        window: half-width in pixels of the window whose valid ground-truth median is
            the reference (see the module docstring; 2 -> 5 x 5 pixels).
        min_valid: fewest valid ground-truth pixels in the window.

    Returns:
        :class:`PointAccuracy` with median / p90 of ``|z - z_gt| / z_gt`` and the count.
    """
    uv = check_array("uv", uv, (None, 2))
    depth = check_array("depth", depth, (len(uv),))
    ref = window_median_depth(uv, gt_depth, window, min_valid)
    ok = np.isfinite(ref) & np.isfinite(depth) & (depth > 0)
    if not ok.any():
        return PointAccuracy(0, float("nan"), float("nan"), float("nan"), ok, np.where(ok, ref, np.nan))
    signed = (depth[ok] - ref[ok]) / ref[ok]
    rel = np.abs(signed)
    return PointAccuracy(int(ok.sum()), float(np.median(rel)), float(np.percentile(rel, 90)),
                         float(np.median(signed)), ok, np.where(ok, ref, np.nan))
