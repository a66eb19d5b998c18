"""Float depth maps as ``.npy``: exact float32 metres, NaN = invalid (no quantisation, no cap).

The 16-bit PNGs of a run quantise to 1/256 m and saturate at 256 m; the ``.npy`` twin
keeps the pipeline's float32 values bit for bit.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from vio_core.checks import check_array
from vio_core.errors import InputError
from vio_core.npyfile import load_array

from ..io.depth_png import write_bytes_atomic


def depth_as_float32(depth) -> np.ndarray:
    """``depth: (H, W)`` metres -> float32 copy with every invalid value (NaN, inf, <= 0) as NaN."""
    depth = check_array("depth", depth, (None, None))
    out = depth.astype(np.float32, copy=True)
    with np.errstate(invalid="ignore"):
        out[~(np.isfinite(out) & (out > 0))] = np.nan
    return out


def write_depth_npy(path, depth) -> None:
    """Write ``depth: (H, W)`` metres as a float32 ``.npy`` (NaN = invalid), atomically.

    Valid values are stored exactly as float32 (the pipeline's maps are float32 already);
    NaN, +-inf and values <= 0 become NaN.

    Raises:
        ShapeError: ``depth`` is not a 2-D numeric array.
        InputError: wrong suffix or the file cannot be written.
    """
    path = Path(path)
    if path.suffix != ".npy":
        raise InputError(f"{path}: float depth maps are written as .npy files")
    buf = io.BytesIO()
    np.save(buf, depth_as_float32(depth), allow_pickle=False)
    try:
        write_bytes_atomic(path, buf.getvalue())
    except OSError as exc:
        raise InputError(f"{path}: cannot write depth .npy ({exc.strerror})") from None


def read_depth_npy(path) -> np.ndarray:
    """Read a depth ``.npy`` written by :func:`write_depth_npy`: (H, W) float32 metres, NaN invalid.

    Raises:
        InputError: missing file, not a 2-D float32 array.
    """
    path = Path(path)
    arr = load_array(path, "depth .npy")
    if arr.ndim != 2 or arr.dtype != np.float32:
        raise InputError(f"{path}: expected a 2-D float32 depth map, got {arr.dtype} {arr.shape}")
    return arr
