"""Colour lookup tables (LUTs) and the depth <-> colour mapping of the previews.

A LUT is a (256, 3) uint8 RGB table. Sequential maps (turbo, viridis, ...) come from
OpenCV's ``applyColorMap``; the diverging map of the error previews ("coolwarm": blue ->
light grey -> red, 255 distinct levels) is built here. Depth maps to a LUT index through a fixed range
``[vmin, vmax]`` metres on a log (default) or linear axis, **near = index 255** (turbo:
red, viridis: yellow), far = index 0; :func:`depth_from_rgb` inverts the mapping (the
nearest LUT colour), which is how tests check that a preview's colour means its depth.
"""

from __future__ import annotations

from functools import lru_cache

import cv2
import numpy as np

from vio_core.checks import check_array
from vio_core.errors import SettingsError, lookup

#: OpenCV colormap names usable for depth previews (perceptually ordered maps only).
_CV2_MAPS = {
    "turbo": "COLORMAP_TURBO",
    "viridis": "COLORMAP_VIRIDIS",
    "inferno": "COLORMAP_INFERNO",
    "magma": "COLORMAP_MAGMA",
    "plasma": "COLORMAP_PLASMA",
    "cividis": "COLORMAP_CIVIDIS",
}
SCALES = ("log", "linear")
#: distinct levels of the diverging "coolwarm" map of error previews (indices 0..254, 127 = zero)
ERROR_LEVELS = 255


def available_colormaps() -> list[str]:
    """Names accepted by :func:`colormap_lut` for depth previews."""
    return sorted(_CV2_MAPS)


@lru_cache(maxsize=None)
def _lut(name: str) -> np.ndarray:
    if name == "coolwarm":
        # blue (59, 76, 192) -> light grey (221, 221, 221) at 127 -> red (180, 4, 38) at 254, linear
        # in RGB; 255 levels (entry 255 repeats 254) so that an error map plus its invalid colour
        # fits an 8-bit palette PNG, and zero error has an entry of its own
        ends = np.array([[59, 76, 192], [221, 221, 221], [180, 4, 38]], dtype=np.float64)
        t = np.linspace(0.0, 2.0, ERROR_LEVELS)[:, None]
        lo = np.clip(1.0 - t, 0.0, 1.0) * ends[0] + np.clip(1.0 - np.abs(t - 1.0), 0.0, 1.0) * ends[1]
        lut = np.rint(lo + np.clip(t - 1.0, 0.0, 1.0) * ends[2]).astype(np.uint8)
        return np.concatenate([lut, lut[-1:]])
    code = getattr(cv2, lookup("colormap", name, _CV2_MAPS))
    ramp = np.arange(256, dtype=np.uint8)[:, None]
    return np.ascontiguousarray(cv2.applyColorMap(ramp, code)[:, 0, ::-1])  # BGR -> RGB


def colormap_lut(name: str) -> np.ndarray:
    """(256, 3) uint8 RGB lookup table of colormap ``name`` (see :func:`available_colormaps`,
    plus ``"coolwarm"``, the diverging map of error previews). Read-only.

    Raises:
        UnknownNameError: unknown name (lists the valid ones).
    """
    lut = _lut(name)
    lut.setflags(write=False)
    return lut


def _check_range(vmin: float, vmax: float, scale: str) -> None:
    if scale not in SCALES:
        raise SettingsError(f"preview scale must be one of {', '.join(SCALES)}, got {scale!r}")
    if not (np.isfinite(vmin) and np.isfinite(vmax) and vmax > vmin):
        raise SettingsError(f"preview range must satisfy vmin < vmax (finite), got [{vmin}, {vmax}]")
    if scale == "log" and not vmin > 0:
        raise SettingsError(f"a log preview range needs vmin > 0 metres, got {vmin}")


def depth_to_index(depth, vmin: float, vmax: float, scale: str = "log") -> tuple[np.ndarray, np.ndarray]:
    """LUT indices of ``depth: (...)`` metres in the range ``[vmin, vmax]`` metres.

    Depths outside the range are clipped to it. Near (``vmin``) is index 255, far
    (``vmax``) index 0. Returns ``(index (...) uint8, valid (...) bool)``; invalid
    (NaN, inf, <= 0) pixels get index 0 and ``valid`` False.

    Raises:
        SettingsError: bad range or scale.
    """
    _check_range(vmin, vmax, scale)
    d = np.asarray(depth, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(d) & (d > 0)
    x = np.clip(np.where(valid, d, vmax), vmin, vmax)
    if scale == "log":
        t = (np.log(x) - np.log(vmin)) / (np.log(vmax) - np.log(vmin))
    else:
        t = (x - vmin) / (vmax - vmin)
    index = np.rint((1.0 - t) * 255.0).astype(np.uint8)
    index[~valid] = 0
    return index, valid


def index_to_depth(index, vmin: float, vmax: float, scale: str = "log") -> np.ndarray:
    """Inverse of :func:`depth_to_index`: depth in metres (float64) at LUT ``index (...)``."""
    _check_range(vmin, vmax, scale)
    t = 1.0 - np.asarray(index, dtype=np.float64) / 255.0
    if scale == "log":
        return np.exp(np.log(vmin) + t * (np.log(vmax) - np.log(vmin)))
    return vmin + t * (vmax - vmin)


def colourise(index, valid, lut, invalid_rgb=(0, 0, 0)) -> np.ndarray:
    """RGB image ``(..., 3)`` uint8 of LUT ``index (...)`` with ``~valid`` pixels set to ``invalid_rgb``."""
    lut = check_array("lut", lut, (256, 3), dtype=None)
    index = np.asarray(index, dtype=np.uint8)
    rgb = lut[index]
    rgb[~np.asarray(valid, dtype=bool)] = np.asarray(invalid_rgb, dtype=np.uint8)
    return rgb


def nearest_index(rgb, lut) -> np.ndarray:
    """LUT index ``(...)`` of the nearest LUT colour to each ``rgb (..., 3)`` colour."""
    lut = check_array("lut", lut, (256, 3), dtype=None).astype(np.int32)
    rgb = np.asarray(rgb).astype(np.int32)
    if rgb.shape[-1:] != (3,):
        raise SettingsError(f"rgb: expected shape (..., 3), got {rgb.shape}")
    flat = rgb.reshape(-1, 3)
    out = np.empty(len(flat), dtype=np.int64)
    for start in range(0, len(flat), 4096):  # chunks keep the (n, 256) distance table small
        chunk = flat[start:start + 4096]
        out[start:start + 4096] = np.argmin(((chunk[:, None, :] - lut[None, :, :]) ** 2).sum(-1), axis=1)
    return out.reshape(rgb.shape[:-1])


def depth_from_rgb(rgb, vmin: float, vmax: float, colormap: str = "turbo", scale: str = "log",
                   invalid_rgb=(0, 0, 0)) -> np.ndarray:
    """Read depth (metres, float64, NaN = invalid colour) back from preview colours ``rgb (..., 3)``.

    Exact to half a LUT step of the range (log: a factor ``(vmax/vmin)**(1/510)``) for
    depths inside ``[vmin, vmax]``; depths outside read back as the range ends.
    """
    rgb = np.asarray(rgb)
    depth = index_to_depth(nearest_index(rgb, colormap_lut(colormap)), vmin, vmax, scale)
    invalid = np.all(rgb.astype(np.int32) == np.asarray(invalid_rgb, dtype=np.int32), axis=-1)
    return np.where(invalid, np.nan, depth)
