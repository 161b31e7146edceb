"""The keyframe-to-now transition of the smoother's navigation state through the IMU factor.

Between keyframes the estimator needs the state predicted with the current preintegration and
how its error depends on the keyframe's: for the estimate's covariance every control step, and
for data association, where the predicted pose's cross-covariance with the landmarks enters the
innovation covariance of each (return, landmark) pair.

GTSAM's ``CombinedImuFactor`` (Forster et al. 2017, "On-Manifold Preintegration for Real-Time
Visual-Inertial Odometry", IEEE T-RO 33(1), eq. 44–45, with the bias random walk) has a
15-dim error ``e ~ N(0, Σ)``: the NavState at j against the prediction from i, and
``b_j − b_i``, with Σ (15 × 15) its noise model's covariance (the preintegration's, with the
nav–bias cross terms in the factor's convention, not the signs ``preintMeasCov`` has in GTSAM
4.3). At the prediction (``e = 0``) the NavState error is, to first order,
``δn_j − H_1 δn_i − H_2 δb_i`` with ``H_1 = ∂predict/∂n_i`` (9 × 9)
and ``H_2 = ∂predict/∂b_i`` (9 × 6), which GTSAM's ``predict`` returns, over the NavState
tangent ``δn = (δθ, δt, δv_B)`` (all in the body frame). Solved for the keyframe tangent
``δ = (δθ, δt, δv_N, δb_a, δb_ω)`` of the graph's variables (Pose3 in B, velocity in N:
``δv_B = C_NBᵀ δv_N``, so ``δn = T δ`` with ``T = diag(I, I, C_NBᵀ)``)::

    δ_j = F δ_i + w,   F = [[T_j⁻¹ H_1 T_i, T_j⁻¹ H_2], [0, I]],   Q = Cov(w) = S Σ Sᵀ,

``S = diag(T_j⁻¹, I)``, so ``Σ_j = F Σ_i Fᵀ + Q`` and ``Cov(δ_j, δ_l) = F Cov(δ_i, δ_l)`` for
any other variable l (a landmark), which the IMU factor does not involve. This is the factor's
own linearisation (a test checks it against GTSAM's ``linearize``) without linearising the
factor at every control step.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from quadslam_env.models.jit import kernel
from quadslam_env.types import FloatArray

NAV_DIM = 15
"""Keyframe tangent (δθ, δt, δv_N, δb_a, δb_ω): Pose3 (6) + velocity (3) + biases (6)."""


@kernel
def _transition(
    H1: FloatArray, H2: FloatArray, cov: FloatArray, R_i: FloatArray, R_j: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """``(F, Q)`` (15, 15) of the module docstring from ``predict``'s Jacobians ``H1`` (9, 9),
    ``H2`` (9, 6), the factor's noise covariance ``cov`` (15, 15) and ``C_NB`` at i and j."""
    F = np.zeros((NAV_DIM, NAV_DIM))
    S = np.zeros((NAV_DIM, NAV_DIM))
    for r in range(9):
        for c in range(6):
            F[r, c] = H1[r, c]
            F[r, 9 + c] = H2[r, c]
        for c in range(3):  # H_1 T_i: the velocity columns turned into N
            F[r, 6 + c] = H1[r, 6] * R_i[c, 0] + H1[r, 7] * R_i[c, 1] + H1[r, 8] * R_i[c, 2]
    for c in range(NAV_DIM):  # T_j⁻¹: the velocity rows turned into N
        a, b, d = F[6, c], F[7, c], F[8, c]
        for r in range(3):
            F[6 + r, c] = R_j[r, 0] * a + R_j[r, 1] * b + R_j[r, 2] * d
    for r in range(6):
        F[9 + r, 9 + r] = 1.0
        S[r, r] = 1.0
        S[9 + r, 9 + r] = 1.0
    for r in range(3):
        for c in range(3):
            S[6 + r, 6 + c] = R_j[r, c]
    Q = S @ cov @ S.T
    return F, 0.5 * (Q + Q.T)


@kernel
def _propagate(
    H1: FloatArray,
    H2: FloatArray,
    cov: FloatArray,
    R_i: FloatArray,
    R_j: FloatArray,
    P: FloatArray,
) -> FloatArray:
    """``Σ_j = F P Fᵀ + Q`` (9, 9) over (δθ, δt, δv_N) at j: :func:`_transition`'s map of the
    keyframe's (15, 15) covariance ``P``, its navigation rows only."""
    F, Q = _transition(H1, H2, cov, R_i, R_j)
    Fn = np.ascontiguousarray(F[:9])
    out = Fn @ P @ Fn.T + Q[:9, :9]
    return 0.5 * (out + out.T)


_KernelArgs = tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]
"""``(H1, H2, Σ, C_NB at i, C_NB at j)``: :func:`_transition`'s arguments."""


class ImuTransition:
    """The keyframe's side of the IMU factor, reused for every prediction from a keyframe
    (every control step between two scans, and the association's) and moved to the next
    keyframe with :meth:`rebase`.

    Args:
        gtsam: The ``gtsam`` module.
        pose: The keyframe's ``gtsam.Pose3`` (``C_NB``, ρ in N, m).
        vel: (3,) its velocity in N, m/s.
        bias: Its ``imuBias.ConstantBias`` (the bias held over the preintegration).
    """

    def __init__(self, gtsam: Any, pose: Any, vel: FloatArray, bias: Any) -> None:
        self._g = gtsam
        self.rebase(pose, vel, bias)
        # predict() fills these in place (column-major, as the bindings' Eigen maps want).
        self._H1 = np.zeros((9, 9), order="F")
        self._H2 = np.zeros((9, 6), order="F")

    def rebase(self, pose: Any, vel: FloatArray, bias: Any) -> None:
        """Move the transition to another keyframe (arguments as for the constructor)."""
        self._nav = self._g.NavState(pose, np.asarray(vel, dtype=float))
        self._bias = bias
        self._R_i = np.ascontiguousarray(pose.rotation().matrix(), dtype=float)

    def __call__(self, pim: Any) -> tuple[Any, FloatArray, FloatArray, FloatArray]:
        """The keyframe state predicted with ``pim`` and the linear map of its error (module
        docstring).

        Args:
            pim: ``PreintegratedCombinedMeasurements`` since the keyframe, integrated at the
                keyframe's bias (``deltaTij() > 0``).

        Returns:
            ``(pose_j, vel_j (3,), F (15, 15), Q (15, 15))``: the predicted ``Pose3`` and
            velocity (m/s, N), and ``δ_j = F δ_i + noise`` with noise covariance Q, over the
            tangent (δθ rad, δt m, δv_N m/s, δb_a m/s², δb_ω rad/s).
        """
        pose_j, vel_j, args = self._linearise(pim)
        F, Q = _transition(*args)
        return pose_j, vel_j, F, Q

    def propagate(self, pim: Any, P: FloatArray) -> tuple[Any, FloatArray, FloatArray, FloatArray]:
        """The keyframe state predicted with ``pim`` and its covariance: the estimate between
        keyframes, every control step.

        Args:
            pim: As for :meth:`__call__`.
            P: (15, 15) the keyframe's joint marginal over (δθ, δt, δv_N, δb_a, δb_ω).

        Returns:
            ``(pose_j, vel_j (3,), C_NB (3, 3) at j, Σ_j (9, 9))`` with ``Σ_j = F P Fᵀ + Q`` over
            (δθ rad, δt m, δv_N m/s), exactly symmetric.
        """
        pose_j, vel_j, args = self._linearise(pim)
        return pose_j, vel_j, args[4], _propagate(*args, P)

    def _linearise(self, pim: Any) -> tuple[Any, FloatArray, _KernelArgs]:
        """``predict`` with its Jacobians and the factor's noise covariance: ``(pose_j, vel_j,
        the kernels' arguments (H1, H2, Σ (15, 15), C_NB at i, C_NB at j), C order)``."""
        nav = pim.predict(self._nav, self._bias, self._H1, self._H2)
        pose_j = nav.pose()
        R_j = np.ascontiguousarray(pose_j.rotation().matrix(), dtype=float)
        factor = self._g.CombinedImuFactor(0, 1, 2, 3, 4, 5, pim)  # for its noise model only
        cov = np.ascontiguousarray(factor.noiseModel().covariance(), dtype=float)
        H1, H2 = np.ascontiguousarray(self._H1), np.ascontiguousarray(self._H2)
        args = (H1, H2, cov, self._R_i, R_j)
        return pose_j, np.asarray(nav.velocity(), dtype=float), args
