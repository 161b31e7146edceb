"""Reference math of the model tests, written out from seed 001 eq. 1 and docs/design.md §2–3
independently of the package code: the elementary rotations, the DCM, skew, angle wrap, central
finite differences and random attitudes (tests/sim/test_models.py, test_lidar_model.py)."""

from __future__ import annotations

import math

import numpy as np


def c1(phi: float) -> np.ndarray:
    c, s = math.cos(phi), math.sin(phi)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def c2(theta: float) -> np.ndarray:
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def c3(psi: float) -> np.ndarray:
    c, s = math.cos(psi), math.sin(psi)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def ref_dcm(euler) -> np.ndarray:
    """C_NB = C3(ψ) C2(θ) C1(φ)."""
    return c3(euler[2]) @ c2(euler[1]) @ c1(euler[0])


def ref_skew(w) -> np.ndarray:
    """Matrix with ``ref_skew(w) @ x == np.cross(w, x)``, built column by column."""
    return np.column_stack([np.cross(w, e) for e in np.eye(3)])


def ref_wrap(a):
    """Wrap to (-π, π]: π − ((π − a) mod 2π) (independent of the package)."""
    return math.pi - np.mod(math.pi - np.asarray(a, dtype=float), 2 * math.pi)


def central_fd(fun, x0, h: float = 1e-6) -> np.ndarray:
    """Central differences of ``fun`` (returning (..., 3) measurements) w.r.t. the 3-vector
    ``x0``; angle channels of the difference are wrapped. Returns (..., 3, 3)."""
    cols = []
    for i in range(3):
        d = np.zeros(3)
        d[i] = h
        diff = fun(x0 + d) - fun(x0 - d)
        diff[..., :2] = ref_wrap(diff[..., :2])
        cols.append(diff / (2 * h))
    return np.stack(cols, axis=-1)


def random_euler(rng: np.random.Generator, n: int, max_pitch: float = 1.3) -> np.ndarray:
    out = rng.uniform(-math.pi, math.pi, size=(n, 3))
    out[:, 1] = rng.uniform(-max_pitch, max_pitch, size=n)
    return out
