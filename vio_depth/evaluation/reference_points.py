"""Reference sparse metric points taken from ground-truth depth, for comparison with SfM.

The paper evaluates its rescaling with simulated low-resolution LiDARs ("evenly selecting
as many horizontal lines in the ground truth depth maps as the number of beams") and with
N random ground-truth samples. Selecting one of these as the point source instead of the
SfM front end (``--points lidar:16``, ``--points random:500``; the option is
:class:`vio_depth.pipeline.PointSourceSpec`) compares SfM with them on the same frames.
Both need ground-truth depth and are an evaluation tool, not a sensor model.
"""

from __future__ import annotations

import numpy as np

from vio_core.checks import check_image
from vio_core.errors import InputError


def _valid_gt(gt_depth) -> tuple[np.ndarray, np.ndarray]:
    gt = check_image("gt_depth", gt_depth)
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(gt) & (gt > 0)
    return gt, valid


def beam_rows(gt_depth, n_beams: int, over_valid_rows: bool = True) -> np.ndarray:
    """Image rows of a simulated ``n_beams``-beam LiDAR.

    The band of rows ``[r0, r1]`` (with ``h = r1 - r0 + 1`` rows) is split into ``n_beams``
    equal parts and each beam takes the row containing the centre of its part::

        row_k = r0 + floor((k + 0.5) * h / n_beams),   k = 0 .. n_beams - 1

    so 1 beam is the middle row of the band. With ``over_valid_rows`` the band is from the
    first to the last row holding any valid ground truth (KITTI's projected LiDAR covers only
    the lower part of the image); otherwise it is the whole image height.

    Args:
        gt_depth: (H, W) metres, 0 = invalid.
        n_beams: number of beams, 1 <= n_beams <= h.
        over_valid_rows: see above.

    Returns:
        (n_beams,) int64 rows, strictly increasing.

    Raises:
        InputError: no valid ground truth, or more beams than rows in the band.
    """
    gt, valid = _valid_gt(gt_depth)
    if n_beams < 1:
        raise InputError(f"lidar: n_beams must be >= 1, got {n_beams}")
    if over_valid_rows:
        rows = np.flatnonzero(valid.any(axis=1))
        if len(rows) == 0:
            raise InputError("lidar: the ground-truth depth has no valid pixel")
        r0, r1 = int(rows[0]), int(rows[-1])
    else:
        r0, r1 = 0, gt.shape[0] - 1
    h = r1 - r0 + 1
    if n_beams > h:
        raise InputError(f"lidar: {n_beams} beams need at least as many rows, the band has {h}")
    return r0 + np.floor((np.arange(n_beams) + 0.5) * h / n_beams).astype(np.int64)


def lidar_beams(gt_depth, n_beams: int, over_valid_rows: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Every valid ground-truth pixel on the rows of :func:`beam_rows`.

    Args:
        gt_depth: (H, W) metres, 0 = invalid.
        n_beams: number of beams (1, 16, 32, 64 in the paper).
        over_valid_rows: see :func:`beam_rows`.

    Returns:
        uv: (N, 2) float64 px, ``(column, row)`` at pixel centres, row-major order.
        depth: (N,) float64 metres.
    """
    gt, valid = _valid_gt(gt_depth)
    rows = beam_rows(gt, n_beams, over_valid_rows)
    sub = valid[rows]
    r_idx, cols = np.nonzero(sub)
    r = rows[r_idx]
    uv = np.stack([cols, r], axis=1).astype(np.float64)
    return uv, gt[r, cols].astype(np.float64)


def random_samples(gt_depth, n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``n`` distinct valid ground-truth pixels drawn uniformly (all of them if fewer).

    Args:
        gt_depth: (H, W) metres, 0 = invalid.
        n: number of samples (>= 1).
        seed: seed of the draw.

    Returns:
        uv: (M, 2) float64 px ``(column, row)``, ``M = min(n, valid pixels)``, row-major order.
        depth: (M,) float64 metres.
    """
    if n < 1:
        raise InputError(f"random: the number of samples must be >= 1, got {n}")
    gt, valid = _valid_gt(gt_depth)
    flat = np.flatnonzero(valid)
    if len(flat) > n:
        flat = np.sort(np.random.default_rng(seed).choice(flat, size=n, replace=False))
    rows, cols = np.divmod(flat, gt.shape[1])
    uv = np.stack([cols, rows], axis=1).astype(np.float64)
    return uv, gt.reshape(-1)[flat].astype(np.float64)
