"""Numba kernels of the batched EKF-SLAM: covariance prediction and the LiDAR model per lane.

Every kernel works on one lane's slices of the batch arrays (``x[b]`` (nmax,), ``P[b]``
(nmax, nmax)) or loops over the lanes itself, so the Python layer calls one compiled function
per batch operation. ``fastmath`` stays off (IEEE semantics, no reassociation): the loops are
written with the contiguous index innermost so LLVM vectorises them anyway.

Diagnostics of all lanes live in one (7, B) float array whose rows are indexed by the ``D_*``
constants below, so :meth:`EkfSlamBatch.estimate` hands out row views without conversion.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from estimators.base import POSE_DIM
from quadslam_env.models.rotations import FloatArray
from quadslam_env.models.strapdown import strapdown_jacobians, strapdown_rk4

D_NIS, D_NIS_DOF, D_N_REJECTED, D_N_REJECTED_LAST, D_N_UPDATES, D_N_MAPPED, D_DIVERGED = range(7)
DIAGNOSTIC_NAMES = (
    "nis",
    "nis_dof",
    "n_rejected",
    "n_rejected_last",
    "n_updates",
    "n_mapped",
    "diverged",
)
"""Names of the rows of the diagnostics array, in row order (``Estimate.diagnostics`` keys)."""

MAX_PITCH = math.radians(89.0)
"""|θ̂| beyond which D(Λ) (1/cos θ) is treated as singular and the lane flagged diverged."""
_TWO_PI = 2.0 * math.pi


# ---------------------------------------------------------------------- angles and rotations
@njit(cache=True)
def wrap_state_angle(a: float) -> float:
    """Angle wrap to (-π, π] with the exact IEEE remainder (CPython's ``math.remainder``)."""
    absx = abs(a)
    m = absx % _TWO_PI  # fmod for positive operands: exact
    c = _TWO_PI - m
    if m < c:
        w = m
    elif m > c:
        w = -c
    else:  # half-way: round the quotient to even, as IEEE remainder does
        w = m - 2.0 * ((0.5 * (absx - m)) % _TWO_PI)
    w = math.copysign(1.0, a) * w
    return math.pi if w == -math.pi else w


@njit(cache=True)
def wrap_residual(a: float) -> float:
    """Angle wrap to (-π, π] as ``quadslam_env.models.wrap_angle`` does for arrays."""
    w = (a + math.pi) % _TWO_PI - math.pi
    return math.pi if w == -math.pi else w


@njit(cache=True)
def dcm_and_partials(phi: float, theta: float, psi: float, C: FloatArray, dC: FloatArray) -> None:
    """``C = C_NB(Λ)`` (seed 001 eq. 1) into C (3, 3) and ``dC[i] = ∂C_NB/∂Λ_i`` (3, 3, 3)."""
    cf, sf = math.cos(phi), math.sin(phi)
    ct, st = math.cos(theta), math.sin(theta)
    cp, sp = math.cos(psi), math.sin(psi)
    C[0, 0], C[0, 1], C[0, 2] = ct * cp, sf * st * cp - cf * sp, cf * st * cp + sf * sp
    C[1, 0], C[1, 1], C[1, 2] = ct * sp, sf * st * sp + cf * cp, cf * st * sp - sf * cp
    C[2, 0], C[2, 1], C[2, 2] = -st, sf * ct, cf * ct
    for a in range(3):
        # ∂C/∂φ = C C1(φ)ᵀ ∂C1/∂φ: column 0 vanishes, columns 1, 2 rotate into each other.
        dC[0, a, 0], dC[0, a, 1], dC[0, a, 2] = 0.0, C[a, 2], -C[a, 1]
        # ∂C/∂ψ = ∂C3/∂ψ C3ᵀ C: rows 0, 1 rotate into each other, row 2 vanishes.
        dC[2, 0, a], dC[2, 1, a], dC[2, 2, a] = -C[1, a], C[0, a], 0.0
    dC[1, 0, 0], dC[1, 0, 1], dC[1, 0, 2] = -st * cp, sf * ct * cp, cf * ct * cp
    dC[1, 1, 0], dC[1, 1, 1], dC[1, 1, 2] = -st * sp, sf * ct * sp, cf * ct * sp
    dC[1, 2, 0], dC[1, 2, 1], dC[1, 2, 2] = -ct, -sf * st, -cf * st


# ---------------------------------------------------------------------- LiDAR model per landmark
@njit(cache=True)
def lidar_model(
    pos: FloatArray, C: FloatArray, dC: FloatArray, lm: FloatArray, h: FloatArray, H: FloatArray
) -> None:
    """Predicted measurement of one landmark and its Jacobian (seed 001 eq. 30–31, 40).

    ``c = C_NBᵀ (l - ρ)``, ``h = (atan2(c2, c1), atan2(c3, ‖c_12‖), ‖c‖)``.

    Args:
        pos: (3,) ρ̂ in N, m.
        C: (3, 3) ``C_NB(Λ̂)``.
        dC: (3, 3, 3) ``∂C_NB/∂Λ_i``.
        lm: (3,) landmark position in N, m.
        h: (3,) receives (α rad, β rad, δ m).
        H: (3, 9) receives ``[∂h/∂ρ, ∂h/∂Λ, ∂h/∂l]`` (∂h/∂v is zero).
    """
    d0, d1, d2 = lm[0] - pos[0], lm[1] - pos[1], lm[2] - pos[2]
    c1 = C[0, 0] * d0 + C[1, 0] * d1 + C[2, 0] * d2
    c2 = C[0, 1] * d0 + C[1, 1] * d1 + C[2, 1] * d2
    c3 = C[0, 2] * d0 + C[1, 2] * d1 + C[2, 2] * d2
    horiz = math.hypot(c1, c2)
    h[0] = math.atan2(c2, c1)
    h[1] = math.atan2(c3, horiz)
    h[2] = math.sqrt(horiz * horiz + c3 * c3)
    # Floor: the azimuth is undefined straight above/below (c1 = c2 = 0).
    hh2 = max(c1 * c1 + c2 * c2, 1e-12)
    hh = math.sqrt(hh2)
    dd2 = hh2 + c3 * c3
    dd = math.sqrt(dd2)
    # Rows of ∂h/∂c, then the chain rule through ∂c/∂l = C_NBᵀ, ∂c/∂ρ = -C_NBᵀ and
    # ∂c/∂Λ_a = (∂C/∂Λ_a)ᵀ (l - ρ).
    _chain_row(H, 0, -c2 / hh2, c1 / hh2, 0.0, C, dC, d0, d1, d2)
    _chain_row(H, 1, -c1 * c3 / (dd2 * hh), -c2 * c3 / (dd2 * hh), hh / dd2, C, dC, d0, d1, d2)
    _chain_row(H, 2, c1 / dd, c2 / dd, c3 / dd, C, dC, d0, d1, d2)


@njit(cache=True)
def _chain_row(
    H: FloatArray,
    r: int,
    j0: float,
    j1: float,
    j2: float,
    C: FloatArray,
    dC: FloatArray,
    d0: float,
    d1: float,
    d2: float,
) -> None:
    """Row r of ``[∂h/∂ρ, ∂h/∂Λ, ∂h/∂l]`` from the row ``(j0, j1, j2)`` of ``∂h_r/∂c``."""
    for a in range(3):
        hl = j0 * C[a, 0] + j1 * C[a, 1] + j2 * C[a, 2]
        H[r, 6 + a] = hl
        H[r, a] = -hl
        e0 = dC[a, 0, 0] * d0 + dC[a, 1, 0] * d1 + dC[a, 2, 0] * d2
        e1 = dC[a, 0, 1] * d0 + dC[a, 1, 1] * d1 + dC[a, 2, 1] * d2
        e2 = dC[a, 0, 2] * d0 + dC[a, 1, 2] * d1 + dC[a, 2, 2] * d2
        H[r, 3 + a] = j0 * e0 + j1 * e1 + j2 * e2


@njit(cache=True)
def lidar_inverse_model(
    pos: FloatArray,
    C: FloatArray,
    dC: FloatArray,
    y: FloatArray,
    lm: FloatArray,
    G_eul: FloatArray,
    G_y: FloatArray,
) -> None:
    """Inverse model ``l = ρ + C_NB ϱ(y)`` and its Jacobians (seed 001 eq. 44–45, 49).

    Args:
        pos: (3,) ρ̂ in N, m.
        C: (3, 3) ``C_NB(Λ̂)``.
        dC: (3, 3, 3) ``∂C_NB/∂Λ_i``.
        y: (3,) measurement (α rad, β rad, δ m).
        lm: (3,) receives the landmark position in N, m.
        G_eul: (3, 3) receives ``∂g/∂Λ`` (``∂g/∂ρ = I``, ``∂g/∂v = 0``).
        G_y: (3, 3) receives ``∂g/∂y``.
    """
    alpha, beta, delta = y[0], y[1], y[2]
    ca, sa, cb, sb = math.cos(alpha), math.sin(alpha), math.cos(beta), math.sin(beta)
    rho = (delta * cb * ca, delta * cb * sa, delta * sb)
    drho = (
        (-delta * cb * sa, -delta * sb * ca, cb * ca),
        (delta * cb * ca, -delta * sb * sa, cb * sa),
        (0.0, delta * cb, sb),
    )
    for a in range(3):
        lm[a] = pos[a] + (C[a, 0] * rho[0] + C[a, 1] * rho[1] + C[a, 2] * rho[2])
        for i in range(3):
            G_eul[a, i] = dC[i, a, 0] * rho[0] + dC[i, a, 1] * rho[1] + dC[i, a, 2] * rho[2]
            G_y[a, i] = C[a, 0] * drho[0][i] + C[a, 1] * drho[1][i] + C[a, 2] * drho[2][i]


# ---------------------------------------------------------------------- prediction
@njit(cache=True)
def _predict_lane(
    xb: FloatArray,
    Pb: FloatArray,
    nb: int,
    nv: int,
    az: float,
    p: float,
    q: float,
    r: float,
    sa: float,
    sg: float,
    dt: float,
    qc: FloatArray,
    work: tuple,
) -> bool:
    """Propagate one lane; returns False (and changes nothing) if the result is unusable.

    ``work`` is the scratch of :func:`predict_work`.
    """
    stages, s_new, F, G, A, M, Phi, Gam, Pvv, T = work
    strapdown_rk4(xb, az, p, q, r, dt, stages, s_new)
    strapdown_jacobians(xb, p, q, r, F, G)
    # A = F dt over (s, b): the biases enter through λ = λ̃ - b, so ∂f/∂b = -G.
    A[:, :] = 0.0
    for i in range(POSE_DIM):
        for j in range(POSE_DIM):
            A[i, j] = F[i, j] * dt
        if nv > POSE_DIM:
            A[i, 9], A[i, 10], A[i, 11], A[i, 12] = (
                -G[i, 1] * dt,
                -G[i, 2] * dt,
                -G[i, 3] * dt,
                -G[i, 0] * dt,
            )
    # M = I + ½A, Φ = I + A M = I + A + ½A² (eq. 27 to second order), Γ = M G σ dt with the
    # IMU white noise (σ held over the sample) as the input noise. The products run with
    # the output index innermost (independent sums, same k order) and skip the many exact
    # zeros of A.
    for i in range(nv):
        for j in range(nv):
            M[i, j] = 0.5 * A[i, j] + (1.0 if i == j else 0.0)
    for i in range(nv):
        Phi[i, :] = 0.0
        Gam[i, :] = 0.0
        for k in range(nv):
            a = A[i, k]
            if a != 0.0:
                for j in range(nv):
                    Phi[i, j] += a * M[k, j]
        Phi[i, i] += 1.0
        for k in range(POSE_DIM):  # the bias rows of σG are zero
            a = M[i, k]
            if a != 0.0:
                Gam[i, 0] += a * (G[k, 0] * sa)
                for j in range(1, 4):
                    Gam[i, j] += a * (G[k, j] * sg)
    # T = Φ P[:nv, :n]: the rows of the pose–bias block and its cross-covariances (eq. 29).
    # Φ is sparse (∂f/∂ρ = 0, Λ̇ does not depend on v); skipping its zeros is exact because
    # P is always finite (every write is checked).
    finite = True
    for i in range(nv):
        Ti = T[i]
        Ti[:nb] = 0.0
        for k in range(nv):
            a = Phi[i, k]
            if a != 0.0:
                Pk = Pb[k]
                for j in range(nb):
                    Ti[j] += a * Pk[j]
        for j in range(nb):
            finite &= Ti[j] * 0.0 == 0.0  # exact test, and unlike a sum it vectorises
    # P_vv = Φ P_vv Φᵀ (symmetrised) + Γ Γᵀ + Q dt; M is free again and holds Φᵀ.
    PhiT = M
    for i in range(nv):
        for j in range(nv):
            PhiT[j, i] = Phi[i, j]
    for i in range(nv):
        Pvv[i, :] = 0.0
        for k in range(nv):
            t = T[i, k]
            for j in range(nv):
                Pvv[i, j] += t * PhiT[k, j]
    for i in range(nv):
        for j in range(i + 1):
            gg = 0.0
            for k in range(4):
                gg += Gam[i, k] * Gam[j, k]
            v = (Pvv[i, j] + Pvv[j, i]) * 0.5 + gg
            if i == j:
                v += qc[i] * dt
            Pvv[i, j] = v
            Pvv[j, i] = v
            finite &= v * 0.0 == 0.0
    for i in range(POSE_DIM):
        finite &= s_new[i] * 0.0 == 0.0
    if not (finite and abs(s_new[7]) < MAX_PITCH):
        return False
    for i in range(nv):
        Pi = Pb[i]
        for j in range(nv):
            Pi[j] = Pvv[i, j]
        for j in range(nv, nb):
            Pi[j] = T[i, j]
    s_new[6] = wrap_state_angle(s_new[6])
    s_new[8] = wrap_state_angle(s_new[8])
    xb[:POSE_DIM] = s_new
    return True


@njit(cache=True)
def predict_work(nv: int, nmax: int) -> tuple:
    """Scratch of :func:`_predict_lane`: RK4 stages (5, 9), ŝ⁺ (9,), F (9, 9), G (9, 4),
    A, M, Φ (nv, nv), Γ (nv, 4), P_vv (nv, nv) and T (nv, nmax)."""
    return (
        np.empty((5, POSE_DIM)),
        np.empty(POSE_DIM),
        np.empty((POSE_DIM, POSE_DIM)),
        np.empty((POSE_DIM, 4)),
        np.empty((nv, nv)),
        np.empty((nv, nv)),
        np.empty((nv, nv)),
        np.empty((nv, 4)),
        np.empty((nv, nv)),
        np.empty((nv, nmax)),
    )


@njit(cache=True)
def predict_lanes(
    x: FloatArray,
    P: FloatArray,
    n: np.ndarray,
    nv: int,
    stale: np.ndarray,
    rates: FloatArray,
    diag: FloatArray,
    active: np.ndarray,
    accel: FloatArray,
    gyro: FloatArray,
    sa: float,
    sg: float,
    dt: float,
    qc: FloatArray,
) -> None:
    """EKF prediction (seed 001 eq. 24–29) of the ``active`` lanes over one IMU sample.

    Mean: RK4 with the bias-corrected input held (eq. 26). Covariance: only the rows
    ``P[b, :nv, :n]`` are written; the mirrored columns ``P[b, nv:n, :nv]`` are marked stale
    and rebuilt by the next update (or :func:`sync_lane`), which saves a strided write of
    3·n_m·nv entries per step. A lane whose result is non-finite or whose pitch reaches 89°
    keeps its state and gets ``diverged = 1``.

    Args:
        x: (B, nmax) means.
        P: (B, nmax, nmax) covariances.
        n: (B,) int, state size per lane.
        nv: Vehicle-state size (9, or 13 with biases).
        stale: (B,) bool, set for lanes whose mirrored columns are out of date.
        rates: (B, 3) receives the bias-corrected gyro in rad/s.
        diag: (7, B) diagnostics (row ``D_DIVERGED`` is set on failure).
        active: (B,) bool, lanes to propagate.
        accel: (B, 3) measured specific force in m/s² (only the z column is used, eq. 25).
        gyro: (B, 3) measured body rates in rad/s.
        sa: Accelerometer white-noise std times dt (0 to leave IMU noise out of Q_d).
        sg: Gyro white-noise std times dt (0 likewise).
        dt: Sample period in s.
        qc: (nv,) diagonal of the continuous process-noise density.
    """
    work = predict_work(nv, x.shape[1])
    for b in range(x.shape[0]):
        if not active[b]:
            continue
        xb = x[b]
        p, q, r, az = gyro[b, 0], gyro[b, 1], gyro[b, 2], accel[b, 2]
        if nv > POSE_DIM:
            p -= xb[9]
            q -= xb[10]
            r -= xb[11]
            az -= xb[12]
        if _predict_lane(xb, P[b], n[b], nv, az, p, q, r, sa, sg, dt, qc, work):
            stale[b] = stale[b] or n[b] > nv
            rates[b, 0], rates[b, 1], rates[b, 2] = p, q, r
        else:
            diag[D_DIVERGED, b] = 1.0


@njit(cache=True)
def sync_lane(Pb: FloatArray, nb: int, nv: int) -> None:
    """Rebuild the stale columns ``P[nv:n, :nv]`` of one lane from the rows ``P[:nv, nv:n]``."""
    for i in range(nv, nb):
        Pi = Pb[i]
        for j in range(nv):
            Pi[j] = Pb[j, i]


# ---------------------------------------------------------------------- outputs
@njit(cache=True)
def fill_outputs(
    x: FloatArray,
    nv: int,
    slot_of_id: np.ndarray,
    mapped: np.ndarray,
    known: np.ndarray,
    known_pos: FloatArray,
    vel_inertial: FloatArray,
    landmark_means: FloatArray,
) -> None:
    """Per lane: ``vel_inertial = C_NB(Λ̂) v̂`` (B, 3) and the landmark means by id
    (B, Lmax, 3) from the map slots (or the known map); rows of unmapped ids are left as is."""
    C = np.empty((3, 3))
    dC = np.empty((3, 3, 3))
    for b in range(x.shape[0]):
        xb = x[b]
        dcm_and_partials(xb[6], xb[7], xb[8], C, dC)
        for a in range(3):
            vel_inertial[b, a] = C[a, 0] * xb[3] + C[a, 1] * xb[4] + C[a, 2] * xb[5]
        for j in range(mapped.shape[1]):
            if mapped[b, j]:
                if known[b]:
                    landmark_means[b, j] = known_pos[b, j]
                else:
                    c = nv + 3 * slot_of_id[b, j]
                    landmark_means[b, j] = xb[c : c + 3]
