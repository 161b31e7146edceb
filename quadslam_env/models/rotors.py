"""Rotors of a quadcopter: thrust, drag torque, the mixer, its inverse, the motor lag.

Frames (docs/design.md §2): body B is FRD (b1 forward, b2 right, b3 down). Rotor i sits at
``r_i = (x_i, y_i, 0)`` in B, pushes with thrust ``T_i = k_f ω_i²`` along ``−b3`` and twists the
body about b3 with the reaction of its drag torque ``d_i k_m ω_i²``, where ``d_i = +1`` for a
rotor spinning counter-clockwise seen from above (its reaction yaws the body clockwise seen
from above: a positive ψ̇ in NED) and ``−1`` for a clockwise one. The force ``−T_i b3`` at
``r_i`` gives the moment ``r_i × (−T_i b3) = (−y_i T_i, x_i T_i, 0)``, so the wrench
``w = (f_T, τ_x, τ_y, τ_z)`` is linear in the thrusts (Mahony, Kumar & Corke 2012,
"Multirotor Aerial Vehicles", IEEE Robotics & Automation Magazine 19(3), eq. 6, written here in
FRD)::

    w = M T,   M = [[1, 1, 1, 1], [−y_i], [x_i], [d_i c]],   c = k_m / k_f (m).

Layouts (rotor numbering of the Crazyflie 2.x, seen from above, b1 up the page):

- ``x``: 1 front-right, 2 back-right, 3 back-left, 4 front-left, each at ``L/√2`` along
  both body axes (L = arm length from the centre of mass to the rotor axis);
- ``plus``: 1 front, 2 right, 3 back, 4 left, at L on one axis.

Rotors 1 and 3 spin counter-clockwise, 2 and 4 clockwise (the Crazyflie's M1–M4). In both
layouts the four rows of M are mutually orthogonal, so the inverse is exact in closed form:
``M⁻¹ = Mᵀ diag(1/‖m_k‖²)`` for rows m_k (no numerical inversion).

Rotor limits. ``ω ∈ [ω_min, ω_max]`` bounds each thrust to ``[k_f ω_min², k_f ω_max²]``. The
inverse mixer (:func:`allocate`) solves ``T = M⁻¹ w`` exactly when that fits, and otherwise
gives way in the order of what matters least for staying in the air (the priority of PX4's
multicopter mixer without "airmode"):

1. **Yaw first.** Yaw torque comes from the drag torques, ``c = k_m / k_f`` times the thrusts
   (0.016 m against a 0.225 m arm on the paper vehicle with 1000 rad/s rotors), so a yaw
   demand that roll and pitch would get at no cost needs large thrust differences; kept at
   any price it would take the collective thrust with it (two rotors at full speed and two at
   rest climb or fall whatever the thrust command).
   So the roll, pitch and thrust part ``T_0 = M⁻¹ (f_T, τ_x, τ_y, 0)`` is placed first and the
   yaw part ``τ_z u`` (``u`` the last column of M⁻¹) is added scaled by the largest
   ``s ∈ [0, 1]`` that keeps all four thrusts inside the limits: the yaw torque keeps its sign
   and shrinks, nothing else changes.
2. **Then the collective thrust**, if ``T_0`` itself does not fit: every torque row of M sums to
   zero, so adding the same δ to all four thrusts changes f_T alone, and the smallest such δ
   that brings all four inside is applied (a negative thrust asked for by a torque at low
   collective thrust raises the collective thrust; an above-max thrust lowers it).
3. Only when the roll and pitch demand alone spans more than the rotor range
   (``max T_0 − min T_0 > T_max − T_min``) is each thrust clipped to its limits after
   centring, which also distorts those torques (and no yaw is left).

Motor lag: each rotor's speed follows its command through a first-order lag
``ω̇ = (ω_cmd − ω)/τ_m``, integrated exactly over a substep h:
``ω ← ω_cmd + (ω − ω_cmd) e^{−h/τ_m}`` (:func:`motor_lag`).

Crazyflie 2.0 values (:data:`CRAZYFLIE2_ROTORS`) are those of Förster 2015, "System
Identification of the Crazyflie 2.0 Nano Quadrocopter", BSc thesis, ETH Zürich, as the
gym-pybullet-drones model ``cf2x.urdf`` documents them (Panerati et al. 2021): ``k_f =
3.16e-10 N/rpm²``, ``k_m = 7.94e-12 N·m/rpm²``, thrust-to-weight 2.25; converted here to
rad/s. The arm length 0.046 m (centre to rotor) is the thesis's; cf2x.urdf places the rotors
at 0.0397 m. The motor time constant 0.015 s is an assumed order of magnitude for the
Crazyflie's brushed coreless motors, not a value from the thesis.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from quadslam_env.models.jit import inline_kernel, kernel
from quadslam_env.types import GRAVITY, FloatArray

LAYOUTS = ("x", "plus")
"""Arm geometries: ``x`` (rotors between the body axes) and ``plus`` (rotors on them)."""

SPIN = (1.0, -1.0, 1.0, -1.0)
"""``d_i``: +1 counter-clockwise seen from above (rotors 1, 3), −1 clockwise (rotors 2, 4)."""

RPM = 2.0 * math.pi / 60.0
"""One revolution per minute in rad/s."""


def rotor_positions(layout: str, arm: float) -> FloatArray:
    """(4, 2) rotor positions ``(x_i, y_i)`` in B (FRD), m, for ``layout`` and arm length ``arm``.

    Raises:
        ValueError: Unknown layout (the message lists :data:`LAYOUTS`).
    """
    if layout == "x":
        a = arm / math.sqrt(2.0)
        return np.array([[a, a], [-a, a], [-a, -a], [a, -a]])
    if layout == "plus":
        return np.array([[arm, 0.0], [0.0, arm], [-arm, 0.0], [0.0, -arm]])
    raise ValueError(f"rotor layout: got {layout!r}; allowed: one of {list(LAYOUTS)}")


def mixer_matrix(layout: str, arm: float, k_f: float, k_m: float) -> FloatArray:
    """(4, 4) mixer M: rotor thrusts (N) → ``(f_T [N], τ_x, τ_y, τ_z [N·m])`` in B (FRD).

    Args:
        layout: ``x`` or ``plus``. arm: Centre-to-rotor distance L in m.
        k_f: Thrust coefficient in N/(rad/s)². k_m: Drag-torque coefficient in N·m/(rad/s)².
    """
    pos = rotor_positions(layout, arm)
    return np.array([[1.0] * 4, -pos[:, 1], pos[:, 0], np.array(SPIN) * (k_m / k_f)])


def mixer_inverse(mixer: FloatArray) -> FloatArray:
    """(4, 4) exact inverse ``Mᵀ diag(1/‖m_k‖²)`` of a mixer with orthogonal rows m_k.

    Raises:
        ValueError: The rows are not orthogonal (not a mixer of :func:`mixer_matrix`).
    """
    gram = mixer @ mixer.T
    norms = np.diag(gram).copy()
    if np.any(np.abs(gram - np.diag(norms)) > 1e-12 * norms.max()):
        raise ValueError("mixer_inverse: the mixer's rows are not orthogonal")
    return mixer.T / norms


@dataclass(frozen=True)
class RotorParams:
    """Four identical rotors on arms of one layout.

    Attributes:
        layout: ``x`` or ``plus`` (:data:`LAYOUTS`).
        arm: Centre-of-mass-to-rotor distance L in m.
        k_f: Thrust coefficient in N/(rad/s)² (``T = k_f ω²``).
        k_m: Drag-torque coefficient in N·m/(rad/s)² (``|τ| = k_m ω²``).
        motor_tau: Motor time constant τ_m of the rotor speed in s; 0 = instantaneous.
        omega_min: Lowest rotor speed in rad/s (idle), ≥ 0.
        omega_max: Highest rotor speed in rad/s.
        mixer: (4, 4) M of :func:`mixer_matrix`, derived.
        mixer_inv: (4, 4) exact M⁻¹, derived.
    """

    layout: str
    arm: float
    k_f: float
    k_m: float
    motor_tau: float
    omega_min: float
    omega_max: float
    mixer: FloatArray = field(init=False, repr=False)
    mixer_inv: FloatArray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        values = (self.arm, self.k_f, self.k_m, self.motor_tau, self.omega_min, self.omega_max)
        if not all(math.isfinite(v) and v >= 0.0 for v in values):
            raise ValueError(f"RotorParams: got {values}; allowed: finite numbers >= 0")
        if min(self.arm, self.k_f, self.k_m) <= 0.0 or self.omega_max <= self.omega_min:
            raise ValueError("RotorParams: arm, k_f and k_m must be > 0 and omega_max > omega_min")
        mixer = mixer_matrix(self.layout, self.arm, self.k_f, self.k_m)
        inv = mixer_inverse(mixer)
        mixer.setflags(write=False)
        inv.setflags(write=False)
        object.__setattr__(self, "mixer", mixer)
        object.__setattr__(self, "mixer_inv", inv)

    @property
    def thrust_min(self) -> float:
        """Lowest thrust of one rotor ``k_f ω_min²`` in N."""
        return self.k_f * self.omega_min**2

    @property
    def thrust_max(self) -> float:
        """Highest thrust of one rotor ``k_f ω_max²`` in N."""
        return self.k_f * self.omega_max**2

    @property
    def max_collective_thrust(self) -> float:
        """``4 k_f ω_max²`` in N: all rotors at full speed."""
        return 4.0 * self.thrust_max

    @property
    def max_torque(self) -> FloatArray:
        """(3,) largest torque per body axis in N·m with the rotors inside their limits:
        ``½ Σ_i |M_ki| (T_max − T_min)`` (half the rotors at the top, half at the bottom, at
        the collective thrust ``2 (T_min + T_max)``)."""
        return self._torque_per_thrust_step() * (0.5 * (self.thrust_max - self.thrust_min))

    def hover_torque(self, weight: float) -> FloatArray:
        """(3,) largest torque per body axis in N·m that keeps the collective thrust at
        ``weight`` N: ``Σ_i |M_ki| · min(T_max − T_h, T_h − T_min)`` with ``T_h = weight/4``.

        Each rotor moves by ±δ from ``T_h`` with the sign of its ``M_ki``; in both layouts the
        signs of a torque row balance, so the collective thrust stays, and δ stops at the first
        limit. This is all an attitude loop can count on while the vehicle holds its altitude
        (for yaw ``4c·min(…)`` with ``c = k_m/k_f``); :attr:`max_torque` needs the collective
        thrust half-way up the range. 0 where the rotors cannot carry the weight.
        """
        hover = 0.25 * weight
        step = max(0.0, min(self.thrust_max - hover, hover - self.thrust_min))
        return self._torque_per_thrust_step() * step

    def _torque_per_thrust_step(self) -> FloatArray:
        """(3,) ``Σ_i |M_ki|``: the torque in N·m per N when every rotor moves by 1 N with the
        sign of its entry in torque row k (m)."""
        return np.abs(self.mixer[1:]).sum(axis=1)

    def hover_speed(self, weight: float) -> float:
        """Rotor speed in rad/s at which four equal rotors carry ``weight`` N."""
        return math.sqrt(weight / (4.0 * self.k_f))


# k_f, k_m of cf2x.urdf in N/rpm² and N·m/rpm², thrust-to-weight 2.25, mass 0.027 kg.
_CF2_KF = 3.16e-10 / RPM**2
_CF2_OMEGA_MAX = math.sqrt(2.25 * 0.027 * GRAVITY / (4.0 * _CF2_KF))

CRAZYFLIE2_ROTORS = RotorParams(
    layout="x",
    arm=0.046,
    k_f=_CF2_KF,
    k_m=7.94e-12 / RPM**2,
    motor_tau=0.015,
    omega_min=0.0,
    omega_max=_CF2_OMEGA_MAX,
)
"""The Crazyflie 2.0's rotors (module docstring for the sources): ``k_f ≈ 2.88e-8
N/(rad/s)²``, ``k_m ≈ 7.24e-10 N·m/(rad/s)²``, ``ω_max ≈ 2274 rad/s``."""


# --------------------------------------------------------------------------------------------
# Kernels on one vehicle (lifted over lanes by the vehicle step of ``integrators``).
# --------------------------------------------------------------------------------------------


@inline_kernel
def allocate(
    wrench: tuple[float, float, float, float],
    mixer_inv: FloatArray,
    t_min: float,
    t_max: float,
    out: FloatArray,
) -> None:
    """Rotor thrusts ``out`` (4,) in N for a wrench ``(f_T, τ_x, τ_y, τ_z)`` (N, N·m, B frame).

    ``T = M⁻¹ w`` exactly when it lies in ``[t_min, t_max]``; otherwise the yaw torque gives
    way first, then the collective thrust (a common shift of all four, roll and pitch torques
    kept), and only a roll and pitch demand beyond the rotors' range is clipped (module
    docstring).
    """
    lo, hi = math.inf, -math.inf
    for i in range(4):
        t = mixer_inv[i, 0] * wrench[0] + mixer_inv[i, 1] * wrench[1] + mixer_inv[i, 2] * wrench[2]
        out[i] = t
        lo, hi = min(lo, t), max(hi, t)
    if lo < t_min or hi > t_max:  # roll, pitch and thrust alone do not fit
        shift = t_min - lo if lo < t_min else t_max - hi
        if hi - lo > t_max - t_min:  # cannot fit: centre the spread, then clip
            shift = 0.5 * (t_min + t_max) - 0.5 * (lo + hi)
        for i in range(4):
            out[i] = min(max(out[i] + shift, t_min), t_max)
    scale = 1.0  # the largest share of the yaw torque that keeps every thrust in its limits
    for i in range(4):
        yaw = mixer_inv[i, 3] * wrench[3]
        if yaw > 0.0:
            scale = min(scale, max(t_max - out[i], 0.0) / yaw)
        elif yaw < 0.0:
            scale = min(scale, min(t_min - out[i], 0.0) / yaw)
    for i in range(4):  # (the clip only removes rounding at the limit the scale stops on)
        out[i] = min(max(out[i] + scale * mixer_inv[i, 3] * wrench[3], t_min), t_max)


@inline_kernel
def motor_lag(speed: FloatArray, cmd: FloatArray, keep: float) -> None:
    """Exact first-order lag over one substep: ``ω ← ω_cmd + (ω − ω_cmd) keep`` for (4,) speeds
    in rad/s with ``keep = e^{−h/τ_m}`` (0: the speed jumps to the command)."""
    for i in range(4):
        speed[i] = cmd[i] + (speed[i] - cmd[i]) * keep


@inline_kernel
def rotor_wrench(
    speed: FloatArray, mixer: FloatArray, k_f: float
) -> tuple[float, float, float, float]:
    """``(f_T [N], τ_x, τ_y, τ_z [N·m])`` in B of rotor speeds (4,) rad/s: ``M (k_f ω²)``."""
    t0, t1 = k_f * speed[0] * speed[0], k_f * speed[1] * speed[1]
    t2, t3 = k_f * speed[2] * speed[2], k_f * speed[3] * speed[3]
    return (
        mixer[0, 0] * t0 + mixer[0, 1] * t1 + mixer[0, 2] * t2 + mixer[0, 3] * t3,
        mixer[1, 0] * t0 + mixer[1, 1] * t1 + mixer[1, 2] * t2 + mixer[1, 3] * t3,
        mixer[2, 0] * t0 + mixer[2, 1] * t1 + mixer[2, 2] * t2 + mixer[2, 3] * t3,
        mixer[3, 0] * t0 + mixer[3, 1] * t1 + mixer[3, 2] * t2 + mixer[3, 3] * t3,
    )


@kernel
def allocate_lanes(
    thrust: FloatArray,
    torque: FloatArray,
    mixer_inv: FloatArray,
    t_min: float,
    t_max: float,
    out: FloatArray,
) -> None:
    """:func:`allocate` of B lanes: thrust (B,) N, torque (B, 3) N·m → rotor thrusts (B, 4) N."""
    for i in range(thrust.shape[0]):
        w = (thrust[i], torque[i, 0], torque[i, 1], torque[i, 2])
        allocate(w, mixer_inv, t_min, t_max, out[i])
