"""EKF-SLAM with the horizontal wind as states (``estimator.params.wind: estimate``).

The "drag fusion" of PX4's EKF2, after Leishman, Macdonald, Beard & McLain 2014, "Quadrotors
and accelerometers: state estimation with an improved dynamic model", IEEE Control Systems
34(1): a rotor (and body) drag makes the accelerometer's horizontal axes read the velocity
relative to the air, so with a drag model they measure the wind.

State of a lane: ``x = (s, b, w, m)`` with ``w = (w_N, w_E)`` (m/s, N) the last two vehicle
states (after the bias block, before the landmarks; nv = 11, or 17 with the biases (b_ω, b_az,
b_ax, b_ay)). Per IMU sample:

1. **Prediction** (:func:`predict_wind_lanes`): the thrust-axis process (seed 001 eq. 24–25,
   input λ = (ã_z, ω̃) − b) with the vehicle's drag on the body's horizontal axes,
   ``v̇ = −ω×v + C_NBᵀ g n3 + a_z b3 + P_xy d(v − C_NBᵀ w)``
   (:mod:`quadslam_env.models.strapdown`, Leishman et al.'s drag model), the wind a random walk
   ``ẇ = n_w`` (density ``wind_walk``) and (b_ax, b_ay) random walks that enter no process
   row. RK4 for the mean; ``Φ = I + A + ½A²`` with ``A = F dt`` where F gains the drag rows
   ``D = ∂(P_xy d)/∂(v, Λ, w)`` (:func:`~quadslam_env.models.strapdown.drag_jacobians`).
2. **Measurement** (:func:`accel_update`) at the predicted state: the sample is taken at the end
   of its period, as the state it is predicted to. ``z = (ã_x, ã_y)``,
   ``h(x) = P_xy d(v − C_NBᵀ w) + (b_ax, b_ay)``, ``H = [D | I]`` over (v, Λ, w, b_xy) and
   ``R = σ_a² I`` (the accelerometer's white-noise variance per sample). The gain and the update
   are the LiDAR update's (:func:`~estimators.ekf.correction.stacked_gain`, ``x += W L⁻¹ν``,
   ``P −= W Wᵀ``), after the stale columns of P are rebuilt.

**Observability.** With the pose pinned by the landmarks, the measurement gives the air
velocity's horizontal body components and hence ``C_NBᵀ w``: the wind is observable at once.
A constant (b_ax, b_ay) adds a body-fixed offset that, while the heading is fixed, reads as a
wind ``C b / μ``; the two separate only as the vehicle turns (the figure-8 with tangent
heading turns through 360° a period). Without drag (μ = 0) the wind is unobservable, which the
settings refuse (:meth:`~estimators.ekf.settings.EkfSlamSettings.drag_model`).
"""

from __future__ import annotations

import math

import numpy as np

from estimators.ekf.correction import correction, stacked_gain
from estimators.ekf.kernels import (
    D_DIVERGED,
    commit_prediction,
    discretise,
    propagate_covariance,
    sync_lane,
)
from estimators.ekf.settings import WIND_DIM
from estimators.ekf.state import EkfState
from estimators.ekf.update import DIAG_FLOOR, subtract_outer
from quadslam_env.models.frames import wrap_pi
from quadslam_env.models.jit import inline_kernel, kernel
from quadslam_env.models.rigid_body import Vec3
from quadslam_env.models.strapdown import (
    drag_jacobians,
    horizontal_drag,
    strapdown_drag_rk4,
    strapdown_jacobians,
)
from quadslam_env.types import POSE_DIM, FloatArray


@kernel
def drag_transition(
    xb: FloatArray,
    nv: int,
    gyro: Vec3,
    drag: tuple,
    sa: float,
    sg: float,
    dt: float,
    work: tuple,
) -> None:
    """``Φ`` and ``Γ`` of one IMU sample of the drag model into ``work`` (module docstring).

    Args:
        xb: (≥nv,) state; the linearisation point s (9,) and the wind ``x[nv−2:nv]``.
        nv: Vehicle-state size (11 or 17).
        gyro: Bias-corrected body rates (p, q, r) in rad/s.
        drag: ``(μ [1/s], c_q (3,) [1/m])``.
        sa, sg: Accelerometer and gyro white-noise std times dt (0: no IMU noise in Q_d).
        dt: Sample period in s.
        work: The scratch of :func:`wind_work`; F (9, 9), G (9, 4), D (2, 8), A, M, Φ
            (nv, nv) and Γ (nv, 4) receive their values.
    """
    F, G, D, C, dC = work[2], work[3], work[4], work[5], work[6]
    A, M, Phi, Gam = work[7], work[8], work[9], work[10]
    w0 = nv - WIND_DIM
    strapdown_jacobians(xb, gyro[0], gyro[1], gyro[2], F, G)
    drag_jacobians(xb, xb[w0], xb[w0 + 1], drag[0], drag[1], C, dC, D)
    for i in range(2):
        for k in range(6):
            F[3 + i, 3 + k] += D[i, k]
    A[:, :] = 0.0
    for i in range(POSE_DIM):
        for j in range(POSE_DIM):
            A[i, j] = F[i, j] * dt
        if nv > POSE_DIM + WIND_DIM:  # b_ω, b_az through the inputs; b_ax, b_ay: no process row
            A[i, 9], A[i, 10], A[i, 11], A[i, 12] = (
                -G[i, 1] * dt,
                -G[i, 2] * dt,
                -G[i, 3] * dt,
                -G[i, 0] * dt,
            )
    for i in range(2):
        A[3 + i, w0] = D[i, 6] * dt
        A[3 + i, w0 + 1] = D[i, 7] * dt
    discretise(A, nv, G, sa, sg, M, Phi, Gam)


@kernel
def wind_work(nv: int, nmax: int) -> tuple:
    """Scratch of one lane: RK4 work (6, 12), y = (s, ω) (12,), F (9, 9), G (9, 4), D (2, 8),
    C (3, 3), ∂C (3, 3, 3), A, M, Φ (nv, nv), Γ (nv, 4), P_vv (nv, nv) and T (nv, nmax)."""
    return (
        np.empty((6, 12)),
        np.empty(12),
        np.empty((POSE_DIM, POSE_DIM)),
        np.empty((POSE_DIM, 4)),
        np.empty((2, 8)),
        np.empty((3, 3)),
        np.empty((3, 3, 3)),
        np.empty((nv, nv)),
        np.empty((nv, nv)),
        np.empty((nv, nv)),
        np.empty((nv, 4)),
        np.empty((nv, nv)),
        np.empty((nv, nmax)),
    )


@kernel
def _predict_drag_lane(
    xb: FloatArray,
    Pb: FloatArray,
    nb: int,
    nv: int,
    az: float,
    gyro: Vec3,
    drag: tuple,
    noise: Vec3,
    qc: FloatArray,
    work: tuple,
) -> bool:
    """Propagate one lane; False (nothing changed) if the result is unusable. ``noise`` is
    ``(σ_a dt, σ_ω dt, dt)``."""
    stages, y, Phi, Gam, Pvv, T = work[0], work[1], work[9], work[10], work[11], work[12]
    sa, sg, dt = noise
    w0 = nv - WIND_DIM
    for i in range(POSE_DIM):
        y[i] = xb[i]
    y[9], y[10], y[11] = gyro
    strapdown_drag_rk4(y, az, xb[w0], xb[w0 + 1], drag[0], drag[1], dt, stages)
    s_new = y[:POSE_DIM]
    drag_transition(xb, nv, gyro, drag, sa, sg, dt, work)
    finite = propagate_covariance(Pb, nb, nv, Phi, Gam, qc, dt, T, Pvv)
    return commit_prediction(xb, Pb, nb, nv, s_new, T, Pvv, finite)


@inline_kernel
def accel_innovation(
    xb: FloatArray,
    Pb: FloatArray,
    nb: int,
    nv: int,
    accel_xy: tuple,
    drag: tuple,
    r_var: float,
    work: tuple,
) -> tuple:
    """The innovation ``ν = z − h(x)`` (2,), ``U = H P[:, :n]`` (2, n) and ``S = U Hᵀ + R``
    (2, 2) of the horizontal accelerometer axes at one lane's state (arguments as
    :func:`accel_update`); U is formed from the rows of H's columns (v, Λ, w[, b_xy]), which
    are current even while the mirrored columns are stale."""
    D, C, dC = work[4], work[5], work[6]
    w0 = nv - WIND_DIM
    wn, we = xb[w0], xb[w0 + 1]
    drag_jacobians(xb, wn, we, drag[0], drag[1], C, dC, D)
    c = (C[0, 0], C[0, 1], C[0, 2], C[1, 0], C[1, 1], C[1, 2], C[2, 0], C[2, 1], C[2, 2])
    h = horizontal_drag(xb, c, wn, we, drag[0], drag[1])
    bias = nv > POSE_DIM + WIND_DIM
    nu = np.empty(2)
    nu[0], nu[1] = accel_xy[0] - h[0], accel_xy[1] - h[1]
    if bias:
        nu[0] -= xb[13]
        nu[1] -= xb[14]
    U = np.empty((2, nb))
    for a in range(2):
        Ua = U[a]
        d0, d1, d2, d3 = D[a, 0], D[a, 1], D[a, 2], D[a, 3]
        d4, d5, d6, d7 = D[a, 4], D[a, 5], D[a, 6], D[a, 7]
        P3, P4, P5, P6, P7, P8 = Pb[3], Pb[4], Pb[5], Pb[6], Pb[7], Pb[8]
        Pw, Pe = Pb[w0], Pb[w0 + 1]
        # One expression per output row (vectorised over j, as correction._stacked_rows).
        for j in range(nb):
            Ua[j] = (
                d0 * P3[j] + d1 * P4[j] + d2 * P5[j] + d3 * P6[j] + d4 * P7[j] + d5 * P8[j]
                + d6 * Pw[j] + d7 * Pe[j]
            )  # fmt: skip
        if bias:
            Pbias = Pb[13 + a]
            for j in range(nb):
                Ua[j] += Pbias[j]
    S = np.empty((2, 2))
    for a in range(2):
        for e in range(2):
            acc = 0.0
            for k in range(6):
                acc += U[a, 3 + k] * D[e, k]
            acc += U[a, w0] * D[e, 6] + U[a, w0 + 1] * D[e, 7]
            if bias:
                acc += U[a, 13 + e]
            S[a, e] = acc
        S[a, a] += r_var
    return nu, U, S


@kernel
def accel_update(
    xb: FloatArray,
    Pb: FloatArray,
    nb: int,
    nv: int,
    accel_xy: tuple,
    drag: tuple,
    r_var: float,
    stale: bool,
    work: tuple,
) -> bool:
    """Update one lane with the horizontal accelerometer axes (module docstring, step 2).

    Args:
        xb: (≥nb,) state; Pb: (≥nb, ≥nb) covariance (rows ``:nv`` current; the columns
            ``P[nv:n, :nv]`` are rebuilt first when ``stale``).
        nb: State size n. nv: Vehicle-state size (11 or 17).
        accel_xy: Measured specific force ``(ã_x, ã_y)`` in m/s² (B).
        drag: ``(μ [1/s], c_q (3,) [1/m])``.
        r_var: Measurement variance per axis, m²/s⁴.
        stale: Whether the columns ``P[nv:n, :nv]`` lag the rows.
        work: The scratch of :func:`wind_work` (D, C and ∂C are used).

    Returns:
        False (and nothing changed) if S is not positive definite or the result is unusable;
        otherwise P is whole and symmetric again.
    """
    nu, U, S = accel_innovation(xb, Pb, nb, nv, accel_xy, drag, r_var, work)
    Wt = np.empty((2, nb))
    z = np.empty(2)
    if not stacked_gain(S, U, nu, np.arange(2), Wt, z):
        return False
    dx = np.zeros(nb)
    correction(Wt, z, dx)
    total = 0.0
    negative = False
    for j in range(nb):
        total += dx[j]
        wsq = Wt[0, j] * Wt[0, j] + Wt[1, j] * Wt[1, j]
        negative = negative or Pb[j, j] - wsq < DIAG_FLOOR
    if not math.isfinite(total) or negative:
        return False
    for j in range(nb):
        xb[j] += dx[j]
    if stale:
        sync_lane(Pb, nb, nv)
    subtract_outer(Pb, Wt, nb)
    xb[6] = wrap_pi(xb[6])
    xb[8] = wrap_pi(xb[8])
    return True


@kernel
def predict_wind_lanes(
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
    drag: tuple,
    noise: Vec3,
    r_var: float,
    qc: FloatArray,
) -> None:
    """Prediction and accelerometer update of the ``active`` lanes over one IMU sample.

    As :func:`~estimators.ekf.kernels.predict_lanes` (a lane whose result is unusable keeps its
    state and gets ``diverged = 1``), then :func:`accel_update` with the sample's horizontal
    axes, which leaves P whole (not stale).

    Args:
        x: (B, nmax) means. P: (B, nmax, nmax) covariances. n: (B,) int state sizes.
        nv: Vehicle-state size (11, or 17 with the biases).
        stale: (B,) bool lanes whose mirrored columns are out of date (updated).
        rates: (B, 3) receives the bias-corrected gyro in rad/s.
        diag: (15, B) diagnostics (row ``D_DIVERGED`` is set on failure).
        active: (B,) bool lanes to propagate.
        accel: (B, 3) measured specific force in m/s² (z: the input; x, y: the measurement).
        gyro: (B, 3) measured body rates in rad/s.
        drag: ``(μ [1/s], c_q (3,) [1/m])`` of the vehicle.
        noise: ``(σ_a dt, σ_ω dt, dt)``: the IMU white noise mapped into Q_d (zeros to leave it
            out) and the sample period in s.
        r_var: Variance of each horizontal accelerometer axis per sample, m²/s⁴.
        qc: (nv,) diagonal of the continuous process-noise density.
    """
    work = wind_work(nv, x.shape[1])
    bias = nv > POSE_DIM + WIND_DIM
    for b in range(x.shape[0]):
        if not active[b]:
            continue
        xb = x[b]
        p, q, r, az = gyro[b, 0], gyro[b, 1], gyro[b, 2], accel[b, 2]
        if bias:
            p -= xb[9]
            q -= xb[10]
            r -= xb[11]
            az -= xb[12]
        if not _predict_drag_lane(xb, P[b], n[b], nv, az, (p, q, r), drag, noise, qc, work):
            diag[D_DIVERGED, b] = 1.0
            continue
        rates[b, 0], rates[b, 1], rates[b, 2] = p, q, r
        lag = stale[b] or n[b] > nv
        if accel_update(xb, P[b], n[b], nv, (accel[b, 0], accel[b, 1]), drag, r_var, lag, work):
            stale[b] = False
        else:
            stale[b] = lag
            diag[D_DIVERGED, b] = 1.0


def predict_wind(
    state: EkfState,
    nv: int,
    active: np.ndarray,
    accel: FloatArray,
    gyro: FloatArray,
    drag: tuple[float, Vec3],
    noise: Vec3,
    r_var: float,
    qc: FloatArray,
) -> None:
    """:func:`predict_wind_lanes` on the filter's ``state`` (EKF-SLAM's ``predict`` with
    ``wind: estimate``); arguments as there, the arrays of any dtype and layout."""
    predict_wind_lanes(
        state.x,
        state.P,
        state.n,
        nv,
        state.stale,
        state.rates,
        state.diag,
        np.ascontiguousarray(active, dtype=bool),
        np.ascontiguousarray(accel, dtype=float),
        np.ascontiguousarray(gyro, dtype=float),
        drag,
        noise,
        r_var,
        qc,
    )
