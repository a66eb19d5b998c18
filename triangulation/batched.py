"""Batched small linear algebra of the multi-view triangulation (:mod:`.multiview`): sums
grouped by index, 2x2 quadratic forms and inverses, 3x3 solves -- vectorised over (M, ...)
stacks, each row computed on its own (the same whichever other rows come along)."""

from __future__ import annotations

import numpy as np


def sum_by(index: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    """Sums of ``values: (M, ...)`` grouped by ``index: (M,)`` into (n, ...), float64."""
    k = int(np.prod(values.shape[1:], dtype=np.int64))
    # one bincount over (group, component) bins: each bin still sums its values in row
    # order, as one bincount per component did
    bins = (np.asarray(index, np.int64)[:, None] * k + np.arange(k)).ravel()
    out = np.bincount(bins, weights=values.reshape(-1), minlength=n * k)
    out = out.astype(np.float64, copy=False)  # bincount of nothing: int zeros
    return out.reshape((n,) + values.shape[1:])


def quad2(r: np.ndarray, S: np.ndarray) -> np.ndarray:
    """(M,) quadratic forms ``r_i^T S_i r_i`` of ``r: (M, 2)``, ``S: (M, 2, 2)``."""
    r0, r1 = r[:, 0], r[:, 1]
    return r0 * (S[:, 0, 0] * r0 + S[:, 0, 1] * r1) + r1 * (S[:, 1, 0] * r0 + S[:, 1, 1] * r1)


def inv2(S: np.ndarray) -> np.ndarray:
    """Batched closed-form inverse of (M, 2, 2) symmetric positive-definite matrices."""
    a, b, d = S[:, 0, 0], S[:, 0, 1], S[:, 1, 1]
    det = a * d - b * b
    out = np.empty_like(S)
    out[:, 0, 0] = d / det
    out[:, 1, 1] = a / det
    out[:, 0, 1] = out[:, 1, 0] = -b / det
    return out


def finite(a: np.ndarray, **kwargs) -> np.ndarray:
    """``np.nan_to_num(a, **kwargs)``, without its cost when ``a`` is already finite (the usual case)."""
    return a if np.isfinite(a).all() else np.nan_to_num(a, **kwargs)


def solve3(A: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Batched 3x3 solve; rows with a singular/ill-conditioned A give NaN and False."""
    with np.errstate(invalid="ignore", over="ignore"):
        A0 = finite(A)
        det = np.linalg.det(A0)
    scale = np.einsum("nii->n", A0) ** 3
    ok = np.isfinite(det) & (np.abs(det) > 1e-12 * np.maximum(np.abs(scale), 1e-300))
    if ok.all():  # the usual case: no masked copies (each matrix is solved on its own either way)
        return np.linalg.solve(A, b[..., None])[..., 0], ok
    x = np.full(b.shape, np.nan)
    if ok.any():
        x[ok] = np.linalg.solve(A[ok], b[ok][..., None])[..., 0]
    return x, ok
