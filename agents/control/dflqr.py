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

import math
from typing import Any

import numpy as np
from scipy.linalg import solve_continuous_are

from agents.control.drag import feedforward_kwargs
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
INTEGRAL_LIMIT = 0.3 * GRAVITY
"""Default cap of the integral action per axis, m/s²: a thrust-to-weight error of 30 %, beyond
the ±20 % mass and ±10 % thrust of the randomised scenario (``ekf_figure8_randomized``)."""
_NO_OFFSET = np.empty((0, 4))
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


def integral_gain_bound(K: FloatArray) -> float:
    """Largest stable integral gain ``k_i`` in s⁻³ of the outer loop with gain ``K`` (4, 7).

    Each flat axis with integral action is ``s³ + K_d s² + K_p s + k_i`` (``K_p = K[i, i]``,
    ``K_d = K[i, 3 + i]``), Hurwitz iff ``k_i < K_p K_d`` (Routh–Hurwitz); the bound is the
    smallest over x, y, z (0.110 s⁻³ for z with :data:`Q_TILDE`, :data:`R_TILDE`).
    """
    return float(min(K[i, i] * K[i, 3 + i] for i in range(3)))


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
def limit_tilt(ux: float, uy: float, uz: float, tan_max: float) -> tuple:
    """Scale the horizontal part of a thrust acceleration so that its tilt from the vertical
    stays at most ``atan(tan_max)``.

    Args:
        ux, uy, uz: ``u_p`` (m/s², NED-like axes: ``uz < 0`` points the thrust up).
        tan_max: tan of the largest tilt; ``inf`` leaves every command as it is.

    Returns:
        ``(ux, uy, uz, limited)``: the command with ``√(ux² + uy²) ≤ tan_max · (−uz)`` (the
        horizontal part scaled, the vertical kept), and whether it had to be scaled.
    """
    if tan_max == math.inf:
        return ux, uy, uz, False
    horizontal = math.sqrt(ux * ux + uy * uy)
    allowed = tan_max * max(-uz, 0.0)
    if horizontal <= allowed:
        return ux, uy, uz, False
    scale = allowed / horizontal
    return ux * scale, uy * scale, uz, True


@kernel
def _command_lanes(
    obs: FloatArray,
    K: FloatArray,
    kp: FloatArray,
    kd: FloatArray,
    mass: float,
    limits: FloatArray,
    u_offset: FloatArray,
    tan_max: float,
    out: FloatArray,
    tilted: np.ndarray,
) -> None:
    """DF-LQR command ``out`` (n, 4) for observations ``obs`` (n, ≥16), steps 1–4.

    With ``limits`` = (max thrust N, max torques (3) N·m) the command is written as the
    normalised ``thrust_torque`` action clipped to [-1, 1]; with an empty ``limits`` as
    physical thrust (N) and torque (N·m). ``u_offset`` (n, k), k ≤ 4, is added to the first k
    entries of ``u = (u_p [m/s², heading frame], u_ψ [rad/s])`` before the inverse map (the
    integral action); an empty (0, k) array adds nothing. ``u_p`` is then tilt-limited
    (:func:`limit_tilt`, ``tan_max = inf``: not at all, DF-LQR as the paper has it) and
    ``tilted`` (n,) records the lanes whose command was.
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
        if u_offset.shape[0]:
            for i in range(u_offset.shape[1]):
                v[i] += u_offset[b, i]
        v[0], v[1], v[2], tilted[b] = limit_tilt(v[0], v[1], v[2], tan_max)
        thrust, phi_d, theta_d, r_d = inverse_map(v[0], v[1], v[2], v[3], mass)
        out[b, 0] = thrust
        out[b, 1] = -kp[0] * (o[6] - phi_d) - kd[0] * o[9]
        out[b, 2] = -kp[1] * (o[7] - theta_d) - kd[1] * o[10]
        out[b, 3] = -kp[2] * o[8] - kd[2] * (o[11] - r_d)
        if limits.shape[0]:
            out[b, 0] = min(1.0, max(-1.0, 2.0 * out[b, 0] / limits[0] - 1.0))
            for i in range(1, 4):
                out[b, i] = min(1.0, max(-1.0, out[b, i] / limits[i]))


def env_controller_kwargs(
    env: Any, name: str, kwargs: dict[str, Any]
) -> tuple[VehicleParams, dict[str, Any]]:
    """What a baseline controller takes from a (possibly wrapped) scalar or vector env: the
    nominal vehicle, and ``kwargs`` completed with the attitude natural frequencies capped for
    the IMU rate and the torque at hover (:func:`attitude_natural_freq`, unless given), the
    action layout, the control period and, with ``drag_feedforward=True``, the observation
    column of the estimated air velocity (:func:`~agents.control.drag.feedforward_kwargs`).

    Raises:
        ValueError: The env's action mode is not ``thrust_torque`` (naming ``name``).
    """
    base = env.unwrapped
    mode = base.scenario.action.mode
    if mode != "thrust_torque":
        raise ValueError(f"action.mode: got {mode!r}; {name} needs 'thrust_torque'")
    kwargs = dict(kwargs)
    if "natural_freq" not in kwargs:
        damping = kwargs.get("damping", ATTITUDE_DAMPING)
        imu_hz = base.scenario.imu_rate_hz
        kwargs["natural_freq"] = attitude_natural_freq(imu_hz, base.vehicle_params, damping)
    kwargs.setdefault("action_dim", base.scenario.action.dim)
    kwargs.setdefault("control_dt", 1.0 / base.scenario.episode.control_hz)
    return base.vehicle_params, feedforward_kwargs(env, kwargs)


def heading_frame_step(
    integral: FloatArray, obs: FloatArray, dt: float
) -> tuple[FloatArray, FloatArray]:
    """One Euler step of ``∫ ρ̃ dt`` kept in the reference-heading frame.

    The heading frame turns by ``ψ̇_d dt`` (obs[:, 15]) each step, so the components of the
    world-frame integral rotate by ``−ψ̇_d dt`` in it; the step then adds ``ρ̃ dt`` (obs[:, 0:3]).

    Args:
        integral: (n, 3) integral of the position error in the heading frame, m·s.
        obs: (n, ≥16) observations (base layout of ``QuadSLAMEnv``).
        dt: Control period, s.

    Returns:
        ``(turned, grown)``, both (n, 3) m·s: the integral in the new heading frame without and
        with this step's error.
    """
    angle = -obs[:, 15] * dt
    c, s = np.cos(angle), np.sin(angle)
    x, y = integral[:, 0], integral[:, 1]
    turned = np.stack([c * x - s * y, s * x + c * y, integral[:, 2]], axis=1)
    return turned, turned + obs[:, 0:3] * dt


class DFLQRPolicy:
    """DF-LQR on the env observation, with stable-baselines3's ``predict`` signature.

    Optional integral action (off by default, ``integral_gain=0``): ``u_p`` gets
    ``−k_i ∫ ρ̃ dt`` (``ρ̃`` the position error of the observation, integrated in the world
    frame and expressed in the heading frame), which removes the steady offset a constant
    acceleration error leaves (a mass or thrust mismatch: ``Δa / k_p`` without it, since the
    loop's position gain ``k_p = K[i, i]`` is soft). Anti-windup: each axis's contribution is
    clamped to ``integral_limit`` and the integral is frozen on the steps whose thrust command
    saturates and for ``integral_hold_s`` after the episode starts. ``predict``'s ``state``
    carries it per lane ((n, 4): the integral in m·s, then the time since the episode started
    in s): zeros on a lane whose ``episode_start`` is set, or when no state is given
    (:func:`integral_gain_bound`).

    Args:
        vehicle: Nominal vehicle parameters (mass, inertia, actuator limits).
        natural_freq: (3,) attitude-loop natural frequencies in rad/s.
        damping: Attitude-loop damping ratio.
        action_dim: 4, or 5 for an env with the heading channel (``action.heading``): the
            fifth component, the reference heading's rate, is 0 (the heading is held).
        integral_gain: ``k_i`` in s⁻³ (m/s² of command per m·s of integrated error), the same
            on x, y, z; 0 turns the integral off. Must stay below :func:`integral_gain_bound`.
        integral_limit: Largest integral contribution per axis, m/s².
        integral_hold_s: The integral stays frozen (at zero) for this long after each episode
            start, s: the take-off climb's error is the initial condition, not a disturbance.
        control_dt: Control period in s (the integration step; ``from_env`` uses the env's).

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
        integral_gain: float = 0.0,
        integral_limit: float = INTEGRAL_LIMIT,
        integral_hold_s: float = 0.0,
        control_dt: float = 0.01,
    ) -> None:
        self.vehicle = vehicle
        self.K = lqr_gain()
        inertia = np.diag(vehicle.inertia)
        wn = np.asarray(natural_freq, dtype=float)
        self.kp = inertia * wn**2
        self.kd = 2.0 * damping * wn * inertia
        self._limits = np.array([vehicle.max_thrust, *vehicle.max_torque])
        self.action_dim = action_dim
        bound = integral_gain_bound(self.K)
        if not 0.0 <= integral_gain < bound:
            raise ValueError(
                f"integral_gain: got {integral_gain!r}; allowed: 0 (off) up to below "
                f"{bound:.4g} s^-3 (the outer loop's stability bound K_p K_d)"
            )
        for key, value in (("integral_limit", integral_limit), ("control_dt", control_dt)):
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"{key}: got {value!r}; allowed: a finite number > 0")
        if not (math.isfinite(integral_hold_s) and integral_hold_s >= 0.0):
            raise ValueError(f"integral_hold_s: got {integral_hold_s!r}; allowed: a number >= 0")
        self.integral_hold_s = float(integral_hold_s)
        self.integral_gain = float(integral_gain)
        self.integral_limit = float(integral_limit)
        self.control_dt = float(control_dt)

    @classmethod
    def from_env(cls, env: Any, **kwargs: Any) -> DFLQRPolicy:
        """Build from a (possibly wrapped) ``QuadSLAMEnv``; requires the ``thrust_torque`` mode.

        Without a ``natural_freq`` argument the attitude loop is capped for the scenario's IMU
        rate and the vehicle's torque around hover (:func:`attitude_natural_freq`; unchanged at
        the default 100 Hz on the presets without rotors). ``kwargs`` go to the constructor
        (e.g. ``integral_gain``); ``control_dt`` is the scenario's control period.
        """
        vehicle, kwargs = env_controller_kwargs(env, cls.__name__, kwargs)
        return cls(vehicle, **kwargs)

    def command(self, obs: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Physical command for observations, without the integral (it lives in
        :meth:`predict`'s state).

        Args:
            obs: (n, obs_dim) observations (the base layout of ``QuadSLAMEnv``).

        Returns:
            ``(thrust (n,) N, torque (n, 3) N·m)`` before saturation.
        """
        out = np.empty((obs.shape[0], 4))
        _command_lanes(np.asarray(obs, dtype=float), self.K, self.kp, self.kd,
                       float(self.vehicle.mass), np.empty(0), _NO_OFFSET, math.inf, out,
                       np.empty(obs.shape[0], dtype=np.bool_))  # fmt: skip
        return out[:, 0], out[:, 1:]

    def predict(
        self,
        observation: np.ndarray,
        state: Any = None,
        episode_start: Any = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, Any]:
        """SB3-style ``predict``: (obs_dim,) or (n, obs_dim) → float32 actions, ``state``
        (passed through, or with the integral on the (n, 4) integral state after this step)."""
        obs = np.asarray(observation, dtype=float)
        single = obs.ndim == 1
        batch = obs[None, :] if single else obs
        act = np.zeros((batch.shape[0], self.action_dim))
        offset = _NO_OFFSET
        if self.integral_gain > 0.0:
            state = self._integral_state(state, episode_start, batch.shape[0])
            offset = -self.integral_gain * state[:, :3]
        _command_lanes(batch, self.K, self.kp, self.kd, float(self.vehicle.mass), self._limits,
                       offset, math.inf, act, np.empty(batch.shape[0], dtype=np.bool_))  # fmt: skip
        if self.integral_gain > 0.0:
            state = self._integrate(state, batch, np.abs(act[:, 0]) >= 1.0)
        act = act.astype(np.float32)
        return (act[0] if single else act), state

    def _integral_state(self, state: Any, episode_start: Any, n: int) -> FloatArray:
        """(n, 4) integral state to act on: ``state``'s, zeroed on the lanes starting an
        episode (all of them without a state)."""
        if state is None:
            return np.zeros((n, 4))
        out = np.array(state, dtype=float).reshape(n, 4)
        if episode_start is not None:
            out[np.asarray(episode_start, dtype=bool).reshape(n)] = 0.0
        return out

    def _integrate(self, state: FloatArray, obs: FloatArray, saturated: np.ndarray) -> FloatArray:
        """One Euler step of the (n, 4) state: ``∫ ρ̃ dt`` in the heading frame
        (:func:`heading_frame_step`); frozen on the lanes whose thrust is ``saturated`` (n,) or
        that are still within ``integral_hold_s`` of their start; clamped to
        ``integral_limit / k_i``. Column 3, the time since the episode started, advances by
        ``control_dt``."""
        dt = self.control_dt
        turned, grown = heading_frame_step(state[:, :3], obs, dt)
        cap = self.integral_limit / self.integral_gain
        frozen = saturated | (state[:, 3] < self.integral_hold_s)
        integral = np.where(frozen[:, None], turned, np.clip(grown, -cap, cap))
        return np.column_stack([integral, state[:, 3] + dt])
