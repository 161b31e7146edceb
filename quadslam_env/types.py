"""Shared array type, physical constants, dimensions and index slices (docs/design.md §2, §9).

Every module that needs one of these imports it from here, so a dimension or a constant is
written once.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
"""A float64 NumPy array; shapes are given in the docstrings that use it."""

GRAVITY = 9.81
"""Gravitational acceleration g in m/s² (docs/design.md §2); gravity is ``+g n3`` in NED."""

DEG = math.pi / 180.0
"""One degree in rad: configs and reports use degrees, the code radians (docs/design.md §2)."""

STATE_DIM = 12
"""Vehicle state ``x = (ρ [m, N], v [m/s, B], Λ [rad], ω [rad/s, B])`` (seed 001 eq. 2)."""

POSE_DIM = 9
"""Pose part ``s = (ρ, v, Λ)`` of the state (the EKF-SLAM vehicle state, seed 001 §2.3)."""

POS, VEL, EUL, RATE = slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 12)
"""Slices of ρ, v, Λ and ω in the 12-state, and of ρ, v, Λ in everything laid out like its
leading :data:`POSE_DIM` entries (pose means, pose covariances, pose process noise). Numba
kernels may use them too (a global slice is a compile-time constant there)."""

MEAS_DIM = 3
"""LiDAR measurement ``y = (α [rad], β [rad], δ [m])`` per landmark (seed 001 §2.3.3)."""

IMU_DIM = 6
"""IMU sample ``(a_m [m/s²], ω_m [rad/s])`` in B (seed 000 eq. 5–7)."""

TEXT_INFO_KEYS = ("termination_reason", "fault_kind")
"""``info`` terms that hold text, one string per lane (``""`` where they do not apply) instead
of a float: the envs pass them through as strings (the vector env as object arrays with a
``_key`` mask of the non-empty ones)."""
