"""Sampling a map at sub-pixel keypoint positions (where the fit reads the disparity)."""

from __future__ import annotations

import numpy as np

from vio_core.checks import check_array, check_image


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


def disparity_spread(image, uv, radius_px: int) -> np.ndarray:
    """How much a map varies around each position, relative to its value there.

    A keypoint on a depth edge (a corner, where KLT and many detectors put them) reads a
    disparity that belongs to the foreground or the background by a fraction of a pixel; a
    fit on such samples pairs a point's depth with the other surface's disparity.

    Args:
        image: (H, W) float map (e.g. disparity); NaN/inf are invalid pixels.
        uv: (N, 2) px positions (``(x, y)``, as :func:`sample_bilinear`).
        radius_px: half-size of the square window, pixels (the window is ``2 r + 1`` wide).

    Returns:
        (N,) ``(max - min) / |value at the nearest pixel|`` over the window, inf where the
        window leaves the image or holds an invalid pixel, or ``uv`` is not finite.
    """
    img = check_image("image", image)
    uv = check_array("uv", uv, (None, 2))
    r = int(radius_px)
    if r < 0:
        raise ValueError(f"radius_px must be >= 0, got {radius_px}")
    h, w = img.shape
    out = np.full(len(uv), np.inf)
    with np.errstate(invalid="ignore"):
        x = np.round(uv[:, 0])
        y = np.round(uv[:, 1])
        ok = np.isfinite(x) & np.isfinite(y) & (x >= r) & (x <= w - 1 - r) & (y >= r) & (y <= h - 1 - r)
    if not ok.any():
        return out
    xi, yi = x[ok].astype(np.intp), y[ok].astype(np.intp)
    d = np.arange(-r, r + 1)
    win = img[(yi[:, None, None] + d[None, :, None]), (xi[:, None, None] + d[None, None, :])]
    win = win.reshape(len(xi), -1).astype(np.float64)
    centre = np.abs(img[yi, xi].astype(np.float64))
    with np.errstate(invalid="ignore", divide="ignore"):
        spread = (win.max(axis=1) - win.min(axis=1)) / centre
    out[ok] = np.where(np.isfinite(win).all(axis=1) & (centre > 0), spread, np.inf)
    return out
