"""Stacked small-matrix helpers shared by the filters (DESIGN.md §9).

All functions work on arrays with leading batch axes (particles, lanes, landmarks) and are
NumPy-vectorised: for 3×3 blocks closed forms beat per-matrix LAPACK calls by far.
"""

from __future__ import annotations

import math

import numpy as np

from quadslam_env.types import FloatArray

LOG_2PI = math.log(2.0 * math.pi)
"""``log 2π``, the constant of Gaussian log-densities."""


def inv3_sym(S: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Inverse and determinant of symmetric 3×3 matrices by cofactors.

    Args:
        S: (..., 3, 3) symmetric matrices.

    Returns:
        ``(inverse (..., 3, 3), determinant (...))``.
    """
    a, b, c = S[..., 0, 0], S[..., 0, 1], S[..., 0, 2]
    d, e, f = S[..., 1, 1], S[..., 1, 2], S[..., 2, 2]
    c00 = d * f - e * e
    c01 = c * e - b * f
    c02 = b * e - c * d
    det = a * c00 + b * c01 + c * c02
    inv = np.empty(S.shape)
    inv[..., 0, 0] = c00
    inv[..., 0, 1] = inv[..., 1, 0] = c01
    inv[..., 0, 2] = inv[..., 2, 0] = c02
    inv[..., 1, 1] = a * f - c * c
    inv[..., 1, 2] = inv[..., 2, 1] = b * c - a * e
    inv[..., 2, 2] = a * d - b * b
    inv /= det[..., None, None]
    return inv, det


def chol3(a: FloatArray) -> FloatArray:
    """Lower Cholesky factors of symmetric PSD 3×3 matrices (..., 3, 3), clipped at zero pivots."""
    out = np.zeros(a.shape)
    l00 = np.sqrt(np.maximum(a[..., 0, 0], 0.0))
    inv00 = np.divide(1.0, l00, out=np.zeros_like(l00), where=l00 > 0.0)
    l10 = a[..., 1, 0] * inv00
    l20 = a[..., 2, 0] * inv00
    l11 = np.sqrt(np.maximum(a[..., 1, 1] - l10 * l10, 0.0))
    inv11 = np.divide(1.0, l11, out=np.zeros_like(l11), where=l11 > 0.0)
    l21 = (a[..., 2, 1] - l20 * l10) * inv11
    l22 = np.sqrt(np.maximum(a[..., 2, 2] - l20 * l20 - l21 * l21, 0.0))
    out[..., 0, 0], out[..., 1, 0], out[..., 2, 0] = l00, l10, l20
    out[..., 1, 1], out[..., 2, 1], out[..., 2, 2] = l11, l21, l22
    return out


def swap(a: FloatArray) -> FloatArray:
    """Transpose of the last two axes (a view)."""
    return np.swapaxes(a, -1, -2)


def swap_copy(a: FloatArray) -> FloatArray:
    """Contiguous transpose of the last two axes (stacked matmul is much faster on it)."""
    return np.ascontiguousarray(np.swapaxes(a, -1, -2))


def mv(a: FloatArray, v: FloatArray) -> FloatArray:
    """Stacked matrix–vector product ``a @ v`` for (..., n, n) and (..., n) → (..., n)."""
    return (a @ v[..., None])[..., 0]


def psd_sqrt(cov: FloatArray) -> FloatArray:
    """A square root ``S`` with ``S Sᵀ = cov`` of a symmetric PSD (possibly singular) (n, n)."""
    vals, vecs = np.linalg.eigh(0.5 * (cov + cov.T))
    return vecs * np.sqrt(np.clip(vals, 0.0, None))
