"""The one shared helper that checks array arguments at function entry.

Every public array-taking function documents shapes and units in its docstring and
calls :func:`check_array` (or :func:`check_transform`) on its inputs, so that a wrong
shape fails early with a message naming the argument instead of deep inside numpy.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from .errors import ShapeError

Dim = int | None


def check_array(
    name: str,
    value,
    shape: Sequence[Dim],
    *,
    dtype: str | type | None = "float",
    finite: bool = False,
) -> np.ndarray:
    """Return ``value`` as an ndarray after checking its shape (and dtype kind).

    Args:
        name: argument name used in the error message.
        value: array-like.
        shape: expected shape; ``None`` entries match any size, e.g. ``(None, 3)``.
        dtype: ``"float"`` (any floating type; ints are converted to float64),
            ``"int"``, ``"bool"``, a numpy dtype to convert to, or ``None`` (keep).
        finite: when true, reject NaN/inf values.

    Raises:
        ShapeError: wrong number of dimensions, size, dtype kind or non-finite values.
    """
    arr = np.asarray(value)
    if arr.ndim != len(shape) or any(
        want is not None and got != want for got, want in zip(arr.shape, shape)
    ):
        want = "(" + ", ".join("N" if s is None else str(s) for s in shape) + ")"
        raise ShapeError(f"{name}: expected shape {want}, got {arr.shape}")
    if dtype == "float":
        if arr.dtype.kind in "iub":
            arr = arr.astype(np.float64)
        elif arr.dtype.kind != "f":
            raise ShapeError(f"{name}: expected a float array, got dtype {arr.dtype}")
    elif dtype == "int":
        if arr.dtype.kind not in "iu":
            raise ShapeError(f"{name}: expected an integer array, got dtype {arr.dtype}")
    elif dtype == "bool":
        if arr.dtype != np.bool_:
            raise ShapeError(f"{name}: expected a boolean array, got dtype {arr.dtype}")
    elif dtype is not None:
        arr = arr.astype(dtype, copy=False)
    if finite and arr.dtype.kind == "f" and not np.all(np.isfinite(arr)):
        raise ShapeError(f"{name}: contains NaN or infinite values")
    return arr


def check_transform(name: str, T) -> np.ndarray:
    """Check a (4, 4) rigid transform: finite, last row [0, 0, 0, 1], orthonormal rotation."""
    T = check_array(name, T, (4, 4), finite=True)
    if not np.allclose(T[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9):
        raise ShapeError(f"{name}: last row must be [0, 0, 0, 1], got {T[3].tolist()}")
    R = T[:3, :3]
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-5) or np.linalg.det(R) < 0:
        raise ShapeError(f"{name}: rotation block is not a proper rotation matrix")
    return T


def check_image(name: str, image, *, channels: int | None = None) -> np.ndarray:
    """Check an image array: (H, W) when ``channels`` is None or 1, else (H, W, channels)."""
    arr = np.asarray(image)
    if channels in (None, 1):
        if arr.ndim != 2:
            raise ShapeError(f"{name}: expected an (H, W) image, got shape {arr.shape}")
    elif arr.ndim != 3 or arr.shape[2] != channels:
        raise ShapeError(f"{name}: expected an (H, W, {channels}) image, got shape {arr.shape}")
    return arr
