"""16-bit PNG depth maps in the KITTI convention: ``uint16 = round(metres * 256)``, 0 = invalid.

The resolution is 1/256 m (3.9 mm) and the largest storable depth is 65535 / 256 =
255.996 m. Both functions take an optional ``scale`` (units per metre) so that other
integer conventions (e.g. ``scale=1000`` for millimetre PNGs) can share the code, but the
native sequence format always uses 256.
"""

from __future__ import annotations

import math
import os
import tempfile
from pathlib import Path
from typing import Iterable

import cv2
import numpy as np

from vio_core.checks import check_array
from vio_core.errors import InputError, SequenceFormatError

from .decode import decode_image
from .images import read_image_bytes

#: KITTI / native-format depth scale: stored uint16 value per metre.
DEPTH_PNG_SCALE = 256.0
#: ``cv2.imencode`` parameters of the PNGs a run writes, chosen for speed: each row filtered as
#: the difference to its left neighbour (SUB), then Huffman coding only (no LZ77 search, so
#: the zlib level does not matter). On 1242x375 depth maps ~14x faster than zlib level 9 with
#: adaptive filters, and 1 % smaller (docs/benchmarks.md, "PNG compression").
FAST_PNG_PARAMS = (cv2.IMWRITE_PNG_COMPRESSION, 1, cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_HUFFMAN_ONLY,
                   cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_SUB)
#: the default: zlib level 9, adaptive filters (the datasets the samples ship with)
SMALL_PNG_PARAMS = (cv2.IMWRITE_PNG_COMPRESSION, 9)


def read_depth_png(path, scale: float = DEPTH_PNG_SCALE) -> np.ndarray:
    """Read a 16-bit depth PNG.

    Args:
        path: file path.
        scale: stored units per metre (256 for the KITTI / native convention).

    Returns:
        depth: (H, W) float32 metres; pixels stored as 0 are returned as 0.0 (invalid).

    Raises:
        SequenceFormatError: the file is missing, unreadable, not single-channel or not
            16-bit unsigned (the message names the file).
    """
    path = Path(path)
    if not path.is_file():
        raise SequenceFormatError(path, "depth PNG not found")
    data = read_image_bytes(path)
    raw = decode_image(data, cv2.IMREAD_UNCHANGED, path, what="depth PNG")
    if raw.ndim != 2:
        raise SequenceFormatError(path, f"depth PNG must be single-channel, got shape {raw.shape}")
    if raw.dtype != np.uint16:
        raise SequenceFormatError(path, f"depth PNG must be 16-bit unsigned, got {raw.dtype}")
    return (raw.astype(np.float32) / np.float32(scale)).astype(np.float32)


def encode_depth_uint16(depth, scale: float = DEPTH_PNG_SCALE) -> np.ndarray:
    """Quantise ``depth: (H, W)`` metres to the stored uint16 values.

    NaN, +-inf and values <= 0 are invalid and become 0. Valid values are rounded to the
    nearest 1/scale m and clipped to [1, 65535] (so a tiny positive depth stays valid and
    depths beyond 65535/scale m, 255.996 m at scale 256, saturate).
    """
    depth = check_array("depth", depth, (None, None))
    if not scale > 0:
        raise InputError(f"depth scale must be positive, got {scale}")
    if depth.dtype == np.float32 and math.frexp(float(scale))[0] == 0.5:
        # a power-of-two scale multiplies float32 exactly: the same values as in float64, in
        # a third of the time (the pipeline's maps are float32, the scale 256)
        with np.errstate(invalid="ignore", over="ignore"):
            valid = np.isfinite(depth) & (depth > 0)
            q = np.clip(np.rint(depth * np.float32(scale)), 1, 65535)
        return np.where(valid, q, 0).astype(np.uint16)
    d = depth.astype(np.float64)
    valid = np.isfinite(d) & (d > 0)
    q = np.zeros(d.shape, dtype=np.uint16)
    q[valid] = np.clip(np.rint(d[valid] * scale), 1, 65535).astype(np.uint16)
    return q


def write_depth_png(path, depth, scale: float = DEPTH_PNG_SCALE, *, fast: bool = False) -> None:
    """Write ``depth: (H, W)`` metres as a 16-bit PNG (see :func:`encode_depth_uint16`).

    NaN or <= 0 means invalid and is written as 0; valid depths are clipped to the uint16
    range, i.e. [1/scale, 65535/scale] metres. Parent folders must exist. The file is
    written under a temporary name and renamed into place, so it is never half-written.
    ``fast``: encode with :data:`FAST_PNG_PARAMS` (what a run writes) instead of
    :data:`SMALL_PNG_PARAMS`; the stored values are the same.

    Raises:
        ShapeError: ``depth`` is not a 2-D float (or integer) array.
        InputError: the file cannot be written.
    """
    path = Path(path)
    if path.suffix.lower() != ".png":
        raise InputError(f"{path}: depth maps are written as .png files")
    q = encode_depth_uint16(depth, scale)
    ok, buf = cv2.imencode(".png", q, list(FAST_PNG_PARAMS if fast else SMALL_PNG_PARAMS))
    if not ok:  # pragma: no cover - cv2 failure
        raise InputError(f"{path}: cannot encode depth PNG")
    try:
        write_bytes_atomic(path, buf.tobytes())
    except OSError as exc:
        raise InputError(f"{path}: cannot write depth PNG ({exc.strerror})") from None


def write_bytes_atomic(path, data: bytes) -> None:
    """Write ``data`` to ``path`` via a temporary file in the same folder and a rename."""
    write_chunks_atomic(path, (data,))


def write_chunks_atomic(path, chunks: Iterable[bytes]) -> None:
    """Write ``chunks`` one after the other to ``path`` via a temporary file in the same
    folder and a rename (a long run's frames.jsonl is never in memory as a whole)."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".partial")
    try:
        with os.fdopen(fd, "wb") as fh:
            for chunk in chunks:
                fh.write(chunk)
        # mkstemp creates 0600 files; give the result the permissions open() would have
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
