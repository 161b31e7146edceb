"""The env's pose state (ρ, v_B, Λ) and GTSAM's tangent space of a keyframe (pose, velocity).

GTSAM keeps a keyframe as a ``Pose3`` (``C_NB``, ρ) and a ``Vector3`` velocity ``v_N`` in the
world frame (here NED, so the IMU factor's gravity is ``(0, 0, +g)``). Its covariances are over
the tangent space ``δx = (δθ, δt, δv_N)`` (9,) with the perturbation

    C_NB ← C_NB Exp(δθ),    ρ ← ρ + C_NB δt,    v_N ← v_N + δv_N

(δθ and δt in the body frame B, δv_N in N; the first-order chart of ``Pose3.retract``). The
env reports ``s = (ρ [m, N], v_B [m/s, B], Λ = (φ, θ, ψ) [rad])`` with the 9×9 covariance over
s, so a covariance Σ over δx maps to ``J Σ Jᵀ`` with the Jacobian ``J = ∂s/∂δx`` at the mean:

    ∂ρ/∂δt = C_NB,    ∂v_B/∂δθ = [v_B]×,    ∂v_B/∂δv_N = C_NBᵀ,    ∂Λ/∂δθ = D(Λ),

all other blocks zero (``v_B = C_NBᵀ v_N``; ``Λ̇ = D(Λ) ω`` of seed 001 eq. 3 with ``δθ = ω dt``).
J is invertible except at ``cos θ = 0`` (where the Euler angles are).
"""

from __future__ import annotations

import numpy as np

from quadslam_env.models.frames import euler_rate_matrix_kernel, skew_from_components
from quadslam_env.models.jit import kernel
from quadslam_env.types import POSE_DIM, FloatArray


@kernel
def _state_jacobian(dcm: FloatArray, vel_body: FloatArray, phi: float, theta: float) -> FloatArray:
    """The (9, 9) ``J`` of :func:`state_jacobian` (kernel: the per-step snapshot calls it)."""
    J = np.zeros((POSE_DIM, POSE_DIM))
    vx = skew_from_components(vel_body[0], vel_body[1], vel_body[2])
    D = euler_rate_matrix_kernel(phi, theta)
    for i in range(3):
        for j in range(3):
            J[i, 3 + j] = dcm[i, j]  # ∂ρ/∂δt = C_NB
            J[3 + i, j] = vx[i, j]  # ∂v_B/∂δθ = [v_B]×
            J[3 + i, 6 + j] = dcm[j, i]  # ∂v_B/∂δv_N = C_NBᵀ
            J[6 + i, j] = D[i, j]  # ∂Λ/∂δθ = D(Λ)
    return J


@kernel
def _state_covariance(
    cov_tangent: FloatArray, dcm: FloatArray, vel_body: FloatArray, phi: float, theta: float
) -> FloatArray:
    """``J Σ Jᵀ`` of :func:`state_covariance`, symmetrised (kernel: called every step)."""
    J = _state_jacobian(dcm, vel_body, phi, theta)
    P = J @ cov_tangent @ J.T
    return 0.5 * (P + P.T)


def state_jacobian(dcm: FloatArray, vel_body: FloatArray, euler: FloatArray) -> FloatArray:
    """``J = ∂(ρ, v_B, Λ)/∂(δθ, δt, δv_N)`` (9, 9) at a pose (module docstring).

    Args:
        dcm: (3, 3) ``C_NB``.
        vel_body: (3,) ``v_B`` in m/s.
        euler: (3,) Λ = (φ, θ, ψ) in rad (Z-Y-X, ``C_NB = C3(ψ) C2(θ) C1(φ)``).

    Returns:
        (9, 9) Jacobian; rows (ρ m, v_B m/s, Λ rad), columns (δθ rad, δt m, δv_N m/s).
    """
    return _state_jacobian(
        np.ascontiguousarray(dcm, dtype=float),
        np.ascontiguousarray(vel_body, dtype=float),
        float(euler[0]),
        float(euler[1]),
    )


def state_covariance(
    cov_tangent: FloatArray, dcm: FloatArray, vel_body: FloatArray, euler: FloatArray
) -> FloatArray:
    """Covariance (9, 9) over (ρ, v_B, Λ) from GTSAM's over (δθ, δt, δv_N): ``J Σ Jᵀ``.

    Args:
        cov_tangent: (9, 9) covariance over (δθ rad, δt m, δv_N m/s).
        dcm: (3, 3) ``C_NB``.
        vel_body: (3,) ``v_B`` in m/s.
        euler: (3,) Λ in rad.

    Returns:
        (9, 9) covariance over (ρ m, v_B m/s, Λ rad), exactly symmetric.
    """
    return _state_covariance(
        np.ascontiguousarray(cov_tangent, dtype=float),
        np.ascontiguousarray(dcm, dtype=float),
        np.ascontiguousarray(vel_body, dtype=float),
        float(euler[0]),
        float(euler[1]),
    )


def tangent_covariance(
    cov_state: FloatArray,
    dcm: FloatArray,
    vel_body: FloatArray,
    euler: FloatArray,
    floor: float = 0.0,
) -> FloatArray:
    """Covariance (9, 9) over (δθ, δt, δv_N) from one over (ρ, v_B, Λ): ``J⁻¹ P J⁻ᵀ``.

    Args:
        cov_state: (9, 9) covariance over (ρ m, v_B m/s, Λ rad).
        dcm: (3, 3) ``C_NB``.
        vel_body: (3,) ``v_B`` in m/s.
        euler: (3,) Λ in rad (``cos θ ≠ 0``).
        floor: Smallest eigenvalue of the result (a zero variance cannot be a factor).

    Returns:
        (9, 9) symmetric covariance over (δθ rad, δt m, δv_N m/s) with eigenvalues ≥ floor.

    Raises:
        numpy.linalg.LinAlgError: At ``cos θ = 0``.
    """
    Jinv = np.linalg.inv(state_jacobian(dcm, vel_body, euler))
    S = Jinv @ cov_state @ Jinv.T
    S = 0.5 * (S + S.T)
    if floor > 0.0:
        w, V = np.linalg.eigh(S)
        S = (V * np.maximum(w, floor)) @ V.T
        S = 0.5 * (S + S.T)
    return S
