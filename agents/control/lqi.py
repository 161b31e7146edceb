"""LQI: DF-LQR with integral action designed in the Riccati equation (seed 001 §2.2, augmented).

DF-LQR (:mod:`agents.control.dflqr`) regulates the flat error ``r̃ = (ρ̃, ρ̃̇, ψ̃)`` of the
double-integrator flat model ``ṙ̃ = A r̃ + B ũ`` (seed 001 eq. 6–14). A constant disturbance
``d`` on the acceleration (a steady wind's drag, a mass or thrust error) leaves it a steady
offset ``K_p⁻¹ d``. The LQI augments the state with the integrals of the flat outputs' errors,
``ξ̇ = C r̃`` with ``C`` picking ``(ρ̃, ψ̃)`` (the axes whose integral weight is positive), and
solves the continuous algebraic Riccati equation of the augmented system

    A_a = [[0, C], [0, A]],   B_a = [[0], [B]],   Q_a = diag(Q_ξ, Q̃),   R̃,

so ``u = u_d − K_r r̃ − K_ξ ξ`` with ``[K_ξ, K_r] = R̃⁻¹ B_aᵀ P_a`` (the textbook LQI, e.g.
Young & Willems 1972; Åström & Murray, *Feedback Systems* §7.4). For a constant disturbance the
closed loop is stable and ``ξ̇ = C r̃ → 0`` at its equilibrium: zero steady-state error on every
integrated axis (final-value theorem). With every integral weight 0 no state is added and the
gain is DF-LQR's, bit for bit.

The rest is DF-LQR's: the inverse map (eq. 15–19) and the attitude PD loop (eq. 20). The
integrals are kept in the reference-heading frame (:func:`~agents.control.dflqr.heading_frame_step`)
and carried in ``predict``'s ``state`` (n, 4): ``(∫x̃, ∫ỹ, ∫z̃ [m·s], ∫ψ̃ [rad·s])``, zeroed on a
lane whose ``episode_start`` is set.

**Tilt limit and anti-windup.** The commanded tilt is limited (:data:`MAX_TILT_DEG`, the
horizontal part of ``u_p`` scaled down). A lane whose thrust or roll/pitch torque command
saturates (a normalised action at ±1) or whose tilt is limited does not integrate on that step
(conditional integration): its actuators cannot follow the command, and integrating then is
what winds up. So the take-off climb needs no hold: while the climb's large error saturates
the thrust or the tilt nothing is integrated, and the integral the designed loop accumulates
after that is the one its Riccati gain accounts for.

**Weights** (:data:`STATE_WEIGHTS`, :data:`INTEGRAL_WEIGHTS`; R̃ is the paper's Table 2
``diag(0.2, 0.2, 0.32, 0.1)``). The paper's Q̃ (Table 2, 0.01 on every flat error) gives a
position gain of 0.18–0.22 s⁻², a 5 s time constant: a 0.7 m/s² drag leaves metres of error
while the integral removes it. The defaults weight the position error 3.2–5.1 (``q/r = 16``,
which alone would give ``K_p = 4 s⁻²``), the velocity error 0 and the position integrals
``q_ξ/r = 16`` too: the Riccati solution is ``K_p = 6.7 s⁻²``, ``K_d = 3.7 s⁻¹``,
``K_ξ = 4.0 s⁻³`` per axis, with closed-loop poles at 0.97 rad/s and a complex pair of
2.0 rad/s, a tenth of the attitude loop's 20 rad/s (the cascade's time-scale separation,
:func:`check_separation`). The heading keeps the paper's weights with a small integral
(``q_ξ = 0.01``; poles at 0.56 rad/s). The weights were set once from that bandwidth, not
tuned, and checked on the truth in the nominal, wind and randomised conditions of the
robustness study on seeds 0–3, not its held-out seeds (docs/robustness.md has the results).

**Drag feed-forward** (``drag_feedforward=True``, off by default): ``u_p`` gains the
compensation of the drag the vehicle's model predicts on the estimated air-relative velocity
(:mod:`agents.control.drag`), so the integral need not carry it.

**Thrust adaptation** (``thrust_adaptation=True``, off by default): the feed-forward ``ρ̈_d``
(and the drag compensation) of ``u_p`` is scaled by the thrust ratio ``r̂ = 1 − c_z / g`` that
the vertical integral command ``c_z = (−K_ξ ξ)_z`` measures (:mod:`agents.control.adaptation`),
so that a vehicle heavier or weaker than the model gets the reference's acceleration, not
``m_nom / m`` of it, without the integral having to follow it.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy.linalg import solve_continuous_are

from agents.control.adaptation import scale_reference, thrust_ratio
from agents.control.dflqr import (
    _NO_OFFSET,
    ATTITUDE_DAMPING,
    ATTITUDE_NATURAL_FREQ,
    R_TILDE,
    DFLQRPolicy,
    _command_lanes,
    flat_system,
    heading_frame_step,
    lqr_gain,
)
from agents.control.drag import DragFeedforward, check_flag
from quadslam_env.models.params import VehicleParams
from quadslam_env.schema import ConfigError
from quadslam_env.types import FloatArray

INTEGRATED = (0, 1, 2, 6)
"""Entries of ``r̃ = (ρ̃, ρ̃̇, ψ̃)`` whose integrals are the augmented states: the flat outputs
(x, y, z, ψ)."""
STATE_WEIGHTS = np.diag([16 * 0.2, 16 * 0.2, 16 * 0.32, 0.0, 0.0, 0.0, 0.04])
"""Default ``Q̃`` (7×7) over ``r̃``: ``q/r = 16`` on the positions (module docstring)."""
INTEGRAL_WEIGHTS = np.array([16 * 0.2, 16 * 0.2, 16 * 0.32, 0.01])
"""Default ``Q_ξ`` diagonal (4,) over ``(∫x̃, ∫ỹ, ∫z̃, ∫ψ̃)``; an entry 0 adds no state."""
MAX_TILT_DEG = 30.0
"""Default limit of the commanded tilt, degrees. A stiff outer loop asks for large tilts when
far from the reference (the take-off climb behind a moving reference); a saturating attitude
loop then tumbles on a vehicle with less torque than nominal (randomised inertia +19%: seed
1001 of the robustness study left the tilt limit in 3 s without it). Flight stacks limit it
too (PX4's ``MPC_TILTMAX_AIR``, 45° by default); the figure-8 needs 3°, the 2.2 m/s wind's drag
another 4°."""
SEPARATION = 0.25
"""Largest outer-loop pole magnitude as a share of the slowest attitude-loop natural frequency
(roll/pitch): the cascade assumes the attitude follows its command instantly, which holds for
poles well below the attitude loop's."""


def lqi_gain(
    state_weights: FloatArray = STATE_WEIGHTS,
    integral_weights: FloatArray = INTEGRAL_WEIGHTS,
    input_weights: FloatArray = R_TILDE,
) -> tuple[FloatArray, FloatArray, np.ndarray]:
    """The LQI gains of the augmented Riccati equation (module docstring).

    Args:
        state_weights: (7, 7) ``Q̃`` over ``r̃``, symmetric positive semidefinite.
        integral_weights: (4,) ``Q_ξ`` diagonal over ``(∫x̃, ∫ỹ, ∫z̃, ∫ψ̃)``, each ≥ 0.
        input_weights: (4, 4) ``R̃``, symmetric positive definite.

    Returns:
        ``(K_r (4, 7), K_ξ (4, 4), poles)``: the gain on ``r̃``, the gain on the integrals (a
        zero column for an axis with weight 0) and the closed-loop eigenvalues (complex, 1/s).

    Raises:
        ConfigError: A weight is negative, not finite or of the wrong shape, or the Riccati
            equation has no stabilising solution.
    """
    Q = _weights("lqi.state_weights", state_weights, (7, 7))
    qi = _weights("lqi.integral_weights", integral_weights, (4,))
    R = _weights("lqi.input_weights", input_weights, (4, 4))
    if np.any(np.linalg.eigvalsh((R + R.T) / 2) <= 0.0):
        raise ConfigError(f"lqi.input_weights: got {R.tolist()}; allowed: positive definite")
    if np.any(np.linalg.eigvalsh((Q + Q.T) / 2) < -1e-12) or np.any(qi < 0.0):
        raise ConfigError(
            f"lqi weights: got state {np.diag(Q).tolist()}, integral {qi.tolist()}; allowed: "
            "positive semidefinite state weights and integral weights >= 0"
        )
    A, B = flat_system()
    axes = [a for a, w in zip(INTEGRATED, qi, strict=True) if w > 0.0]
    K_xi = np.zeros((4, 4))
    if not axes:
        K_r = lqr_gain(Q, R)
        return K_r, K_xi, np.linalg.eigvals(A - B @ K_r)
    k = len(axes)
    Aa = np.zeros((k + 7, k + 7))
    Aa[np.arange(k), k + np.array(axes)] = 1.0
    Aa[k:, k:] = A
    Ba = np.vstack([np.zeros((k, 4)), B])
    Qa = np.zeros((k + 7, k + 7))
    Qa[:k, :k] = np.diag(qi[qi > 0.0])
    Qa[k:, k:] = Q
    try:
        P = solve_continuous_are(Aa, Ba, Qa, R)
    except (np.linalg.LinAlgError, ValueError) as exc:
        raise ConfigError(
            f"lqi weights: got state {np.diag(Q).tolist()}, integral {qi.tolist()}; the "
            f"augmented Riccati equation has no stabilising solution ({exc}); allowed: "
            "weights that make (A_a, Q_a) detectable, e.g. every integrated axis weighted > 0"
        ) from None
    Ka = np.linalg.solve(R, Ba.T @ P)
    poles = np.linalg.eigvals(Aa - Ba @ Ka)
    if not (np.all(np.isfinite(Ka)) and np.all(poles.real < 0.0)):
        raise ConfigError(
            f"lqi weights: got state {np.diag(Q).tolist()}, integral {qi.tolist()}; the "
            "augmented loop is not stable; allowed: finite weights with a stabilising solution"
        )
    cols = [i for i, w in enumerate(qi) if w > 0.0]
    K_xi[:, cols] = Ka[:, :k]
    return Ka[:, k:], K_xi, poles


def _weights(key: str, value: Any, shape: tuple[int, ...]) -> FloatArray:
    """``value`` as a finite float array of ``shape`` (a vector becomes a diagonal for a square
    ``shape``)."""
    arr = np.asarray(value, dtype=float)
    if len(shape) == 2 and arr.shape == shape[:1]:
        arr = np.diag(arr)
    if arr.shape != shape or not np.all(np.isfinite(arr)):
        raise ConfigError(
            f"{key}: got {np.asarray(value).tolist()!r}; allowed: finite numbers of shape "
            f"{shape}" + (f" or a diagonal of {shape[0]}" if len(shape) == 2 else "")
        )
    return arr


def check_separation(poles: np.ndarray, natural_freq: FloatArray) -> None:
    """Refuse an outer loop too fast for the attitude loop under it.

    Raises:
        ConfigError: The fastest pole exceeds :data:`SEPARATION` × the slowest roll/pitch
            natural frequency.
    """
    fastest = float(np.max(np.abs(poles)))
    bound = SEPARATION * float(np.min(np.asarray(natural_freq)[:2]))
    if fastest > bound:
        raise ConfigError(
            f"lqi weights: the outer loop's fastest pole is {fastest:.3g} rad/s; allowed: at "
            f"most {bound:.3g} rad/s ({SEPARATION} x the attitude loop's {bound / SEPARATION:.3g}"
            " rad/s), lower the state or integral weights"
        )


def saturated(act: FloatArray, tilted: np.ndarray) -> np.ndarray:
    """(n,) lanes that must not integrate this step: their normalised thrust or roll/pitch
    torque ``act`` (n, ≥3) at ±1, or their command tilt-limited (``tilted`` (n,))."""
    return tilted | np.any(np.abs(act[:, :3]) >= 1.0, axis=1)


class LQIPolicy(DFLQRPolicy):
    """DF-LQR with integral action in the Riccati design, with SB3's ``predict`` (module
    docstring).

    Args:
        vehicle: Nominal vehicle parameters (mass, inertia, actuator limits).
        natural_freq: (3,) attitude-loop natural frequencies in rad/s.
        damping: Attitude-loop damping ratio.
        action_dim: 4, or 5 with the heading channel (its component is 0).
        state_weights: (7, 7) or (7,) ``Q̃`` over ``r̃``.
        integral_weights: (4,) ``Q_ξ`` over the integrals; all 0 is DF-LQR.
        input_weights: (4, 4) or (4,) ``R̃``.
        max_tilt_deg: Largest commanded tilt in degrees (:func:`~agents.control.dflqr.limit_tilt`;
            90: no limit).
        control_dt: Control period in s (the integration step).
        drag_feedforward: Add the compensation of the estimated drag to ``u_p``
            (:mod:`agents.control.drag`); False: the LQI as before, bit for bit.
        air_velocity_index: First observation entry of the estimated air velocity (the
            ``air_velocity`` block; ``from_env`` finds it), needed with ``drag_feedforward``.
        thrust_adaptation: Scale the feed-forward by the thrust ratio the vertical integral
            measures (:mod:`agents.control.adaptation`); False: the LQI as before, bit for bit.

    Attributes:
        K: (4, 7) gain on ``r̃``; K_xi: (4, 4) gain on the integrals; poles: closed-loop
        eigenvalues of the outer loop, 1/s; feedforward: the
        :class:`~agents.control.drag.DragFeedforward`, or ``None``; adaptation: whether the
        thrust adaptation is on.

    Raises:
        ConfigError: Bad weights, an outer loop too fast for the attitude loop, a
            ``drag_feedforward`` that is not a bool, or one without the air velocity, a
            ``thrust_adaptation`` that is not a bool, or one without a vertical integral.
    """

    def __init__(
        self,
        vehicle: VehicleParams,
        natural_freq: FloatArray | None = None,
        damping: float = ATTITUDE_DAMPING,
        action_dim: int = 4,
        state_weights: FloatArray = STATE_WEIGHTS,
        integral_weights: FloatArray = INTEGRAL_WEIGHTS,
        input_weights: FloatArray = R_TILDE,
        max_tilt_deg: float = MAX_TILT_DEG,
        control_dt: float = 0.01,
        drag_feedforward: bool = False,
        air_velocity_index: int | None = None,
        thrust_adaptation: bool = False,
    ) -> None:
        if not (math.isfinite(max_tilt_deg) and 0.0 < max_tilt_deg <= 90.0):
            raise ConfigError(f"lqi.max_tilt_deg: got {max_tilt_deg!r}; allowed: (0, 90]")
        self.adaptation = check_flag("lqi", thrust_adaptation, "thrust_adaptation")
        self.feedforward = (
            DragFeedforward(vehicle, air_velocity_index, "lqi")
            if check_flag("lqi", drag_feedforward)
            else None
        )
        self._tan_max = math.inf if max_tilt_deg == 90.0 else math.tan(math.radians(max_tilt_deg))
        wn = ATTITUDE_NATURAL_FREQ if natural_freq is None else natural_freq
        super().__init__(vehicle, wn, damping=damping, action_dim=action_dim,
                         control_dt=control_dt)  # fmt: skip
        self.K, self.K_xi, self.poles = lqi_gain(state_weights, integral_weights, input_weights)
        wn = np.sqrt(self.kp / np.diag(vehicle.inertia))
        check_separation(self.poles, wn)
        self._integrates = bool(np.any(self.K_xi != 0.0))
        if self.adaptation and not np.any(self.K_xi[2] != 0.0):
            raise ConfigError(
                f"lqi.thrust_adaptation: got true with integral_weights "
                f"{np.asarray(integral_weights).tolist()}; allowed: false, or a vertical integral"
                " (integral_weights[2] > 0), whose command is the estimate"
            )

    def predict(
        self,
        observation: np.ndarray,
        state: Any = None,
        episode_start: Any = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, Any]:
        """SB3-style ``predict``: (obs_dim,) or (n, obs_dim) → float32 actions and the (n, 4)
        integral state after this step (``state`` passed through when no axis integrates).
        With the thrust adaptation each lane's feed-forward is scaled by the ratio of its
        integrals before this step (:meth:`thrust_ratio`)."""
        obs = np.asarray(observation, dtype=float)
        single = obs.ndim == 1
        batch = obs[None, :] if single else obs
        act = np.zeros((batch.shape[0], self.action_dim))
        mass = float(self.vehicle.mass)
        tilted = np.empty(batch.shape[0], dtype=np.bool_)
        drag = None if self.feedforward is None else self.feedforward.compensation(batch)
        if not self._integrates:
            offset = _NO_OFFSET if drag is None else drag
            _command_lanes(batch, self.K, self.kp, self.kd, mass, self._limits, offset,
                           self._tan_max, act, tilted)  # fmt: skip
        else:
            xi = self._integral_state(state, episode_start, batch.shape[0])
            offset = self._integral_command(xi)
            flown = batch
            if self.adaptation:  # the feed-forward scaled (agents.control.adaptation)
                ratio = thrust_ratio(offset[:, 2])
                flown = scale_reference(batch, ratio)
                drag = None if drag is None else ratio[:, None] * drag
            if drag is not None:
                offset[:, :3] += drag
            _command_lanes(flown, self.K, self.kp, self.kd, mass, self._limits, offset,
                           self._tan_max, act, tilted)  # fmt: skip
            state = self._step_integrals(xi, batch, saturated(act, tilted))
        act = act.astype(np.float32)
        return (act[0] if single else act), state

    def _integral_command(self, xi: FloatArray) -> FloatArray:
        """(n, 4) the integral action ``−K_ξ ξ`` of the (n, 4) integrals ``xi``: m/s² on
        ``u_p`` (heading frame), rad/s on ``u_ψ``."""
        return -xi @ self.K_xi.T

    def thrust_ratio(self, state: Any) -> FloatArray:
        """(n,) the thrust ratio ``r̂ = m_eff / m_nom`` each lane's integrals ``state`` (n, 4)
        measure (:func:`~agents.control.adaptation.thrust_ratio` of the vertical integral
        command), whether or not the adaptation is on; ``None``: one lane, 1.0."""
        xi = np.zeros((1, 4)) if state is None else np.array(state, dtype=float).reshape(-1, 4)
        return thrust_ratio(self._integral_command(xi)[:, 2])

    def _step_integrals(self, xi: FloatArray, obs: FloatArray, held: np.ndarray) -> FloatArray:
        """The (n, 4) integrals after one control period: the position integral turned with the
        heading frame, this step's errors added on the lanes not ``held`` (n,) (conditional
        integration, :func:`saturated`)."""
        turned, grown = heading_frame_step(xi[:, :3], obs, self.control_dt)
        grown_psi = xi[:, 3] + obs[:, 8] * self.control_dt
        free = ~held
        out = np.empty_like(xi)
        out[:, :3] = np.where(free[:, None], grown, turned)
        out[:, 3] = np.where(free, grown_psi, xi[:, 3])
        return out
