"""Strapdown process model of EKF-SLAM (seed 001 eq. 24–28), compiled with numba.

The vehicle state is ``s = (ρ [m, N], v_B [m/s, B], Λ = (φ, θ, ψ) [rad])`` (seed 001 eq. 21)
and the input the IMU-derived ``λ = (a_z, ω)`` (eq. 25): the specific force along b3 in m/s²
(``-g`` in hover) and the body rates ``ω = (p, q, r)`` in rad/s. The process (eq. 24) is

    ρ̇ = C_NB v,    v̇ = -ω×v + C_NBᵀ g n3 + a_z b3,    Λ̇ = D(Λ) ω,

which are the kinematic rows of the rigid body (eq. 2) with the specific force ``a_z b3`` and
ω held as an input. So the derivative and its RK4 step are those of
:mod:`quadslam_env.models.rigid_body` (``kinematics``, ``rk4_step`` with ``hold_rates``) on the
12-vector ``y = (s, ω)``; this module adds what only the filter needs, the analytic Jacobians
``F = ∂f/∂s`` (eq. 28) and ``G = ∂f/∂λ``, and NumPy-facing wrappers for tests.

**The whole specific force.** Eq. 25 keeps only the accelerometer's z axis, so a horizontal
specific force (rotor and body drag: ``−c v_air`` along b1, b2) is read as gravity tilted into
the body, i.e. as an attitude error. The textbook strapdown mechanisation in body-frame velocity
(Groves 2013, *Principles of GNSS, Inertial, and Multisensor Integrated Navigation Systems*,
§5.4, resolved in B) takes all three axes, ``λ = (a_z, ω, a_x, a_y)``:

    v̇ = -ω×v + C_NBᵀ g n3 + (a_x, a_y, a_z),

the same rigid-body rows with the full measured specific force as the input. ``F`` does not
change; ``G`` gains the columns ``∂v̇/∂a_x = b1`` and ``∂v̇/∂a_y = b2``. The column order keeps
eq. 25's four first, so the thrust-axis model is the first four columns of the full one.

**Drag and wind** (EKF-SLAM's ``wind: estimate``; Leishman, Macdonald, Beard & McLain 2014,
"Quadrotors and accelerometers: state estimation with an improved dynamic model", IEEE Control
Systems 34(1), the rotor-drag model). The thrust-axis model keeps ``a_z`` as the input and adds
the vehicle's drag on the body's horizontal axes, on the velocity relative to a horizontal wind
``w = (w_N, w_E, 0)``:

    v̇ = -ω×v + C_NBᵀ g n3 + a_z b3 + P_xy d(v_a),    v_a = v − C_NBᵀ w,

with ``d(v_a) = −μ v_a − c_q ∘ (‖v_a‖ v_a)`` the drag of
:func:`~quadslam_env.models.rigid_body.aero_specific_force` (the truth's drag kernel; with
``c_q = 0``, ``−μ v_a``) and ``P_xy`` the selection of b1, b2. The same term is what the
accelerometer's horizontal axes read, ``(a_x, a_y) = P_xy d(v_a)`` (+ bias, noise): the
measurement of :func:`drag_measurement`. :func:`drag_jacobians` gives its Jacobian over
``(v, Λ, w_N, w_E)``, which is both the drag rows of ``F`` and the measurement's ``H``.
"""

from __future__ import annotations

import math

import numpy as np

from quadslam_env.models.frames import dcm_and_partials, dcm_from_trig
from quadslam_env.models.jit import inline_kernel, kernel
from quadslam_env.models.rigid_body import (
    NO_AIR,
    Vec3,
    Vec9,
    aero_specific_force,
    air_velocity_body,
    kinematics,
    kinematics_dcm,
    pack_bodies,
    rk4_stages,
    rk4_step,
)
from quadslam_env.types import GRAVITY, POSE_DIM, FloatArray

_EYE = np.eye(3)[None]
_BODY = pack_bodies(1.0, 0.0, _EYE, _EYE)[0]
"""Unit mass, no drag: with zero thrust the rigid body's specific force is the input alone."""
_NO_CQ = np.zeros(3)

DragArgs = tuple[float, float, float, float, Vec3]
"""``(a_z [m/s²], w_N, w_E [m/s], μ [1/s], c_q (3) [1/m])``: the drag model's held inputs."""


@kernel
def strapdown_rk4(
    y: FloatArray, accel_x: float, accel_y: float, accel_z: float, dt: float, work: FloatArray
) -> None:
    """One classical RK4 step of eq. 24 with the input λ held over ``dt`` (eq. 26).

    Args:
        y: (12,) ``(s, ω)``: the state s (9,) is advanced in place, ω (rad/s) is the held
            input. Angles are not wrapped.
        accel_x, accel_y: Specific force along b1 and b2 in m/s² (0 in eq. 25's model).
        accel_z: Specific force along b3 in m/s².
        dt: Step in s.
        work: (6, 12) scratch (RK4 stages, stage state, input vector).
    """
    u = work[5, :7]
    u[:] = 0.0
    # input (f_T, τ, a) of the rigid body: only the extra specific force a (B)
    u[4], u[5], u[6] = accel_x, accel_y, accel_z
    rk4_step(y, u, _BODY, True, dt, work[:5], NO_AIR, False)


@kernel
def strapdown_jacobians(
    s: FloatArray, p: float, q: float, r: float, F: FloatArray, G: FloatArray
) -> None:
    """Analytic Jacobians of eq. 24: ``F = ∂f_s/∂s`` (eq. 28) and ``G = ∂f_s/∂λ``.

    The specific force enters f_s linearly, so neither Jacobian depends on it.

    Args:
        s: (≥9,) state (ρ [m, N], v_B [m/s, B], Λ [rad]) in its first 9 entries.
        p: Body rate about b1 in rad/s.
        q: Body rate about b2 in rad/s.
        r: Body rate about b3 in rad/s.
        F: (9, 9) receives ∂f_s/∂s (every entry is written).
        G: (9, 4) receives ∂f_s/∂λ for λ = (a_z, p, q, r), or (9, 6) for the whole specific
            force λ = (a_z, p, q, r, a_x, a_y) (every entry is written).
    """
    u, v, w = s[3], s[4], s[5]
    cf, sf = math.cos(s[6]), math.sin(s[6])
    ct, st = math.cos(s[7]), math.sin(s[7])
    c00, c01, c02, c10, c11, c12, c20, c21, c22 = dcm_from_trig(
        cf, sf, ct, st, math.cos(s[8]), math.sin(s[8])
    )
    g = GRAVITY
    xd = c00 * u + c01 * v + c02 * w
    yd = c10 * u + c11 * v + c12 * w
    # ∂C/∂φ v = C (e1 × v); ∂C/∂θ v = C ((C1ᵀ e2) × v); ∂C/∂ψ v = e3 × (C v).
    e0, e1, e2 = cf * w + sf * v, -sf * u, -cf * u
    sec = 1.0 / ct
    tt = st * sec
    a = sf * q + cf * r
    b = cf * q - sf * r
    F[:, :] = 0.0
    F[0, 3], F[0, 4], F[0, 5] = c00, c01, c02
    F[1, 3], F[1, 4], F[1, 5] = c10, c11, c12
    F[2, 3], F[2, 4], F[2, 5] = c20, c21, c22
    F[0, 6], F[0, 7], F[0, 8] = c02 * v - c01 * w, c00 * e0 + c01 * e1 + c02 * e2, -yd
    F[1, 6], F[1, 7], F[1, 8] = c12 * v - c11 * w, c10 * e0 + c11 * e1 + c12 * e2, xd
    F[2, 6], F[2, 7] = c22 * v - c21 * w, c20 * e0 + c21 * e1 + c22 * e2
    F[3, 4], F[3, 5], F[3, 7] = r, -q, -g * ct
    F[4, 3], F[4, 5], F[4, 6], F[4, 7] = -r, p, g * c22, -g * sf * st
    F[5, 3], F[5, 4], F[5, 6], F[5, 7] = q, -p, -g * c21, -g * cf * st
    F[6, 6], F[6, 7] = b * tt, a * sec * sec
    F[7, 6] = -a
    F[8, 6], F[8, 7] = b * sec, a * tt * sec
    G[:, :] = 0.0
    G[3, 2], G[3, 3] = -w, v
    G[4, 1], G[4, 3] = w, -u
    G[5, 0], G[5, 1], G[5, 2] = 1.0, -v, u
    G[6, 1], G[6, 2], G[6, 3] = 1.0, sf * tt, cf * tt
    G[7, 2], G[7, 3] = cf, -sf
    G[8, 2], G[8, 3] = sf * sec, cf * sec
    if G.shape[1] > 4:
        G[3, 4], G[4, 5] = 1.0, 1.0


@inline_kernel
def horizontal_drag(
    y: FloatArray, c: Vec9, wn: float, we: float, mu: float, cq: Vec3
) -> tuple[float, float]:
    """``P_xy d(v_a)``: the drag along b1 and b2 in m/s² of the state ``y`` (≥6,; v from
    ``y[VEL]``) with ``C_NB`` ``c`` (row-major) in the horizontal wind ``(wn, we)`` (m/s, N),
    for the linear drag ``mu`` (1/s) and the quadratic ``cq`` (3,) (1/m)
    (:func:`~quadslam_env.models.rigid_body.aero_specific_force` on ``v − C_NBᵀ w``)."""
    va = air_velocity_body(y, c, wn, we, 0.0)
    f = aero_specific_force(va[0], va[1], va[2], 0.0, 1.0, mu, cq)
    return f[0], f[1]


@inline_kernel
def _drag_derivative(y: FloatArray, args: DragArgs, out: FloatArray) -> None:
    """Rows ρ̇, v̇, Λ̇ of the drag model (module docstring) for ``y = (s, ω)`` into ``out[:9]``,
    with ``args = (a_z, w_N, w_E, μ, c_q)`` (as :func:`strapdown_drag_rk4` takes them)."""
    accel_z, wn, we, mu, cq = args
    cf, sf = math.cos(y[6]), math.sin(y[6])
    ct, st = math.cos(y[7]), math.sin(y[7])
    c = dcm_from_trig(cf, sf, ct, st, math.cos(y[8]), math.sin(y[8]))
    d = horizontal_drag(y, c, wn, we, mu, cq)
    kinematics_dcm(y, c, (cf, sf, ct, st), (d[0], d[1], accel_z), out)


@kernel
def strapdown_drag_rk4(
    y: FloatArray,
    accel_z: float,
    wn: float,
    we: float,
    mu: float,
    cq: Vec3,
    dt: float,
    work: FloatArray,
) -> None:
    """One classical RK4 step of the drag model with λ = (a_z, ω) and the wind held over ``dt``.

    :func:`~quadslam_env.models.rigid_body.rk4_stages` on ``ṡ = f_s(s, λ) + P_xy d(v_a)``
    (module docstring), ω held.

    Args:
        y: (12,) ``(s, ω)``: s (9,) is advanced in place, ω (rad/s) is the held input.
        accel_z: Specific force along b3 in m/s².
        wn, we: Wind north and east in m/s (N); w_D = 0.
        mu: Linear drag in 1/s. cq: (3,) quadratic drag per body axis in 1/m.
        dt: Step in s.
        work: (≥5, 12) scratch.
    """
    rk4_stages(_drag_derivative, (accel_z, wn, we, mu, cq), y, POSE_DIM, dt, work)


@kernel
def drag_jacobians(
    s: FloatArray,
    wn: float,
    we: float,
    mu: float,
    cq: Vec3,
    C: FloatArray,
    dC: FloatArray,
    D: FloatArray,
) -> None:
    """``D = ∂(P_xy d(v_a))/∂(v, Λ, w_N, w_E)`` (2, 8): the drag rows of F and the H of the
    horizontal accelerometer axes (module docstring).

    With ``J = ∂d/∂v_a`` (rows b1, b2): ``J_ij = −μ δ_ij − c_q,i (‖v_a‖ δ_ij + v_a,i v_a,j /
    ‖v_a‖)``; ``∂v_a/∂v = I``, ``∂v_a/∂Λ_k = −(∂C_NB/∂Λ_k)ᵀ w``, ``∂v_a,j/∂w_m = −C_NB[m, j]``.

    Args:
        s: (≥9,) state (ρ [m, N], v_B [m/s, B], Λ [rad]) in its first 9 entries.
        wn, we: Wind north and east in m/s (N).
        mu: Linear drag in 1/s. cq: (3,) quadratic drag per body axis in 1/m.
        C: (3, 3) and dC: (3, 3, 3) scratch (receive C_NB and its partials).
        D: (2, 8) receives the Jacobian (columns v (3), Λ (3), w_N, w_E; m/s² per unit).
    """
    dcm_and_partials(s[6], s[7], s[8], C, dC)
    c = (C[0, 0], C[0, 1], C[0, 2], C[1, 0], C[1, 1], C[1, 2], C[2, 0], C[2, 1], C[2, 2])
    va = air_velocity_body(s, c, wn, we, 0.0)
    speed = math.sqrt(va[0] * va[0] + va[1] * va[1] + va[2] * va[2])
    inv = 1.0 / speed if speed > 0.0 else 0.0
    for i in range(2):
        for j in range(3):
            D[i, j] = -cq[i] * va[i] * va[j] * inv
        D[i, i] -= mu + cq[i] * speed
        for k in range(3):
            acc = 0.0
            for j in range(3):
                acc -= D[i, j] * (dC[k, 0, j] * wn + dC[k, 1, j] * we)
            D[i, 3 + k] = acc
        for m in range(2):
            D[i, 6 + m] = -(D[i, 0] * C[m, 0] + D[i, 1] * C[m, 1] + D[i, 2] * C[m, 2])


def process_derivative(
    s: FloatArray, accel_z: float, gyro: FloatArray, accel_xy: tuple[float, float] = (0.0, 0.0)
) -> FloatArray:
    """Process model ``ṡ = f_s(s, λ)`` of seed 001 eq. 24 (noise-free).

    ``ρ̇ = C_NB v``, ``v̇ = -ω×v + C_NBᵀ g n3 + a``, ``Λ̇ = D(Λ) ω`` with
    ``a = (a_x, a_y, a_z)`` (eq. 25: ``a_x = a_y = 0``).

    Args:
        s: (9,) vehicle state (ρ [m, N], v_B [m/s, B], Λ [rad]).
        accel_z: Bias-corrected specific force along b3 in m/s² (``-g`` in hover).
        gyro: (3,) bias-corrected body rates ω in rad/s.
        accel_xy: Bias-corrected specific force along b1 and b2 in m/s² (the whole specific
            force; 0 for eq. 25).

    Returns:
        (9,) time derivative of s.
    """
    y = np.concatenate((np.asarray(s, dtype=float), np.asarray(gyro, dtype=float)))
    out = np.empty(POSE_DIM)
    kinematics(y, (float(accel_xy[0]), float(accel_xy[1]), float(accel_z)), out)
    return out


def process_jacobians(
    s: FloatArray, accel_z: float, gyro: FloatArray, full: bool = False
) -> tuple[FloatArray, FloatArray]:
    """Analytic Jacobians of :func:`process_derivative` (seed 001 eq. 28).

    Args:
        s: (9,) vehicle state.
        accel_z: Specific force along b3 in m/s² (does not enter the Jacobians).
        gyro: (3,) body rates in rad/s.
        full: The whole specific force's ``G`` (9, 6) instead of eq. 25's (9, 4).

    Returns:
        ``(F, G)``: ``F = ∂f_s/∂s`` (9, 9) and ``G = ∂f_s/∂λ`` (9, 4) for ``λ = (a_z, ω)``
        ((9, 6) for ``λ = (a_z, ω, a_x, a_y)`` when ``full``). With bias states and
        ``λ = λ̃ - b``, ``∂f/∂b = -G`` column by column.
    """
    del accel_z
    F = np.empty((POSE_DIM, POSE_DIM))
    G = np.empty((POSE_DIM, 6 if full else 4))
    p, q, r = (float(c) for c in gyro)
    strapdown_jacobians(np.ascontiguousarray(s, dtype=float), p, q, r, F, G)
    return F, G


def _wind_args(wind_ne: FloatArray, cq: FloatArray) -> tuple[float, float, Vec3]:
    """(w_N, w_E) and c_q as the kernels take them."""
    wn, we = (float(v) for v in np.asarray(wind_ne, dtype=float).reshape(2))
    q0, q1, q2 = (float(v) for v in np.asarray(cq, dtype=float).reshape(3))
    return wn, we, (q0, q1, q2)


def drag_process_derivative(
    s: FloatArray,
    accel_z: float,
    gyro: FloatArray,
    wind_ne: FloatArray,
    mu: float,
    cq: FloatArray = _NO_CQ,
) -> FloatArray:
    """``ṡ`` of the drag model (module docstring; noise-free, bias-corrected inputs).

    Args:
        s: (9,) vehicle state. accel_z: Specific force along b3 in m/s².
        gyro: (3,) body rates in rad/s. wind_ne: (2,) wind (w_N, w_E) in m/s.
        mu: Linear drag in 1/s. cq: (3,) quadratic drag per body axis in 1/m.

    Returns:
        (9,) time derivative of s.
    """
    y = np.concatenate((np.asarray(s, dtype=float), np.asarray(gyro, dtype=float)))
    out = np.empty(12)
    wn, we, q = _wind_args(wind_ne, cq)
    _drag_derivative(y, (float(accel_z), wn, we, float(mu), q), out)
    return out[:POSE_DIM]


def drag_measurement(
    s: FloatArray, wind_ne: FloatArray, mu: float, cq: FloatArray = _NO_CQ
) -> tuple[FloatArray, FloatArray]:
    """The horizontal accelerometer axes' model ``P_xy d(v_a)`` (2,) in m/s² and its Jacobian
    (2, 8) over (v, Λ, w_N, w_E) (:func:`drag_jacobians`), for a (9,) state and (2,) wind."""
    s = np.ascontiguousarray(s, dtype=float)
    wn, we, q = _wind_args(wind_ne, cq)
    D = np.empty((2, 8))
    drag_jacobians(s, wn, we, float(mu), q, np.empty((3, 3)), np.empty((3, 3, 3)), D)
    c = dcm_from_trig(
        math.cos(s[6]), math.sin(s[6]), math.cos(s[7]), math.sin(s[7]),
        math.cos(s[8]), math.sin(s[8]),
    )  # fmt: skip
    return np.array(horizontal_drag(s, c, wn, we, float(mu), q)), D
