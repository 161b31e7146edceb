"""Differential-flatness LQR baseline (seed 001 §2.2, eq. 4–20) acting on the env observation.

The observation is already in the reference-heading frame (rotated by ``C3(ψ_d)ᵀ``), which is
exactly the frame of the inverse mapping (eq. 16), and the LQR gain is invariant to rotations
about n3 (x and y have equal weights), so the controller works on the observation directly:

1. ``r̃ = (ρ̂ - ρ_d, ρ̂̇ - ρ̇_d, ψ̂ - ψ_d)`` (eq. 11), ``u_d = (ρ̈_d - g n3, ψ̇_d)`` (eq. 5);
2. ``u = u_d - K r̃`` with ``K = R̃⁻¹ Bᵀ P̃`` from the continuous algebraic Riccati equation
   (eq. 12–14);
3. inverse mapping (eq. 15–19): ``f_T = m ‖u_p‖``, ``z = -(m/f_T) C3(ψ_d)ᵀ u_p``,
   ``φ_d = asin(-z2)``, ``θ_d = atan2(z1, z3)``, ``r_d = u_ψ cos θ_d / cos φ_d``,
   ``p_d = q_d = 0``;
4. PD attitude control (eq. 20): ``τ = -k_p (Λ̂ - Λ_d) - k_d (ω̂ - ω_d)``.

Weights: ``Q̃ = diag(0.01 ×6, 0.04)`` (seed 001 Table 2). The paper lists ``R̃ = diag(0.2, 0.32,
0.1)`` for a 4-input system; we read it as ``diag(0.2, 0.2, 0.32, 0.1)`` (x and y share 0.2).
The paper gives no PD gains; we place each axis at natural frequency ``ω_n`` with damping ``ζ``
scaled by the inertia (``k_p = J_ii ω_n²``, ``k_d = 2 ζ ω_n J_ii``), so the same tuning suits
both vehicle presets. ``ω_n = (20, 20, 10) rad/s`` and ``ζ = 0.7`` were chosen by sweeping
(8…25 rad/s, ζ 0.7/0.9) with the oracle estimator on the figure-8: the attitude loop's lag is
the main tracking error because the paper sets ``p_d = q_d = 0`` (RMSE after the climb 0.10 m
at 8 rad/s, 0.04 m at 20 rad/s). Two caps lower ``ω_n`` where the vehicle or its sensors
cannot support it (:func:`attitude_natural_freq`): the IMU rate (:data:`RATE_FEEDBACK_BANDWIDTH`)
and the torque available around hover (:data:`BRAKING_RATE`).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.linalg import solve_continuous_are

from quadslam_env.models.flatness import inverse_map
from quadslam_env.models.jit import kernel
from quadslam_env.models.params import VehicleParams
from quadslam_env.types import GRAVITY, FloatArray

Q_TILDE = np.diag([0.01] * 6 + [0.04])
R_TILDE = np.diag([0.2, 0.2, 0.32, 0.1])
ATTITUDE_NATURAL_FREQ = np.array([20.0, 20.0, 10.0])  # rad/s for roll, pitch, yaw
ATTITUDE_DAMPING = 0.7
RATE_FEEDBACK_BANDWIDTH = 0.4
"""Largest attitude-loop natural frequency per Hz of IMU rate, rad/s/Hz. The loop's damping
feeds back the estimated rates, which a slow IMU refreshes only every T = 1/f_IMU (and as an
average over the period before): a delay of about T, whose phase lag ω_c T at the crossover
ω_c ≈ 2ζω_n must stay below ~0.6 rad to keep ~30° of the PD loop's phase margin, so
ω_n ≤ 0.6 / (1.4 T) ≈ 0.4 f_IMU. At 100 Hz that is 40 rad/s (the defaults stand); at the
paper's 10 Hz IMU it is 4 rad/s (with 20 rad/s the vehicle tips over within a second)."""
BRAKING_RATE = 1.5
"""Rate error in rad/s from which the saturated attitude loop must stop without overshoot.
A PD loop ``τ = −J ω_n² e − 2ζω_n J ė`` whose torque saturates at ``J α`` brakes at α only
once it crosses its switching line ``ė = −ω_n e / (2ζ)``, at the error ``e = 2ζ|ė|/ω_n``; it
stops within that distance iff ``ė² / (2α) ≤ 2ζ|ė|/ω_n``, i.e. ``ω_n ≤ 4ζα / |ė|``. Beyond it
the loop overshoots, and on a vehicle with rotors each torque reversal swings two rotors from
one end of their range to the other through the motor lag, losing collective thrust (``T ∝
ω²``). The paper vehicle with its 1000 rad/s rotors has α = 1.4 rad/s² in yaw around hover
(0.24 N·m / 0.171 kg·m²), so its yaw loop gets ω_n = 2.6 rad/s instead of 10 (at 10 rad/s
the yaw torque sits at a limit on 94 % of the steps, the figure-8's 45° initial heading error
overshoots and the vehicle drifts off, see docs/performance.md). The presets without rotors
(α ≥ 5.8 rad/s², yaw of ``rauniyar2023``) keep :data:`ATTITUDE_NATURAL_FREQ`."""


def attitude_natural_freq(
    imu_rate_hz: float,
    vehicle: VehicleParams | None = None,
    damping: float = ATTITUDE_DAMPING,
) -> FloatArray:
    """(3,) attitude-loop natural frequencies in rad/s: :data:`ATTITUDE_NATURAL_FREQ` capped
    at :data:`RATE_FEEDBACK_BANDWIDTH` × f_IMU and, given a ``vehicle``, per axis at
    ``4ζα/``:data:`BRAKING_RATE` with ``α = hover torque / J_ii`` in rad/s²
    (:attr:`VehicleParams.hover_torque`)."""
    cap = np.minimum(ATTITUDE_NATURAL_FREQ, RATE_FEEDBACK_BANDWIDTH * float(imu_rate_hz))
    if vehicle is None:
        return cap
    alpha = vehicle.hover_torque / np.diag(vehicle.inertia)
    return np.minimum(cap, 4.0 * damping * alpha / BRAKING_RATE)


def flat_system() -> tuple[FloatArray, FloatArray]:
    """``A`` (7×7) and ``B`` (7×4) of the flat model ``ṙ = A r + B u + b g`` (seed 001 eq. 6)."""
    A = np.zeros((7, 7))
    A[0:3, 3:6] = np.eye(3)
    B = np.zeros((7, 4))
    B[3:7, 0:4] = np.eye(4)
    return A, B


def lqr_gain(Q: FloatArray = Q_TILDE, R: FloatArray = R_TILDE) -> FloatArray:
    """``K = R̃⁻¹ Bᵀ P̃`` (4×7) with ``P̃`` solving eq. 13 (``scipy.linalg.solve_continuous_are``)."""
    A, B = flat_system()
    P = solve_continuous_are(A, B, Q, R)
    return np.linalg.solve(R, B.T @ P)


@kernel
def _command_lanes(
    obs: FloatArray,
    K: FloatArray,
    kp: FloatArray,
    kd: FloatArray,
    mass: float,
    limits: FloatArray,
    out: FloatArray,
) -> None:
    """DF-LQR command ``out`` (n, 4) for observations ``obs`` (n, ≥16), steps 1–4.

    With ``limits`` = (max thrust N, max torques (3) N·m) the command is written as the
    normalised ``thrust_torque`` action clipped to [-1, 1]; with an empty ``limits`` as
    physical thrust (N) and torque (N·m).
    """
    r_err = np.empty(7)
    v = np.empty(4)
    for b in range(obs.shape[0]):
        o = obs[b]
        for i in range(6):
            r_err[i] = o[i]
        r_err[6] = o[8]
        # u = u_d − K r̃ with u_d = (ρ̈_d − g n3, ψ̇_d) (n3 is unchanged by the heading rotation).
        u = (o[12], o[13], o[14] - GRAVITY, o[15])
        for i in range(4):
            acc = u[i]
            for j in range(7):
                acc -= K[i, j] * r_err[j]
            v[i] = acc
        thrust, phi_d, theta_d, r_d = inverse_map(v[0], v[1], v[2], v[3], mass)
        out[b, 0] = thrust
        out[b, 1] = -kp[0] * (o[6] - phi_d) - kd[0] * o[9]
        out[b, 2] = -kp[1] * (o[7] - theta_d) - kd[1] * o[10]
        out[b, 3] = -kp[2] * o[8] - kd[2] * (o[11] - r_d)
        if limits.shape[0]:
            out[b, 0] = min(1.0, max(-1.0, 2.0 * out[b, 0] / limits[0] - 1.0))
            for i in range(1, 4):
                out[b, i] = min(1.0, max(-1.0, out[b, i] / limits[i]))


class DFLQRPolicy:
    """DF-LQR on the env observation, with stable-baselines3's ``predict`` signature.

    Args:
        vehicle: Nominal vehicle parameters (mass, inertia, actuator limits).
        natural_freq: (3,) attitude-loop natural frequencies in rad/s.
        damping: Attitude-loop damping ratio.
        action_dim: 4, or 5 for an env with the heading channel (``action.heading``): the
            fifth component, the reference heading's rate, is 0 (the heading is held).

    Attributes:
        K: (4, 7) LQR gain on ``r̃ = (ρ̃, ρ̃̇, ψ̃)``.
        kp, kd: (3,) attitude PD gains in N·m/rad and N·m·s/rad.
    """

    def __init__(
        self,
        vehicle: VehicleParams,
        natural_freq: FloatArray = ATTITUDE_NATURAL_FREQ,
        damping: float = ATTITUDE_DAMPING,
        action_dim: int = 4,
    ) -> None:
        self.vehicle = vehicle
        self.K = lqr_gain()
        inertia = np.diag(vehicle.inertia)
        wn = np.asarray(natural_freq, dtype=float)
        self.kp = inertia * wn**2
        self.kd = 2.0 * damping * wn * inertia
        self._limits = np.array([vehicle.max_thrust, *vehicle.max_torque])
        self.action_dim = action_dim

    @classmethod
    def from_env(cls, env: Any, **kwargs: Any) -> DFLQRPolicy:
        """Build from a (possibly wrapped) ``QuadSLAMEnv``; requires the ``thrust_torque`` mode.

        Without a ``natural_freq`` argument the attitude loop is capped for the scenario's IMU
        rate and the vehicle's torque around hover (:func:`attitude_natural_freq`; unchanged at
        the default 100 Hz on the presets without rotors).
        """
        base = env.unwrapped
        mode = base.scenario.action.mode
        if mode != "thrust_torque":
            raise ValueError(f"action.mode: got {mode!r}; DFLQRPolicy needs 'thrust_torque'")
        if "natural_freq" not in kwargs:
            damping = kwargs.get("damping", ATTITUDE_DAMPING)
            imu_hz = base.scenario.imu_rate_hz
            kwargs["natural_freq"] = attitude_natural_freq(imu_hz, base.vehicle_params, damping)
        kwargs.setdefault("action_dim", base.scenario.action.dim)
        return cls(base.vehicle_params, **kwargs)

    def command(self, obs: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Physical command for observations.

        Args:
            obs: (n, obs_dim) observations (the base layout of ``QuadSLAMEnv``).

        Returns:
            ``(thrust (n,) N, torque (n, 3) N·m)`` before saturation.
        """
        out = np.empty((obs.shape[0], 4))
        _command_lanes(np.asarray(obs, dtype=float), self.K, self.kp, self.kd,
                       float(self.vehicle.mass), np.empty(0), out)  # fmt: skip
        return out[:, 0], out[:, 1:]

    def predict(
        self,
        observation: np.ndarray,
        state: Any = None,
        episode_start: Any = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, Any]:
        """SB3-style ``predict``: (obs_dim,) or (n, obs_dim) → float32 actions, ``state``."""
        obs = np.asarray(observation, dtype=float)
        single = obs.ndim == 1
        batch = obs[None, :] if single else obs
        act = np.zeros((batch.shape[0], self.action_dim))
        _command_lanes(batch, self.K, self.kp, self.kd, float(self.vehicle.mass), self._limits,
                       act)  # fmt: skip
        act = act.astype(np.float32)
        return (act[0] if single else act), state
