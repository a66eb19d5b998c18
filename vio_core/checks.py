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
    got_shape = arr.shape
    # a plain loop, not a generator: this runs tens of thousands of times per sequence
    bad = len(got_shape) != len(shape)
    if not bad:
        for got, want in zip(got_shape, shape):
            if want is not None and got != want:
                bad = True
                break
    if bad:
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
    if finite and arr.dtype.kind == "f" and not np.isfinite(arr).all():
        raise ShapeError(f"{name}: contains NaN or infinite values")
    return arr


def check_transform(name: str, T) -> np.ndarray:
    """Check a (4, 4) rigid transform: finite, last row [0, 0, 0, 1], orthonormal rotation.

    The tolerances are those of ``np.allclose`` (``rtol`` 1e-5): the last row within 1e-9
    (+ 1e-5 for the 1), ``R @ R.T`` within 1e-5 of the identity (+ 1e-5 on the diagonal),
    ``det(R) >= 0``. Evaluated on Python floats: this runs thousands of times per
    sequence and ``np.allclose``'s overhead dominated it.
    """
    T = check_array(name, T, (4, 4), finite=True)
    # |x - y| <= atol + rtol * |y| as np.isclose evaluates it (T is finite: no NaN cases)
    x0, x1, x2, x3 = T[3].tolist()
    if not (abs(x0) <= _ROW_ATOL and abs(x1) <= _ROW_ATOL and abs(x2) <= _ROW_ATOL
            and abs(x3 - 1.0) <= _ROW_ATOL + _RTOL):
        raise ShapeError(f"{name}: last row must be [0, 0, 0, 1], got {T[3].tolist()}")
    R = T[:3, :3]
    (a, b, c), (d, e, f), (g, h, i) = (R @ R.T).tolist()  # in T's dtype, as before
    # (R @ R.T may overflow to inf or NaN: every comparison below is then False)
    orthonormal = (abs(a - 1.0) <= _ROT_ATOL + _RTOL and abs(e - 1.0) <= _ROT_ATOL + _RTOL
                   and abs(i - 1.0) <= _ROT_ATOL + _RTOL and abs(b) <= _ROT_ATOL and abs(c) <= _ROT_ATOL
                   and abs(d) <= _ROT_ATOL and abs(f) <= _ROT_ATOL and abs(g) <= _ROT_ATOL
                   and abs(h) <= _ROT_ATOL)
    if not orthonormal or _det3(R.tolist()) < 0:
        raise ShapeError(f"{name}: rotation block is not a proper rotation matrix")
    return T


#: np.allclose's tolerances of check_transform: atol of the last row, of R @ R.T; rtol
_ROW_ATOL, _ROT_ATOL, _RTOL = 1e-9, 1e-5, 1e-5


def _det3(m: list) -> float:
    """Determinant of a 3x3 matrix given as nested lists (cofactor expansion). Only its sign
    is read, on a matrix already within 1e-5 of orthonormal (determinant close to +-1)."""
    (a, b, c), (d, e, f), (g, h, i) = m
    return a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)


def check_image(name: str, image, *, channels: int | None = None) -> np.ndarray:
    """Check an image array: (H, W) when ``channels`` is None or 1, else (H, W, channels)."""
    arr = np.asarray(image)
    if channels in (None, 1):
        if arr.ndim != 2:
            raise ShapeError(f"{name}: expected an (H, W) image, got shape {arr.shape}")
    elif arr.ndim != 3 or arr.shape[2] != channels:
        raise ShapeError(f"{name}: expected an (H, W, {channels}) image, got shape {arr.shape}")
    return arr
