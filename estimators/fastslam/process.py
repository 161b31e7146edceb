"""Particle process models of the FastSLAM filters: the shared rigid-body kernels over N particles.

Both filters propagate their (N, 12) particle array with
:class:`quadslam_env.models.integrators.RigidBodyLanes` — the kernels that also step the
simulated vehicle — so the filter model is the simulator's model with (possibly mismatched)
nominal parameters. :func:`perturb_particles` then adds the process noise, wraps the Euler
angles and keeps the previous state of any particle that became non-finite, in one loop.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from estimators.inertia import angular_impulse
from quadslam_env.models.frames import wrap_pi
from quadslam_env.models.integrators import RigidBodyLanes, kinematic_derivative
from quadslam_env.models.jit import kernel
from quadslam_env.models.params import VehicleParams
from quadslam_env.models.rigid_body import pack_bodies, specific_force_lanes
from quadslam_env.types import VEL, FloatArray

_EYE3 = np.eye(3)


class DynamicsModel(RigidBodyLanes):
    """Quadcopter dynamics over particles with (possibly mismatched) nominal parameters.

    Args:
        vehicle: Nominal vehicle parameters (mass kg, inertia kg·m², drag 1/s).
        mass_scale: Factor on the mass used by the filter model.
        inertia_scale: Factor on the inertia used by the filter model (seed 000 Fig. 14 uses
            2.5, i.e. +150 %).
    """

    def __init__(
        self, vehicle: VehicleParams, mass_scale: float = 1.0, inertia_scale: float = 1.0
    ) -> None:
        inertia = np.array(vehicle.inertia, dtype=float) * inertia_scale
        super().__init__(float(vehicle.mass) * mass_scale, float(vehicle.drag), inertia)

    def set_inertia(self, inertia: ArrayLike) -> None:
        """Replace J (:meth:`RigidBodyLanes.set_inertia`) and :attr:`principal_theta`."""
        super().set_inertia(inertia)
        self.principal_theta = 1.0 / np.diag(self.inertia)

    def retune(
        self, x: FloatArray, theta: FloatArray, integrals: FloatArray, bias: FloatArray
    ) -> None:
        """Move the model to the principal inverse inertia ``θ`` (3,) in 1/(kg·m²), and the
        particles' rates with it: ``ω^i ← ω^i + θ ⊙ I(1/θ) − θ_model ⊙ I(1/θ_model)``, the
        change of the rate the flight's torques give (see
        :meth:`DynamicFastSLAM._identify_inertia`), with ``I(J) = ∫(τ − ω × Jω)`` from
        :func:`estimators.inertia.angular_impulse`. A no-op if ``θ`` equals
        :attr:`principal_theta`. The inertia becomes ``J = diag(1/θ)``, ``J⁻¹ = diag(1/J)``
        (what the general inverse gives for a diagonal J).

        Args:
            x: (N, 12) particle states, ω updated in place.
            theta: (3,) new θ. integrals: (4, 3) and bias: (3,) ``c`` in rad/s, of
                :class:`estimators.inertia.GyroTorqueRegression`.
        """
        J = np.empty(3)
        if _retune(
            x, theta, integrals, bias, self.principal_theta, J, self._bodies, self.mass, self.drag
        ):
            self.inertia = _EYE3 * J  # diag(J) (np.diag costs more than the step's kernel)
            self.inertia_inv = _EYE3 * (1.0 / J)

    def specific_force(self, x: FloatArray, thrust: float) -> FloatArray:
        """``f_B = −(f_T/m) b3 − drag v`` (..., 3) in m/s² for states (..., 12)."""
        return specific_force_lanes(x[..., VEL], thrust, self.mass, self.drag)


def dynamics_derivative_batch(
    x: FloatArray, thrust: float, torque: Any, vehicle: VehicleParams
) -> FloatArray:
    """:func:`quadslam_env.models.state_derivative` for states (..., 12), nominal parameters."""
    return DynamicsModel(vehicle).derivative(
        np.asarray(x, dtype=float), float(thrust), np.asarray(torque, dtype=float).reshape(3)
    )


kinematic_derivative_batch = kinematic_derivative
"""Strapdown kinematics of the kinematic filter (an alias kept for the FastSLAM API)."""


@kernel
def wrap_euler_rows(x: FloatArray) -> None:
    """Wrap the Euler angles ``x[:, EUL]`` of states (N, 12) to (-π, π] in place."""
    for i in range(x.shape[0]):
        for j in range(6, 9):
            x[i, j] = wrap_pi(x[i, j])


@kernel
def perturb_particles(
    x_new: FloatArray, x_old: FloatArray, draw: FloatArray, scale: FloatArray, bad: np.ndarray
) -> int:
    """Add process noise to propagated particles, wrap their angles, reject non-finite ones.

    ``x_new += draw ⊙ scale`` (row-wise), Euler angles wrapped to (-π, π]; a particle with any
    non-finite entry gets its previous state ``x_old`` back and is flagged in ``bad``.

    Args:
        x_new: (N, 12) propagated states, updated in place.
        x_old: (N, 12) states before the propagation.
        draw: (N, 12) standard normal draws.
        scale: (12,) noise std per state for this period (density × √dt).
        bad: (N,) bool, receives the rejected particles.

    Returns:
        The number of rejected particles.
    """
    n_bad = 0
    for i in range(x_new.shape[0]):
        row = x_new[i]
        finite = True
        for j in range(row.shape[0]):
            v = row[j] + draw[i, j] * scale[j]
            if 6 <= j < 9:
                v = wrap_pi(v)
            row[j] = v
            finite = finite and math.isfinite(v)
        bad[i] = not finite
        if not finite:
            n_bad += 1
            for j in range(row.shape[0]):
                row[j] = x_old[i, j]
    return n_bad


@kernel
def _retune(
    x: FloatArray,
    theta: FloatArray,
    integrals: FloatArray,
    bias: FloatArray,
    theta_model: FloatArray,
    J: FloatArray,
    bodies: FloatArray,
    mass: float,
    drag: float,
) -> bool:
    """:meth:`DynamicsModel.retune` in one pass: shift ω, repack the body, update θ_model.

    Returns whether anything changed; ``J`` (3,) receives ``1/θ`` in kg·m².
    """
    if theta[0] == theta_model[0] and theta[1] == theta_model[1] and theta[2] == theta_model[2]:
        return False
    new, old = np.empty(3), np.empty(3)
    angular_impulse(integrals, theta, bias, new)
    angular_impulse(integrals, theta_model, bias, old)
    for j in range(3):
        d = theta[j] * new[j] - theta_model[j] * old[j]
        for i in range(x.shape[0]):
            x[i, 9 + j] += d
    J_mat, J_inv = np.zeros((1, 3, 3)), np.zeros((1, 3, 3))
    for j in range(3):
        J[j] = 1.0 / theta[j]
        J_mat[0, j, j], J_inv[0, j, j] = J[j], 1.0 / J[j]
        theta_model[j] = 1.0 / J[j]
    body = pack_bodies(mass, drag, J_mat, J_inv)
    for k in range(body.shape[1]):
        bodies[0, k] = body[0, k]
    return True
