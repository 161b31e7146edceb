"""Stacked small-matrix helpers shared by the filters (docs/design.md §9).

The NumPy functions work on arrays with leading batch axes (particles, lanes, landmarks): for
3×3 blocks closed forms beat per-matrix LAPACK calls by far. ``cholesky_lower`` is a numba
kernel for one matrix, called from the filters' lane and particle kernels.
"""

from __future__ import annotations

import math

import numpy as np

from quadslam_env.models.jit import kernel
from quadslam_env.types import FloatArray

LOG_2PI = math.log(2.0 * math.pi)
"""``log 2π``, the constant of Gaussian log-densities."""


@kernel
def cholesky_lower(A: FloatArray) -> bool:
    """In-place Cholesky factor ``A = L Lᵀ`` of an (m, m) matrix (numba kernel).

    Reads the lower triangle and overwrites it with L (as LAPACK ``potrf('L')``); the strict
    upper triangle is left as it was. The one Cholesky of the filters (EKF-SLAM update, FastSLAM
    bias KF) and of the NEES metric.

    Returns:
        False if A is not positive definite (a pivot is not > 0, or NaN).
    """
    m = A.shape[0]
    for j in range(m):
        d = A[j, j]
        for c in range(j):
            d -= A[j, c] * A[j, c]
        if not d > 0.0:
            return False
        ljj = math.sqrt(d)
        A[j, j] = ljj
        for i in range(j + 1, m):
            acc = A[i, j]
            for c in range(j):
                acc -= A[i, c] * A[j, c]
            A[i, j] = acc / ljj
    return True


@kernel
def inv3_sym_one(S: tuple) -> tuple:
    """Inverse and determinant of one symmetric 3×3 ``S`` (rows as tuples; the upper triangle
    is read) by cofactors: ``((row0, row1, row2), det)``."""
    a, b, c = S[0][0], S[0][1], S[0][2]
    d, e, f = S[1][1], S[1][2], S[2][2]
    c00 = d * f - e * e
    c01 = c * e - b * f
    c02 = b * e - c * d
    det = a * c00 + b * c01 + c * c02
    c11, c12, c22 = a * f - c * c, b * c - a * e, a * d - b * b
    i01, i02, i12 = c01 / det, c02 / det, c12 / det
    return ((c00 / det, i01, i02), (i01, c11 / det, i12), (i02, i12, c22 / det)), det


@kernel
def _inv3_sym_lanes(S: FloatArray, inv: FloatArray, det: FloatArray) -> None:
    for n in range(S.shape[0]):
        m = S[n]
        rows, det[n] = inv3_sym_one(
            ((m[0, 0], m[0, 1], m[0, 2]), (m[1, 0], m[1, 1], m[1, 2]), (m[2, 0], m[2, 1], m[2, 2]))
        )
        for r in range(3):
            for c in range(3):
                inv[n, r, c] = rows[r][c]


def inv3_sym(S: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Inverse and determinant of symmetric 3×3 matrices by cofactors (:func:`inv3_sym_one`).

    Args:
        S: (..., 3, 3) symmetric matrices.

    Returns:
        ``(inverse (..., 3, 3), determinant (...))``.
    """
    S = np.asarray(S, dtype=float)
    flat = np.ascontiguousarray(S.reshape(-1, 3, 3))
    inv = np.empty(flat.shape)
    det = np.empty(flat.shape[0])
    _inv3_sym_lanes(flat, inv, det)
    return inv.reshape(S.shape), det.reshape(S.shape[:-2])


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


def mv(a: FloatArray, v: FloatArray) -> FloatArray:
    """Stacked matrix–vector product ``a @ v`` for (..., n, n) and (..., n) → (..., n)."""
    return (a @ v[..., None])[..., 0]


def psd_sqrt(cov: FloatArray) -> FloatArray:
    """A square root ``S`` with ``S Sᵀ = cov`` of symmetric PSD (possibly singular) (..., n, n)."""
    vals, vecs = np.linalg.eigh(0.5 * (cov + np.swapaxes(cov, -1, -2)))
    return vecs * np.sqrt(np.clip(vals, 0.0, None))[..., None, :]
