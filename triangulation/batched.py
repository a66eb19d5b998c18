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


def _adjugate3(A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(M, 3, 3) adjugates and (M,) determinants of ``A: (M, 3, 3)``, by cofactors (row-wise
    products: some 30 array operations instead of a LAPACK call per matrix)."""
    a, b, c = A[:, 0, 0], A[:, 0, 1], A[:, 0, 2]
    d, e, f = A[:, 1, 0], A[:, 1, 1], A[:, 1, 2]
    g, h, i = A[:, 2, 0], A[:, 2, 1], A[:, 2, 2]
    adj = np.empty(A.shape, np.float64)
    adj[:, 0, 0] = e * i - f * h
    adj[:, 1, 0] = f * g - d * i
    adj[:, 2, 0] = d * h - e * g
    adj[:, 0, 1] = c * h - b * i
    adj[:, 1, 1] = a * i - c * g
    adj[:, 2, 1] = b * g - a * h
    adj[:, 0, 2] = b * f - c * e
    adj[:, 1, 2] = c * d - a * f
    adj[:, 2, 2] = a * e - b * d
    det = a * adj[:, 0, 0] + b * adj[:, 1, 0] + c * adj[:, 2, 0]
    return adj, det


def inv3(A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Batched 3x3 inverse of ``A: (M, 3, 3)``: (M, 3, 3) and (M,) bool; rows with a
    singular or ill-conditioned A (``|det| <= 1e-12 trace^3``) give NaN and False."""
    A = np.asarray(A, np.float64)
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        adj, det = _adjugate3(A)
        scale = np.einsum("nii->n", A) ** 3
        ok = np.isfinite(det) & (np.abs(det) > 1e-12 * np.maximum(np.abs(scale), 1e-300))
        out = adj / np.where(ok, det, np.nan)[:, None, None]
    return out, ok


def solve3(A: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Batched 3x3 solve ``A x = b`` (``A: (M, 3, 3)``, ``b: (M, 3)``), by the adjugate;
    rows with a singular or ill-conditioned A give NaN and False (as :func:`inv3`)."""
    inverse, ok = inv3(A)
    with np.errstate(invalid="ignore", over="ignore"):
        x = np.einsum("nij,nj->ni", inverse, b)
    return x, ok
