"""LiDAR range–bearing model, its inverse and analytic Jacobians (seed 001 §2.3.3–2.3.4).

A measurement of landmark ``l`` from pose ``(ρ, Λ)`` is ``y = (α, β, δ)``:
``c = C_NBᵀ (l - ρ)`` (landmark in the body frame, FRD),
``α = atan2(c2, c1)`` (azimuth, positive to the right),
``β = atan2(c3, √(c1² + c2²))`` (elevation, positive *below* the horizon since b3 points down),
``δ = ‖c‖`` (range). Seed 001 eq. 31 lists the azimuth as ``atan(c1/c2)``; docs/design.md §3
fixes it.
The inverse (eq. 44–45) is ``l = ρ + C_NB ϱ(y)`` with ``ϱ = δ (cβ cα, cβ sα, sβ)``.

The model is written once, per landmark, as numba kernels: :func:`spherical_from_body` and
:func:`spherical_jacobian` (``h(c)``, ``∂h/∂c``), :func:`body_from_spherical` and
:func:`body_from_spherical_jacobian` (``ϱ(y)``, ``∂ϱ/∂y``), composed into
:func:`observe_landmark`, :func:`lidar_model` and :func:`lidar_inverse_model` (one landmark
from one pose, with the Jacobians of eq. 40 and 49), which filter kernels (EKF-SLAM lanes,
FastSLAM landmark EKFs) call inside their loops.

The NumPy-facing functions below evaluate the same kernels as gufuncs
(:func:`~quadslam_env.models.jit.generalized`): they broadcast over leading dimensions, so one
call evaluates B vehicles × L landmarks (the simulator's LiDAR) or N particles × k landmarks
(FastSLAM) in one compiled loop. Angles are in rad, lengths in m; ρ, l in N (NED), c in B (FRD).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from quadslam_env.models.frames import dcm_euler_partials, wrap_angle
from quadslam_env.models.jit import generalized, kernel
from quadslam_env.types import FloatArray

Vec3 = tuple[float, float, float]
Mat3 = tuple[Vec3, Vec3, Vec3]

# ------------------------------------------------------------------ per-landmark kernels


@kernel
def spherical_from_body(c1: float, c2: float, c3: float) -> Vec3:
    """``h(c) = (atan2(c2, c1), atan2(c3, ‖c_12‖), ‖c‖)`` (seed 001 eq. 31, azimuth corrected).

    Args:
        c1, c2, c3: Landmark in the body frame (FRD), m.

    Returns:
        ``(α rad, β rad, δ m)``.
    """
    horiz = math.hypot(c1, c2)
    return math.atan2(c2, c1), math.atan2(c3, horiz), math.sqrt(horiz * horiz + c3 * c3)


@kernel
def spherical_jacobian(c1: float, c2: float, c3: float) -> Mat3:
    """Rows of ``∂(α, β, δ)/∂c`` at the body-frame vector ``c`` in m (eq. 40, ``∂h/∂c`` factor).

    The squared horizontal distance is floored at 1e-12 m²: the azimuth is undefined straight
    above/below (c1 = c2 = 0), which a 360° LiDAR can see.

    Returns:
        ``((∂α/∂c), (∂β/∂c), (∂δ/∂c))``, each a row of three, in rad/m and m/m.
    """
    h2 = max(c1 * c1 + c2 * c2, 1e-12)
    h = math.sqrt(h2)
    d2 = h2 + c3 * c3
    d = math.sqrt(d2)
    return (
        (-c2 / h2, c1 / h2, 0.0),
        (-c1 * c3 / (d2 * h), -c2 * c3 / (d2 * h), h / d2),
        (c1 / d, c2 / d, c3 / d),
    )


@kernel
def body_from_spherical(alpha: float, beta: float, delta: float) -> Vec3:
    """``ϱ(y) = δ (cβ cα, cβ sα, sβ)`` (seed 001 eq. 45): the landmark in B, m, from y."""
    cb = math.cos(beta)
    return delta * cb * math.cos(alpha), delta * cb * math.sin(alpha), delta * math.sin(beta)


@kernel
def body_from_spherical_jacobian(alpha: float, beta: float, delta: float) -> Mat3:
    """Rows of ``∂ϱ/∂y`` (seed 001 eq. 50, body-frame part) at ``y = (α rad, β rad, δ m)``.

    Returns:
        Rows ``(∂ϱ_a/∂α, ∂ϱ_a/∂β, ∂ϱ_a/∂δ)`` for a = 1, 2, 3, in m/rad and m/m (B frame).
    """
    ca, sa, cb, sb = math.cos(alpha), math.sin(alpha), math.cos(beta), math.sin(beta)
    return (
        (-delta * cb * sa, -delta * sb * ca, cb * ca),
        (delta * cb * ca, -delta * sb * sa, cb * sa),
        (0.0, delta * cb, sb),
    )


@kernel
def _to_body(C: FloatArray, d0: float, d1: float, d2: float) -> Vec3:
    """``Cᵀ d`` for a (3, 3) matrix ``C`` (``C_NB`` or one of its partials) and d in N."""
    return (
        C[0, 0] * d0 + C[1, 0] * d1 + C[2, 0] * d2,
        C[0, 1] * d0 + C[1, 1] * d1 + C[2, 1] * d2,
        C[0, 2] * d0 + C[1, 2] * d1 + C[2, 2] * d2,
    )


@kernel
def _to_inertial(
    pos: FloatArray, C: FloatArray, r0: float, r1: float, r2: float, out: FloatArray
) -> None:
    """``out = ρ + C_NB ϱ`` (eq. 44) for ρ (3,) in N and ϱ in B."""
    for a in range(3):
        out[a] = pos[a] + (C[a, 0] * r0 + C[a, 1] * r1 + C[a, 2] * r2)


@kernel
def measure_landmark(pos: FloatArray, C: FloatArray, lm: FloatArray) -> Vec3:
    """Noise-free measurement (α rad, β rad, δ m) of one landmark ``lm`` (3,) in N, m from a
    vehicle at ``pos`` (3,) with ``C_NB`` = ``C`` (3, 3) (seed 001 eq. 30–31)."""
    c1, c2, c3 = _to_body(C, lm[0] - pos[0], lm[1] - pos[1], lm[2] - pos[2])
    return spherical_from_body(c1, c2, c3)


@kernel
def observe_landmark(
    pos: FloatArray, C: FloatArray, lm: FloatArray, h: FloatArray, H_lm: FloatArray
) -> tuple[Vec3, Mat3]:
    """Predicted measurement of one landmark and its landmark Jacobian (seed 001 eq. 31, 40).

    The forward model for filter kernels that need only ``∂h/∂l`` (FastSLAM's landmark EKFs);
    :func:`lidar_model` adds the pose Jacobians.

    Args:
        pos: (3,) ρ in N, m.
        C: (3, 3) ``C_NB``.
        lm: (3,) landmark position l in N, m.
        h: (3,) receives (α rad, β rad, δ m).
        H_lm: (3, 3) receives ``∂h/∂l = (∂h/∂c) C_NBᵀ`` (= ``-∂h/∂ρ``).

    Returns:
        ``(l − ρ, ∂h/∂c)``: the offset in N, m and the rows of :func:`spherical_jacobian`,
        for the rest of the chain rule.
    """
    d = (lm[0] - pos[0], lm[1] - pos[1], lm[2] - pos[2])
    c1, c2, c3 = _to_body(C, d[0], d[1], d[2])
    h[0], h[1], h[2] = spherical_from_body(c1, c2, c3)
    jac = spherical_jacobian(c1, c2, c3)
    for r in range(3):
        j0, j1, j2 = jac[r]
        for a in range(3):
            H_lm[r, a] = j0 * C[a, 0] + j1 * C[a, 1] + j2 * C[a, 2]
    return d, jac


@kernel
def lidar_model(
    pos: FloatArray, C: FloatArray, dC: FloatArray, lm: FloatArray, h: FloatArray, H: FloatArray
) -> None:
    """Predicted measurement of one landmark and its Jacobian (seed 001 eq. 30–31, 40).

    Args:
        pos: (3,) ρ in N, m.
        C: (3, 3) ``C_NB(Λ)``.
        dC: (3, 3, 3) ``∂C_NB/∂Λ_i`` (:func:`~quadslam_env.models.frames.dcm_and_partials`).
        lm: (3,) landmark position in N, m.
        h: (3,) receives (α rad, β rad, δ m).
        H: (3, 9) receives ``[∂h/∂ρ, ∂h/∂Λ, ∂h/∂l]`` (∂h/∂v is zero); ``∂c/∂ρ = -C_NBᵀ``,
            ``∂c/∂Λ_a = (∂C/∂Λ_a)ᵀ (l - ρ)``.
    """
    d, jac = observe_landmark(pos, C, lm, h, H[:, 6:9])
    e = (
        _to_body(dC[0], d[0], d[1], d[2]),
        _to_body(dC[1], d[0], d[1], d[2]),
        _to_body(dC[2], d[0], d[1], d[2]),
    )
    for r in range(3):
        j0, j1, j2 = jac[r]
        for a in range(3):
            H[r, a] = -H[r, 6 + a]
            H[r, 3 + a] = j0 * e[a][0] + j1 * e[a][1] + j2 * e[a][2]


@kernel
def lidar_inverse_model(
    pos: FloatArray,
    C: FloatArray,
    dC: FloatArray,
    y: FloatArray,
    lm: FloatArray,
    G_eul: FloatArray,
    G_y: FloatArray,
) -> None:
    """Inverse model ``l = g(s, y) = ρ + C_NB ϱ(y)`` and its Jacobians (eq. 44–45, 49–50).

    Args:
        pos: (3,) ρ in N, m.
        C: (3, 3) ``C_NB(Λ)``.
        dC: (3, 3, 3) ``∂C_NB/∂Λ_i``.
        y: (3,) measurement (α rad, β rad, δ m).
        lm: (3,) receives the landmark position in N, m.
        G_eul: (3, 3) receives ``∂g/∂Λ`` in m/rad (``∂g/∂ρ = I``, ``∂g/∂v = 0``).
        G_y: (3, 3) receives ``∂g/∂y = C_NB ∂ϱ/∂y``.
    """
    r0, r1, r2 = body_from_spherical(y[0], y[1], y[2])
    D = body_from_spherical_jacobian(y[0], y[1], y[2])
    _to_inertial(pos, C, r0, r1, r2, lm)
    for a in range(3):
        for i in range(3):
            G_eul[a, i] = dC[i, a, 0] * r0 + dC[i, a, 1] * r1 + dC[i, a, 2] * r2
            G_y[a, i] = C[a, 0] * D[0][i] + C[a, 1] * D[1][i] + C[a, 2] * D[2][i]


@kernel
def lidar_models(
    pos: FloatArray, C: FloatArray, dC: FloatArray, lms: FloatArray, h: FloatArray, H: FloatArray
) -> None:
    """:func:`lidar_model` of k landmarks ``lms`` (k, 3) into ``h`` (k, 3) and ``H`` (k, 3, 9)."""
    for i in range(lms.shape[0]):
        lidar_model(pos, C, dC, lms[i], h[i], H[i])


@kernel
def lidar_inverse_models(
    pos: FloatArray,
    C: FloatArray,
    dC: FloatArray,
    y: FloatArray,
    lms: FloatArray,
    G_eul: FloatArray,
    G_y: FloatArray,
) -> None:
    """:func:`lidar_inverse_model` of k measurements ``y`` (k, 3) into ``lms`` (k, 3) and
    ``G_eul``, ``G_y`` (k, 3, 3)."""
    for i in range(y.shape[0]):
        lidar_inverse_model(pos, C, dC, y[i], lms[i], G_eul[i], G_y[i])


# ---------------------------------------------------- gufuncs: the kernels over leading axes
_POSE_LM = "(n),(n,n),(n)"


@generalized("void(f8[:], f8[:, :], f8[:], f8[:])", _POSE_LM + "->(n)")
def _body_vector(pos: FloatArray, C: FloatArray, lm: FloatArray, out: FloatArray) -> None:
    out[0], out[1], out[2] = _to_body(C, lm[0] - pos[0], lm[1] - pos[1], lm[2] - pos[2])


@generalized("void(f8[:], f8[:])", "(n)->(n)")
def _measure_from_body(c: FloatArray, out: FloatArray) -> None:
    out[0], out[1], out[2] = spherical_from_body(c[0], c[1], c[2])


@generalized("void(f8[:], f8[:, :], f8[:], f8[:])", _POSE_LM + "->(n)")
def _lidar_measure(pos: FloatArray, C: FloatArray, lm: FloatArray, out: FloatArray) -> None:
    out[0], out[1], out[2] = measure_landmark(pos, C, lm)


@generalized("void(f8[:], f8[:, :], f8[:], f8[:], f8[:, :])", _POSE_LM + "->(n),(n,n)")
def _lidar_measure_jacobian(
    pos: FloatArray, C: FloatArray, lm: FloatArray, h: FloatArray, H_lm: FloatArray
) -> None:
    observe_landmark(pos, C, lm, h, H_lm)


@generalized("void(f8[:], f8[:, :])", "(n)->(n,n)")
def _measure_jacobian_body(c: FloatArray, out: FloatArray) -> None:
    jac = spherical_jacobian(c[0], c[1], c[2])
    for r in range(3):
        out[r, 0], out[r, 1], out[r, 2] = jac[r]


@generalized("void(f8[:], f8[:])", "(n)->(n)")
def _body_from_measure(y: FloatArray, out: FloatArray) -> None:
    out[0], out[1], out[2] = body_from_spherical(y[0], y[1], y[2])


@generalized("void(f8[:], f8[:, :], f8[:], f8[:])", _POSE_LM + "->(n)")
def _lidar_inverse(pos: FloatArray, C: FloatArray, y: FloatArray, out: FloatArray) -> None:
    r0, r1, r2 = body_from_spherical(y[0], y[1], y[2])
    _to_inertial(pos, C, r0, r1, r2, out)


@generalized("void(f8[:], f8[:, :])", "(n)->(n,n)")
def _measure_inverse_jacobian(y: FloatArray, out: FloatArray) -> None:
    D = body_from_spherical_jacobian(y[0], y[1], y[2])
    for r in range(3):
        out[r, 0], out[r, 1], out[r, 2] = D[r]


def _xyz(a: ArrayLike) -> FloatArray:
    """``a`` as a float array with a last axis of length 3 (the kernels' core dimension)."""
    arr = np.asarray(a, dtype=float)
    if arr.shape[-1:] != (3,):
        raise ValueError(f"LiDAR model: expected an array of shape (..., 3), got {arr.shape}")
    return arr


# ------------------------------------------------------------------ NumPy-facing functions
def body_vector(pos: FloatArray, dcm: FloatArray, landmarks: FloatArray) -> FloatArray:
    """Landmark positions in the body frame, ``c = C_NBᵀ (l - ρ)`` (seed 001 eq. 31).

    Args:
        pos: (..., 3) vehicle position ρ in N, m.
        dcm: (..., 3, 3) ``C_NB``.
        landmarks: (..., 3) landmark positions l in N, m.

    Returns:
        (..., 3) vectors c in B, m (leading axes broadcast).
    """
    return _body_vector(pos, dcm, _xyz(landmarks))


def measure_from_body(c: FloatArray) -> FloatArray:
    """Spherical coordinates ``(α rad, β rad, δ m)`` (eq. 31) of body-frame vectors c (..., 3)."""
    return _measure_from_body(_xyz(c))


def lidar_measure(pos: FloatArray, dcm: FloatArray, landmarks: FloatArray) -> FloatArray:
    """Noise-free LiDAR measurement ``h_o(s, l)`` (seed 001 eq. 30–31, azimuth corrected).

    Args:
        pos: (..., 3) vehicle position in N, m.
        dcm: (..., 3, 3) ``C_NB``.
        landmarks: (..., 3) landmark positions in N, m.

    Returns:
        (..., 3) measurements (α rad, β rad, δ m) (leading axes broadcast).
    """
    return _lidar_measure(pos, dcm, _xyz(landmarks))


def lidar_measure_jacobian(
    pos: FloatArray, dcm: FloatArray, landmarks: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Measurement and its landmark Jacobian in one pass (seed 001 eq. 31, 40).

    Args:
        pos: (..., 3) vehicle position in N, m.
        dcm: (..., 3, 3) ``C_NB``.
        landmarks: (..., 3) landmark positions in N, m.

    Returns:
        ``(h, H_lm)`` of shapes (..., 3) and (..., 3, 3): (α rad, β rad, δ m) and
        ``∂h/∂l = (∂h/∂c) C_NBᵀ`` (equal to ``-∂h/∂ρ``), leading axes broadcast.
    """
    return _lidar_measure_jacobian(pos, dcm, _xyz(landmarks))


def body_from_measure(meas: FloatArray) -> FloatArray:
    """``ϱ(y) = δ (cβ cα, cβ sα, sβ)`` (seed 001 eq. 45), (..., 3) → (..., 3) in B, m."""
    return _body_from_measure(_xyz(meas))


def lidar_inverse(pos: FloatArray, dcm: FloatArray, meas: FloatArray) -> FloatArray:
    """Inverse model ``l = g(s, y) = ρ + C_NB ϱ(y)`` (seed 001 eq. 44).

    Args:
        pos: (..., 3) vehicle position in N, m.
        dcm: (..., 3, 3) ``C_NB``.
        meas: (..., 3) measurements (α rad, β rad, δ m).

    Returns:
        (..., 3) landmark positions in N, m (leading axes broadcast).
    """
    return _lidar_inverse(pos, dcm, _xyz(meas))


def measure_jacobian_body(c: FloatArray) -> FloatArray:
    """Jacobian ``∂(α, β, δ)/∂c`` (eq. 40) at body vectors c (..., 3) in m → (..., 3, 3)."""
    return _measure_jacobian_body(_xyz(c))


def lidar_jacobians(
    pos: FloatArray, euler: FloatArray, dcm: FloatArray, landmarks: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Analytic Jacobians of the measurement of k landmarks from one pose (seed 001 eq. 40).

    Args:
        pos: (3,) vehicle position in N, m.
        euler: (3,) Euler angles (φ, θ, ψ) in rad.
        dcm: (3, 3) ``C_NB`` at ``euler``.
        landmarks: (k, 3) landmark positions in N, m.

    Returns:
        ``(H_pos, H_euler, H_lm)``, each (k, 3, 3): ``∂h/∂ρ``, ``∂h/∂Λ`` and ``∂h/∂l``.
        ``∂h/∂v`` is zero.
    """
    lms = np.ascontiguousarray(_xyz(landmarks).reshape(-1, 3))
    h = np.empty(lms.shape)
    H = np.empty((lms.shape[0], 3, 9))
    C = np.ascontiguousarray(dcm, dtype=float)
    lidar_models(_xyz(pos), C, dcm_euler_partials(euler), lms, h, H)
    return H[:, :, 0:3], H[:, :, 3:6], H[:, :, 6:9]


def measure_inverse_jacobian(meas: FloatArray) -> FloatArray:
    """``∂ϱ/∂y`` of ``ϱ(y) = δ (cβ cα, cβ sα, sβ)`` (seed 001 eq. 50, body-frame part).

    Args:
        meas: (..., 3) measurements (α rad, β rad, δ m).

    Returns:
        (..., 3, 3) Jacobians, columns ∂/∂α, ∂/∂β, ∂/∂δ, in m/rad and m/m (B frame).
    """
    return _measure_inverse_jacobian(_xyz(meas))


def inverse_jacobians(
    euler: FloatArray, dcm: FloatArray, meas: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Jacobians of the inverse model ``g(s, y)`` for k measurements (seed 001 eq. 49–50).

    Args:
        euler: (3,) Euler angles in rad.
        dcm: (3, 3) ``C_NB``.
        meas: (k, 3) measurements (α, β, δ).

    Returns:
        ``(G_euler, G_meas)``, each (k, 3, 3): ``∂g/∂Λ`` and ``∂g/∂y = C_NB ∂ϱ/∂y``.
        ``∂g/∂ρ = I`` and ``∂g/∂v = 0``.
    """
    y = np.ascontiguousarray(_xyz(meas).reshape(-1, 3))
    G_euler = np.empty((y.shape[0], 3, 3))
    G_meas = np.empty((y.shape[0], 3, 3))
    C = np.ascontiguousarray(dcm, dtype=float)
    lidar_inverse_models(
        np.zeros(3), C, dcm_euler_partials(euler), y, np.empty(y.shape), G_euler, G_meas
    )
    return G_euler, G_meas


def measurement_residual(measured: FloatArray, predicted: FloatArray) -> FloatArray:
    """Innovation ``y - h`` (..., 3) with the azimuth and elevation differences wrapped to
    (-π, π] (leading axes broadcast)."""
    res = measured - predicted
    res[..., :2] = wrap_angle(res[..., :2])
    return res
