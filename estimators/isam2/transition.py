"""The keyframe-to-now transition of the smoother's navigation state through the IMU factor.

Between keyframes the estimator needs the state predicted with the current preintegration and
how its error depends on the keyframe's: for the estimate's covariance every control step, and
for data association, where the predicted pose's cross-covariance with the landmarks enters the
innovation covariance of each (return, landmark) pair.

GTSAM's ``CombinedImuFactor`` (Forster et al. 2017, "On-Manifold Preintegration for Real-Time
Visual-Inertial Odometry", IEEE T-RO 33(1), eq. 44–45, with the bias random walk) linearised
at the keyframe state ``i`` and its prediction ``j`` (where its error is zero) gives whitened
rows ``A_i δ_i + A_j δ_j = w``, ``w ~ N(0, I)``, over the 15-dim tangent
``δ = (δθ, δt, δv_N, δb_a, δb_ω)`` (Pose3 in B, velocity in N, biases). Solved for ``δ_j``::

    δ_j = F δ_i + A_j⁻¹ w,   F = −A_j⁻¹ A_i,   Q = A_j⁻¹ A_j⁻ᵀ,

so ``Σ_j = F Σ_i Fᵀ + Q`` and ``Cov(δ_j, δ_l) = F Cov(δ_i, δ_l)`` for any other variable l
(a landmark), which the IMU factor does not involve.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from quadslam_env.models.jit import kernel
from quadslam_env.types import FloatArray

NAV_DIM = 15
"""Keyframe tangent (δθ, δt, δv_N, δb_a, δb_ω): Pose3 (6) + velocity (3) + biases (6)."""

# Column blocks of the linearised CombinedImuFactor, keys (X_i, V_i, X_j, V_j, B_i, B_j).
_COLS_I = np.r_[0:9, 18:24]
_COLS_J = np.r_[9:18, 24:30]


@kernel
def _transition(
    A: FloatArray, cols_i: np.ndarray, cols_j: np.ndarray
) -> tuple[FloatArray, FloatArray]:
    """``(F, Q)`` of the module docstring from the whitened Jacobian ``A`` (15, 30)."""
    Ai = np.empty((NAV_DIM, NAV_DIM))
    Aj = np.empty((NAV_DIM, NAV_DIM))
    for c in range(NAV_DIM):
        Ai[:, c] = A[:, cols_i[c]]
        Aj[:, c] = A[:, cols_j[c]]
    Aj_inv = np.linalg.inv(Aj)
    return -Aj_inv @ Ai, Aj_inv @ Aj_inv.T


class ImuTransition:
    """The keyframe's side of the IMU factor, reused for every prediction from a keyframe
    (every control step between two scans, and the association's) and moved to the next
    keyframe with :meth:`rebase`.

    The factor's linearisation point ``(X_i, V_i, X_j, V_j, B_i, B_j)`` is one ``gtsam.Values``
    for the transition's life: a call updates the prediction's pose and velocity in place,
    :meth:`rebase` the keyframe's entries (a value inserted into a fresh ``Values`` costs far
    more in the Python bindings than one updated, a bias most). ``B_j`` keeps the first
    keyframe's bias: the factor's Jacobians do not depend on it (its bias part is the linear
    walk ``B_j − B_i``, and the preintegration involves ``B_i`` only), and only they are used.

    Args:
        gtsam: The ``gtsam`` module.
        pose: The keyframe's ``gtsam.Pose3`` (``C_NB``, ρ in N, m).
        vel: (3,) its velocity in N, m/s.
        bias: Its ``imuBias.ConstantBias`` (the bias held over the preintegration).
    """

    def __init__(self, gtsam: Any, pose: Any, vel: FloatArray, bias: Any) -> None:
        self._g = gtsam
        vel = np.asarray(vel, dtype=float)
        self._nav = gtsam.NavState(pose, vel)
        self._bias = bias
        values = gtsam.Values()
        for key, value in enumerate((pose, vel, pose, vel, bias, bias)):
            values.insert(key, value)
        self._values = values

    def rebase(self, pose: Any, vel: FloatArray, bias: Any) -> None:
        """Move the transition to another keyframe (arguments as for the constructor)."""
        vel = np.asarray(vel, dtype=float)
        self._nav = self._g.NavState(pose, vel)
        self._bias = bias
        self._values.update(0, pose)
        self._values.update(1, vel)
        self._values.update(4, bias)

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
        g = self._g
        nav = pim.predict(self._nav, self._bias)
        pose_j, vel_j = nav.pose(), np.asarray(nav.velocity(), dtype=float)
        self._values.update(2, pose_j)
        self._values.update(3, vel_j)
        factor = g.CombinedImuFactor(0, 1, 2, 3, 4, 5, pim)
        A = np.ascontiguousarray(factor.linearize(self._values).jacobian()[0], dtype=float)
        F, Q = _transition(A, _COLS_I, _COLS_J)
        return pose_j, vel_j, F, Q
