"""LiDAR model of one landmark for the batched EKF-SLAM, compiled with numba.

Seed 001 §2.3.3–2.3.4 with the azimuth of DESIGN.md §3: for landmark l seen from
``(ρ, Λ)``, ``c = C_NBᵀ (l - ρ)`` and ``y = (α, β, δ) = (atan2(c2, c1), atan2(c3, ‖c_12‖),
‖c‖)``; the inverse is ``l = ρ + C_NB ϱ(y)``, ``ϱ = δ (cβ cα, cβ sα, sβ)`` (eq. 44–45).
These are the same equations as :mod:`quadslam_env.models.lidar` (NumPy, broadcasting),
written per landmark so the filter kernels can call them inside their loops over lanes.
"""

from __future__ import annotations

import math

import numpy as np

from quadslam_env.models.frames import dcm_from_trig
from quadslam_env.models.jit import kernel
from quadslam_env.types import POSE_DIM, FloatArray


@kernel
def dcm_and_partials(phi: float, theta: float, psi: float, C: FloatArray, dC: FloatArray) -> None:
    """``C = C_NB(Λ)`` (seed 001 eq. 1) into C (3, 3) and ``dC[i] = ∂C_NB/∂Λ_i`` (3, 3, 3)."""
    cf, sf = math.cos(phi), math.sin(phi)
    ct, st = math.cos(theta), math.sin(theta)
    cp, sp = math.cos(psi), math.sin(psi)
    c = dcm_from_trig(cf, sf, ct, st, cp, sp)
    for k in range(9):
        C[k // 3, k % 3] = c[k]
    for a in range(3):
        # ∂C/∂φ = C C1(φ)ᵀ ∂C1/∂φ: column 0 vanishes, columns 1, 2 rotate into each other.
        dC[0, a, 0], dC[0, a, 1], dC[0, a, 2] = 0.0, C[a, 2], -C[a, 1]
        # ∂C/∂ψ = ∂C3/∂ψ C3ᵀ C: rows 0, 1 rotate into each other, row 2 vanishes.
        dC[2, 0, a], dC[2, 1, a], dC[2, 2, a] = -C[1, a], C[0, a], 0.0
    dC[1, 0, 0], dC[1, 0, 1], dC[1, 0, 2] = -st * cp, sf * ct * cp, cf * ct * cp
    dC[1, 1, 0], dC[1, 1, 1], dC[1, 1, 2] = -st * sp, sf * ct * sp, cf * ct * sp
    dC[1, 2, 0], dC[1, 2, 1], dC[1, 2, 2] = -ct, -sf * st, -cf * st


@kernel
def lidar_model(
    pos: FloatArray, C: FloatArray, dC: FloatArray, lm: FloatArray, h: FloatArray, H: FloatArray
) -> None:
    """Predicted measurement of one landmark and its Jacobian (seed 001 eq. 30–31, 40).

    ``c = C_NBᵀ (l - ρ)``, ``h = (atan2(c2, c1), atan2(c3, ‖c_12‖), ‖c‖)``.

    Args:
        pos: (3,) ρ̂ in N, m.
        C: (3, 3) ``C_NB(Λ̂)``.
        dC: (3, 3, 3) ``∂C_NB/∂Λ_i``.
        lm: (3,) landmark position in N, m.
        h: (3,) receives (α rad, β rad, δ m).
        H: (3, 9) receives ``[∂h/∂ρ, ∂h/∂Λ, ∂h/∂l]`` (∂h/∂v is zero).
    """
    d0, d1, d2 = lm[0] - pos[0], lm[1] - pos[1], lm[2] - pos[2]
    c1 = C[0, 0] * d0 + C[1, 0] * d1 + C[2, 0] * d2
    c2 = C[0, 1] * d0 + C[1, 1] * d1 + C[2, 1] * d2
    c3 = C[0, 2] * d0 + C[1, 2] * d1 + C[2, 2] * d2
    horiz = math.hypot(c1, c2)
    h[0] = math.atan2(c2, c1)
    h[1] = math.atan2(c3, horiz)
    h[2] = math.sqrt(horiz * horiz + c3 * c3)
    # Floor: the azimuth is undefined straight above/below (c1 = c2 = 0).
    hh2 = max(c1 * c1 + c2 * c2, 1e-12)
    hh = math.sqrt(hh2)
    dd2 = hh2 + c3 * c3
    dd = math.sqrt(dd2)
    # Rows of ∂h/∂c, then the chain rule through ∂c/∂l = C_NBᵀ, ∂c/∂ρ = -C_NBᵀ and
    # ∂c/∂Λ_a = (∂C/∂Λ_a)ᵀ (l - ρ).
    _chain_row(H, 0, -c2 / hh2, c1 / hh2, 0.0, C, dC, d0, d1, d2)
    _chain_row(H, 1, -c1 * c3 / (dd2 * hh), -c2 * c3 / (dd2 * hh), hh / dd2, C, dC, d0, d1, d2)
    _chain_row(H, 2, c1 / dd, c2 / dd, c3 / dd, C, dC, d0, d1, d2)


@kernel
def _chain_row(
    H: FloatArray,
    r: int,
    j0: float,
    j1: float,
    j2: float,
    C: FloatArray,
    dC: FloatArray,
    d0: float,
    d1: float,
    d2: float,
) -> None:
    """Row r of ``[∂h/∂ρ, ∂h/∂Λ, ∂h/∂l]`` from the row ``(j0, j1, j2)`` of ``∂h_r/∂c``."""
    for a in range(3):
        hl = j0 * C[a, 0] + j1 * C[a, 1] + j2 * C[a, 2]
        H[r, 6 + a] = hl
        H[r, a] = -hl
        e0 = dC[a, 0, 0] * d0 + dC[a, 1, 0] * d1 + dC[a, 2, 0] * d2
        e1 = dC[a, 0, 1] * d0 + dC[a, 1, 1] * d1 + dC[a, 2, 1] * d2
        e2 = dC[a, 0, 2] * d0 + dC[a, 1, 2] * d1 + dC[a, 2, 2] * d2
        H[r, 3 + a] = j0 * e0 + j1 * e1 + j2 * e2


@kernel
def lidar_inverse_model(
    pos: FloatArray,
    C: FloatArray,
    dC: FloatArray,
    y: FloatArray,
    lm: FloatArray,
    G_eul: FloatArray,
    G_y: FloatArray,
) -> None:
    """Inverse model ``l = ρ + C_NB ϱ(y)`` and its Jacobians (seed 001 eq. 44–45, 49).

    Args:
        pos: (3,) ρ̂ in N, m.
        C: (3, 3) ``C_NB(Λ̂)``.
        dC: (3, 3, 3) ``∂C_NB/∂Λ_i``.
        y: (3,) measurement (α rad, β rad, δ m).
        lm: (3,) receives the landmark position in N, m.
        G_eul: (3, 3) receives ``∂g/∂Λ`` (``∂g/∂ρ = I``, ``∂g/∂v = 0``).
        G_y: (3, 3) receives ``∂g/∂y``.
    """
    alpha, beta, delta = y[0], y[1], y[2]
    ca, sa, cb, sb = math.cos(alpha), math.sin(alpha), math.cos(beta), math.sin(beta)
    rho = (delta * cb * ca, delta * cb * sa, delta * sb)
    drho = (
        (-delta * cb * sa, -delta * sb * ca, cb * ca),
        (delta * cb * ca, -delta * sb * sa, cb * sa),
        (0.0, delta * cb, sb),
    )
    for a in range(3):
        lm[a] = pos[a] + (C[a, 0] * rho[0] + C[a, 1] * rho[1] + C[a, 2] * rho[2])
        for i in range(3):
            G_eul[a, i] = dC[i, a, 0] * rho[0] + dC[i, a, 1] * rho[1] + dC[i, a, 2] * rho[2]
            G_y[a, i] = C[a, 0] * drho[0][i] + C[a, 1] * drho[1][i] + C[a, 2] * drho[2][i]


@kernel
def predicted_measurements(xb: FloatArray, lms: FloatArray, h: FloatArray, H: FloatArray) -> None:
    """``h`` (k, 3) and Jacobian blocks ``H`` (k, 3, 9) = ``[∂h/∂ρ, ∂h/∂Λ, ∂h/∂l]`` of the
    landmarks ``lms`` (k, 3) seen from the pose in ``xb`` (eq. 34, 40)."""
    C = np.empty((3, 3))
    dC = np.empty((3, 3, 3))
    dcm_and_partials(xb[6], xb[7], xb[8], C, dC)
    for i in range(lms.shape[0]):
        lidar_model(xb[0:3], C, dC, lms[i], h[i], H[i])


def stacked_model(
    xb: FloatArray, lms: FloatArray, lm_cols: np.ndarray | None
) -> tuple[np.ndarray, FloatArray, FloatArray]:
    """Stacked observation model of k landmarks as dense arrays (eq. 34 and 40).

    Args:
        xb: (n,) total state of one lane.
        lms: (k, 3) landmark positions in N, m.
        lm_cols: (3k,) their columns in x, or ``None`` for known (non-state) landmarks.

    Returns:
        ``(cols, h, H)``: ``cols`` (d,) the columns ``[s, m_κ]`` of x the model depends on
        (d = 9 + 3k, or 9 for known landmarks), ``h`` (3k,) the predicted (α, β, δ) and
        ``H`` (3k, d) = ``∂h/∂x[cols]``.
    """
    k = lms.shape[0]
    h = np.empty((k, 3))
    blocks = np.empty((k, 3, 9))
    predicted_measurements(xb, np.ascontiguousarray(lms, dtype=float), h, blocks)
    cols = np.arange(POSE_DIM) if lm_cols is None else np.r_[np.arange(POSE_DIM), lm_cols]
    H = np.zeros((k, 3, cols.shape[0]))
    H[:, :, 0:3] = blocks[:, :, 0:3]
    H[:, :, 6:9] = blocks[:, :, 3:6]
    if lm_cols is not None:
        for i in range(k):
            H[i, :, POSE_DIM + 3 * i : POSE_DIM + 3 * i + 3] = blocks[i, :, 6:9]
    return cols, h.ravel(), H.reshape(3 * k, -1)
