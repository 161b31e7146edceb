"""Geometric tracking control on SE(3) with integral action, on the env observation.

Lee, Leok & McClamroch, "Geometric tracking control of a quadrotor UAV on SE(3)", CDC 2010
(eq. 15–21 there), with the position-error integral of Goodarzi, Lee & Lee, "Geometric
nonlinear PID control of a quadrotor UAV on SE(3)", ECC 2013 (their ``−k_I e_I`` term). The
frames are theirs: NED with e3 down, the thrust along −b3, ``m v̇ = m g e3 − f R e3``.

The observation is in the reference-heading frame (rotated by ``C3(ψ_d)ᵀ``), in which the
reference heading is 0: there ``R = C(φ̂, θ̂, ψ̂ − ψ_d)`` and the desired heading axis is e1.
Per lane:

1. ``A = ẍ_d − k_x e_x − k_v e_v − k_I e_I − g e3`` (m/s²; Lee eq. 15 divided by m, with the
   integral), the acceleration the thrust must supply;
2. thrust ``f = −m A · R e3`` (eq. 15: projected on the current thrust axis), desired thrust
   axis ``b3_d = −A / ‖A‖``, ``b2_d = b3_d × e1 / ‖·‖``, ``b1_d = b2_d × b3_d``,
   ``R_d = [b1_d b2_d b3_d]`` (eq. 16–18);
3. ``e_R = ½ (R_dᵀ R − Rᵀ R_d)^∨``, ``e_Ω = Ω − Rᵀ R_d Ω_d`` with ``Ω_d = (0, 0, ψ̇_d)``
   (eq. 10–11), and ``M = −k_R e_R − k_Ω e_Ω + Ω × J Ω`` (eq. 16, without the
   ``Ω̇_d`` terms, which the figure-8's slow references make small).

**Gains** (:data:`POSITION_GAINS`). ``k_x, k_v, k_I`` per unit mass are those of the LQI's
Riccati design (:mod:`agents.control.lqi`: ``k_x = 6.7 s⁻²``, ``k_v = 3.7 s⁻¹``,
``k_I = 4.0 s⁻³``, poles at 1–2 rad/s), so the two baselines share their outer-loop bandwidth
and differ in the attitude law; ``k_R = J ω_n²`` and ``k_Ω = 2ζω_n J`` per axis with DF-LQR's
natural frequencies and their caps for the IMU rate and the torque at hover
(:func:`~agents.control.dflqr.attitude_natural_freq`), so the same defaults suit the paper
vehicle and the Crazyflie. The tilt limit and the integral are the LQI's: the commanded tilt at
most 30°, the integral in the heading frame, not integrated on a lane whose thrust or roll/pitch
torque saturates or whose tilt is limited (conditional integration, no take-off hold), carried
in ``predict``'s ``state`` (n, 3) m·s. The drag feed-forward is the LQI's
(``drag_feedforward=True``: ``A`` gains the compensation of :mod:`agents.control.drag`), and so
is the thrust adaptation (``thrust_adaptation=True``: the feed-forward ``ẍ_d``, and the drag
compensation, scaled by ``r̂ = 1 − c_z / g`` of the vertical integral command
``c_z = −k_I e_I,z``, :mod:`agents.control.adaptation`).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from agents.control.adaptation import scale_reference, thrust_ratio
from agents.control.dflqr import (
    ATTITUDE_DAMPING,
    ATTITUDE_NATURAL_FREQ,
    BRAKING_RATE,
    env_controller_kwargs,
    heading_frame_step,
    limit_tilt,
)
from agents.control.drag import DragFeedforward, check_flag
from agents.control.lqi import MAX_TILT_DEG, check_separation, lqi_gain, saturated
from quadslam_env.models.frames import dcm_from_trig
from quadslam_env.models.jit import kernel
from quadslam_env.models.params import VehicleParams
from quadslam_env.schema import ConfigError
from quadslam_env.types import GRAVITY, FloatArray


def _lqi_position_gains() -> tuple[float, float, float]:
    K_r, K_xi, _ = lqi_gain()
    return float(K_r[0, 0]), float(K_r[0, 3]), float(K_xi[0, 0])


POSITION_GAINS = _lqi_position_gains()
"""Default ``(k_x [s⁻²], k_v [s⁻¹], k_I [s⁻³])`` per unit mass: the LQI's horizontal gains."""
_NO_OFFSET = np.empty((0, 3))


@kernel
def _se3_lanes(
    obs: FloatArray,
    gains: FloatArray,
    kR: FloatArray,
    kW: FloatArray,
    inertia: FloatArray,
    mass: float,
    limits: FloatArray,
    integral: FloatArray,
    offset: FloatArray,
    tan_max: float,
    rate_limit: float,
    out: FloatArray,
    tilted: np.ndarray,
) -> None:
    """Normalised ``thrust_torque`` actions ``out`` (n, 4) for observations ``obs`` (n, ≥16),
    steps 1–3 of the module docstring; ``gains = (k_x, k_v, k_I)`` (``k_I`` unused here),
    ``integral`` (n, 3) the integral command ``−k_I e_I`` in m/s², ``offset`` (n, 3) m/s² added
    to ``A`` (the drag compensation; an empty (0, 3) adds nothing), ``limits = (max thrust N,
    max torques (3) N·m)``, ``inertia`` (3, 3) kg·m²; ``A`` is tilt-limited
    (:func:`~agents.control.dflqr.limit_tilt`), the lanes so limited marked in ``tilted``
    (n,)."""
    A = np.empty(3)
    Rd = np.empty((3, 3))
    E = np.empty((3, 3))
    for b in range(obs.shape[0]):
        o = obs[b]
        for i in range(3):
            A[i] = o[12 + i] - gains[0] * o[i] - gains[1] * o[3 + i] + integral[b, i]
        A[2] -= GRAVITY
        if offset.shape[0]:
            for i in range(3):
                A[i] += offset[b, i]
        A[0], A[1], A[2], tilted[b] = limit_tilt(A[0], A[1], A[2], tan_max)
        c = dcm_from_trig(math.cos(o[6]), math.sin(o[6]), math.cos(o[7]), math.sin(o[7]),
                          math.cos(o[8]), math.sin(o[8]))  # fmt: skip
        # f = −m A · R e3 (R e3 is the third column of C_NB)
        thrust = -mass * (A[0] * c[2] + A[1] * c[5] + A[2] * c[8])
        norm = math.sqrt(A[0] * A[0] + A[1] * A[1] + A[2] * A[2])
        b3 = (-A[0] / norm, -A[1] / norm, -A[2] / norm)
        n2 = math.sqrt(b3[2] * b3[2] + b3[1] * b3[1])  # b3 × e1 = (0, b3z, −b3y)
        b2 = (0.0, b3[2] / n2, -b3[1] / n2)
        b1 = (b2[1] * b3[2] - b2[2] * b3[1], b2[2] * b3[0] - b2[0] * b3[2],
              b2[0] * b3[1] - b2[1] * b3[0])  # fmt: skip
        for i in range(3):
            Rd[i, 0], Rd[i, 1], Rd[i, 2] = b1[i], b2[i], b3[i]
        # E = R_dᵀ R (R = C_NB row-major in c)
        for i in range(3):
            for j in range(3):
                E[i, j] = Rd[0, i] * c[j] + Rd[1, i] * c[3 + j] + Rd[2, i] * c[6 + j]
        eR = (0.5 * (E[2, 1] - E[1, 2]), 0.5 * (E[0, 2] - E[2, 0]), 0.5 * (E[1, 0] - E[0, 1]))
        # Rᵀ R_d Ω_d with Ω_d = (0, 0, ψ̇_d): ψ̇_d times the third row of E = (R_dᵀ R)ᵀ's column
        w = (o[9], o[10], o[11])
        jw = (inertia[0, 0] * w[0] + inertia[0, 1] * w[1] + inertia[0, 2] * w[2],
              inertia[1, 0] * w[0] + inertia[1, 1] * w[1] + inertia[1, 2] * w[2],
              inertia[2, 0] * w[0] + inertia[2, 1] * w[1] + inertia[2, 2] * w[2])  # fmt: skip
        gyro = (w[1] * jw[2] - w[2] * jw[1], w[2] * jw[0] - w[0] * jw[2],
                w[0] * jw[1] - w[1] * jw[0])  # fmt: skip
        out[b, 0] = min(1.0, max(-1.0, 2.0 * thrust / limits[0] - 1.0))
        for i in range(3):
            eW = w[i] - E[2, i] * o[15]
            # −k_R e_R − k_Ω e_Ω as a rate loop on a bounded rate set-point: the same law while
            # |k_R e_R / k_Ω| ≤ the braking rate, and a loop that can stop its torque-limited
            # swing beyond it (agents.control.dflqr.BRAKING_RATE)
            rate_sp = min(rate_limit, max(-rate_limit, -kR[i] * eR[i] / kW[i]))
            torque = -kW[i] * (eW - rate_sp) + gyro[i]
            out[b, 1 + i] = min(1.0, max(-1.0, torque / limits[1 + i]))


class SE3Policy:
    """Geometric SE(3) tracking with integral action, with SB3's ``predict`` (module docstring).

    Args:
        vehicle: Nominal vehicle parameters (mass, inertia, actuator limits).
        natural_freq: (3,) attitude natural frequencies in rad/s (``k_R = J ω_n²``).
        damping: Attitude damping ratio (``k_Ω = 2ζω_n J``).
        action_dim: 4, or 5 with the heading channel (its component is 0).
        position_gains: ``(k_x s⁻², k_v s⁻¹, k_I s⁻³)`` per unit mass; ``k_I = 0`` is Lee et
            al.'s controller without the integral.
        max_tilt_deg: Largest commanded tilt in degrees (the LQI's default; 90: no limit).
        control_dt: Control period in s (the integration step).
        drag_feedforward: Add the compensation of the estimated drag to ``A``
            (:mod:`agents.control.drag`); False: the controller as before, bit for bit.
        air_velocity_index: First observation entry of the estimated air velocity (the
            ``air_velocity`` block; ``from_env`` finds it), needed with ``drag_feedforward``.
        thrust_adaptation: Scale the feed-forward by the thrust ratio the vertical integral
            measures (:mod:`agents.control.adaptation`); False: the controller as before, bit
            for bit.

    Raises:
        ConfigError: Negative or non-finite gains, an unstable outer loop (the linearised
            per-axis loop ``s³ + k_v s² + k_x s + k_I`` must be Hurwitz: ``k_I < k_x k_v``),
            one too fast for the attitude loop, a ``drag_feedforward`` that is not a bool, or
            one without the air velocity, a ``thrust_adaptation`` that is not a bool, or one
            with ``k_I = 0``.
    """

    def __init__(
        self,
        vehicle: VehicleParams,
        natural_freq: FloatArray | None = None,
        damping: float = ATTITUDE_DAMPING,
        action_dim: int = 4,
        position_gains: tuple[float, float, float] = POSITION_GAINS,
        max_tilt_deg: float = MAX_TILT_DEG,
        control_dt: float = 0.01,
        drag_feedforward: bool = False,
        air_velocity_index: int | None = None,
        thrust_adaptation: bool = False,
    ) -> None:
        if not (math.isfinite(max_tilt_deg) and 0.0 < max_tilt_deg <= 90.0):
            raise ConfigError(f"se3.max_tilt_deg: got {max_tilt_deg!r}; allowed: (0, 90]")
        self.adaptation = check_flag("se3", thrust_adaptation, "thrust_adaptation")
        self.feedforward = (
            DragFeedforward(vehicle, air_velocity_index, "se3")
            if check_flag("se3", drag_feedforward)
            else None
        )
        self._tan_max = math.inf if max_tilt_deg == 90.0 else math.tan(math.radians(max_tilt_deg))
        gains = np.asarray(position_gains, dtype=float)
        if gains.shape != (3,) or not np.all(np.isfinite(gains)) or np.any(gains < 0.0):
            raise ConfigError(
                f"se3.position_gains: got {list(np.ravel(position_gains))!r}; allowed: three "
                "finite numbers >= 0 (k_x s^-2, k_v s^-1, k_I s^-3)"
            )
        k_x, k_v, k_i = gains
        if not (k_x > 0.0 and k_v > 0.0 and k_i < k_x * k_v):
            raise ConfigError(
                f"se3.position_gains: got {gains.tolist()}; allowed: k_x > 0, k_v > 0 and "
                f"k_I < k_x k_v = {k_x * k_v:.4g} (Routh-Hurwitz of s^3 + k_v s^2 + k_x s + k_I)"
            )
        wn = ATTITUDE_NATURAL_FREQ if natural_freq is None else natural_freq
        wn = np.asarray(wn, dtype=float)
        check_separation(np.roots([1.0, k_v, k_x, k_i] if k_i > 0 else [1.0, k_v, k_x]), wn)
        if self.adaptation and k_i == 0.0:
            raise ConfigError(
                f"se3.thrust_adaptation: got true with position_gains {gains.tolist()}; allowed:"
                " false, or k_I > 0 (the vertical integral's command is the estimate)"
            )
        inertia = np.diag(vehicle.inertia)
        self.vehicle = vehicle
        self.gains = gains
        self.kR = inertia * wn**2
        self.kW = 2.0 * damping * wn * inertia
        self._limits = np.array([vehicle.max_thrust, *vehicle.max_torque])
        self.action_dim = action_dim
        self.control_dt = float(control_dt)

    @classmethod
    def from_env(cls, env: Any, **kwargs: Any) -> SE3Policy:
        """Build from a (possibly wrapped) env in ``thrust_torque`` mode; the attitude gains
        capped as DF-LQR's (:func:`~agents.control.dflqr.attitude_natural_freq`)."""
        vehicle, kwargs = env_controller_kwargs(env, cls.__name__, kwargs)
        return cls(vehicle, **kwargs)

    def predict(
        self,
        observation: np.ndarray,
        state: Any = None,
        episode_start: Any = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, Any]:
        """SB3-style ``predict``: (obs_dim,) or (n, obs_dim) → float32 actions and the (n, 3)
        position-error integral after this step (zeros on lanes whose ``episode_start`` is set,
        or when no ``state`` is given). With the thrust adaptation each lane's feed-forward is
        scaled by the ratio of its integral before this step (:meth:`thrust_ratio`)."""
        obs = np.asarray(observation, dtype=float)
        single = obs.ndim == 1
        batch = obs[None, :] if single else obs
        n = batch.shape[0]
        xi = np.zeros((n, 3)) if state is None else np.array(state, dtype=float).reshape(n, 3)
        if state is not None and episode_start is not None:
            xi[np.asarray(episode_start, dtype=bool).reshape(n)] = 0.0
        act = np.zeros((n, self.action_dim))
        tilted = np.empty(n, dtype=np.bool_)
        drag = _NO_OFFSET if self.feedforward is None else self.feedforward.compensation(batch)
        command = self._integral_command(xi)
        flown = batch
        if self.adaptation:  # the feed-forward scaled (agents.control.adaptation)
            ratio = thrust_ratio(command[:, 2])
            flown = scale_reference(batch, ratio)
            drag = drag if self.feedforward is None else ratio[:, None] * drag
        _se3_lanes(flown, self.gains, self.kR, self.kW, np.asarray(self.vehicle.inertia),
                   float(self.vehicle.mass), self._limits, command, drag, self._tan_max,
                   BRAKING_RATE, act, tilted)  # fmt: skip
        turned, grown = heading_frame_step(xi, batch, self.control_dt)
        state = np.where(saturated(act, tilted)[:, None], turned, grown)
        act = act.astype(np.float32)
        return (act[0] if single else act), state

    def _integral_command(self, xi: FloatArray) -> FloatArray:
        """(n, 3) the integral action ``−k_I e_I`` in m/s² (heading frame) of the (n, 3)
        integrals ``xi`` in m·s."""
        return -self.gains[2] * xi

    def thrust_ratio(self, state: Any) -> FloatArray:
        """(n,) the thrust ratio ``r̂ = m_eff / m_nom`` each lane's integral ``state`` (n, 3)
        measures (:func:`~agents.control.adaptation.thrust_ratio` of the vertical integral
        command), whether or not the adaptation is on; ``None``: one lane, 1.0."""
        xi = np.zeros((1, 3)) if state is None else np.array(state, dtype=float).reshape(-1, 3)
        return thrust_ratio(self._integral_command(xi)[:, 2])
