"""Posterior Cramér–Rao bound (PCRB) of EKF-SLAM's model along a true trajectory.

An analysis tool, not an estimator: it evaluates the models at the **true** state, so no
estimator may use it (like :mod:`quadslam_env.metrics`, it belongs to the layer that compares
estimators with the truth). It answers "how small could the error of any unbiased estimator
using the same data be?", so that a filter's error, and a paper's figure, can be put next to
what the sensors allow.

**The recursion** (Tichavský, Muravchik & Nehorai 1998). For ``x_{k+1} = f(x_k) + w_k``,
``w_k ~ N(0, Q_k)`` and ``z_k = h(x_k) + v_k``, ``v_k ~ N(0, R)``, the Fisher information
``J_k`` of the state obeys ``J_{k+1} = D22 − D21 (J_k + D11)⁻¹ D12`` with
``D11 = E[Fᵀ Q⁻¹ F]``, ``D12 = −E[Fᵀ] Q⁻¹``, ``D22 = Q⁻¹ + E[Hᵀ R⁻¹ H]``; by the matrix
inversion lemma this is

    J_{k+1} = (Q_k + F_k J_k⁻¹ F_kᵀ)⁻¹ + H_{k+1}ᵀ R⁻¹ H_{k+1}                  (1)

(:func:`information_step`). The expectations over the true state are taken along the one
true trajectory of each seed (``F_k``, ``H_k`` evaluated at the truth): the bound of that
trajectory, averaged over seeds by the study (:mod:`agents.lab.estimator_studies.bound`). With ``B =
J⁻¹``, (1) is the Kalman covariance recursion ``B⁻ = F B Fᵀ + Q``, ``B = B⁻ − B⁻Hᵀ(H B⁻ Hᵀ + R)⁻¹H
B⁻`` (:func:`covariance_predict`, :func:`covariance_update`), which the SLAM bound below runs in,
because the scenarios' priors and process noise are singular (seed 001 Table 7 gives the
attitude a zero initial variance; with zero extra Q the process noise has rank 4: only the
IMU noise drives the state), where the information form would need infinite entries.

**The model** is EKF-SLAM's own, through the functions the filter calls (one implementation of
each equation): the strapdown process (seed 001 eq. 24) driven by the noise-free IMU input,
its transition ``Φ = I + A + ½A²`` and noise input ``Γ`` from
:func:`estimators.ekf.kernels.transition_matrices`, the covariance prediction
``P_vv ← Φ P_vv Φᵀ + Γ Γᵀ + Q dt``, ``P_vm ← Φ P_vm`` from
:func:`~estimators.ekf.kernels.propagate_covariance` (bias states and their random walks when
the settings estimate them), and the stacked LiDAR Jacobian of
:func:`estimators.ekf.update.stacked_model` for the landmarks that are truly visible at each
scan (the EKF's χ² gate plays no part: every return counts).

**Landmarks that enter the state** (unknown map). A landmark has no prior: it enters when first
seen, with exactly the information its first measurement carries. Its joint information with
the state ``x`` is ``[[J + H_xᵀR⁻¹H_x, H_xᵀR⁻¹H_l], [H_lᵀR⁻¹H_x, H_lᵀR⁻¹H_l]]``; since ``H_l``
(3×3) is invertible this inverts in closed form (:func:`augment_without_prior`):

    B_lx = −H_l⁻¹ H_x B_xx,     B_ll = H_l⁻¹ (H_x B_xx H_xᵀ + R) H_l⁻ᵀ,

and the marginal bound of ``x`` is unchanged (a first sighting says nothing about the
vehicle). This is the exact limit of a landmark entering with prior covariance ``σ² I``,
``σ → ∞`` (no large-but-finite σ whose round-off would enter the bound), and it equals
EKF-SLAM's registration (seed 001 eq. 46–53) with the inverse model's Jacobians
``G_s = −H_l⁻¹ H_x``, ``G_y = H_l⁻¹`` at the same point. Landmarks seen later in the same
scan as known ones enter after the update with the known ones, as in the filter.

The bound on the error of a function ``g`` of the state (the inertial velocity ``C_NB v``, the
rotation vector of the attitude error) is ``∂g/∂x B ∂g/∂xᵀ``; :func:`error_bounds` gives the
mean-square bounds of the position, inertial velocity and attitude (rotation angle) errors
that :mod:`quadslam_env.metrics` reports.

**The map block.** The landmarks' rows and columns of the same ``B`` bound the map: ``B_ll``
(3×3, N frame, m²) of landmark ``l`` (:func:`landmark_blocks`) bounds the covariance of its
position error, and the map RMSE that :mod:`quadslam_env.metrics` reports,
``√((1/n) Σ_j ‖l̂_j − l_j‖²)`` over the n mapped landmarks, has the mean-square bound

    E[(1/n) Σ_j ‖l̂_j − l_j‖²]  ≥  (1/n) Σ_j tr B_{l_j l_j}                      (2)

(:func:`map_error_bound`). It holds the SLAM gauge: the landmarks inherit the prior's position
variance (no measurement tells a shift of vehicle and map together), so ``tr B_ll`` never
drops below the trace of the pose prior's position block.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import cho_factor, cho_solve, solve_triangular

from estimators.ekf.kernels import (
    propagate_covariance,
    store_rows,
    sync_lane,
    transition_matrices,
)
from estimators.ekf.settings import EkfSlamSettings
from estimators.ekf.update import stacked_model
from quadslam_env.models.strapdown import process_jacobians
from quadslam_env.types import EUL, POS, POSE_DIM, FloatArray

# ----------------------------------------------------------------- the generic recursion


def information_step(
    J: FloatArray, F: FloatArray, Q: FloatArray, H: FloatArray | None, R: FloatArray | None
) -> FloatArray:
    """One step of eq. (1): ``J⁺ = (Q + F J⁻¹ Fᵀ)⁻¹ + Hᵀ R⁻¹ H``.

    Args:
        J: (n, n) information of the state at step k (positive definite).
        F: (n, n) process Jacobian at the true state.
        Q: (n, n) process noise covariance.
        H: (m, n) measurement Jacobian at step k + 1, or ``None`` (no measurement).
        R: (m, m) measurement noise covariance (with ``H``).

    Returns:
        (n, n) information at step k + 1.
    """
    prior = Q + F @ np.linalg.solve(J, F.T)
    out = np.linalg.inv(0.5 * (prior + prior.T))
    if H is not None and R is not None:
        out = out + H.T @ np.linalg.solve(R, H)
    return 0.5 * (out + out.T)


def covariance_predict(P: FloatArray, F: FloatArray, Q: FloatArray) -> FloatArray:
    """``B⁻ = F B Fᵀ + Q``: the prediction half of eq. (1) with ``B = J⁻¹``."""
    out = F @ P @ F.T + Q
    return 0.5 * (out + out.T)


def covariance_update(P: FloatArray, H: FloatArray, R: FloatArray) -> FloatArray:
    """``B = (B⁻⁻¹ + Hᵀ R⁻¹ H)⁻¹ = B⁻ − B⁻Hᵀ (H B⁻ Hᵀ + R)⁻¹ H B⁻`` (valid for singular B⁻).

    Args:
        P: (n, n) prior bound ``B⁻``.
        H: (m, n) measurement Jacobian.
        R: (m, m) measurement noise covariance (positive definite).
    """
    U = H @ P
    S = U @ H.T + R
    L = np.linalg.cholesky(0.5 * (S + S.T))
    W = solve_triangular(L, U, lower=True)
    out = P - W.T @ W
    return 0.5 * (out + out.T)


def augment_without_prior(
    P: FloatArray, rows: np.ndarray, H_x: FloatArray, H_l: FloatArray, R: FloatArray
) -> FloatArray:
    """Append new states ``l`` that enter with no prior, seen once through
    ``z = H_x x[rows] + H_l l + v`` (module docstring): ``B_lx = G B[rows, :]``,
    ``B_ll = G B[rows, rows] Gᵀ + H_l⁻¹ R H_l⁻ᵀ`` with ``G = −H_l⁻¹ H_x``.

    Args:
        P: (n, n) bound of the current state.
        rows: (d,) the state entries the measurement depends on.
        H_x: (m, d) Jacobian with respect to ``x[rows]``.
        H_l: (m, m) Jacobian with respect to the new states (invertible; block diagonal
            when several landmarks enter at once).
        R: (m, m) measurement noise covariance.

    Returns:
        (n + m, n + m) bound of ``(x, l)``.
    """
    n, m = P.shape[0], H_l.shape[0]
    Hl_inv = np.linalg.inv(H_l)
    G = -Hl_inv @ H_x
    out = np.zeros((n + m, n + m))
    out[:n, :n] = P
    cross = G @ P[rows, :]
    out[n:, :n] = cross
    out[:n, n:] = cross.T
    new = cross[:, rows] @ G.T + Hl_inv @ R @ Hl_inv.T
    out[n:, n:] = 0.5 * (new + new.T)
    return out


# ---------------------------------------------------------------------- EKF-SLAM's bound


@dataclass
class TruthRecord:
    """What the bound needs of one flown episode (the truth, never an estimate).

    Attributes:
        dt: IMU sample (control) period in s.
        state: (K + 1, 12) true states ``(ρ, v_B, Λ, ω)`` at ``t = 0, dt, …, K dt``.
        rates: (K, 3) true body rates averaged over each step (the noise-free gyro input).
        landmarks: (L, 3) true landmark positions (NED, m); ids are row indices.
        scan_steps: (S,) int, the steps k (1 … K) at whose end the LiDAR scanned.
        scan_ids: S arrays of the landmark ids truly visible in those scans.
    """

    dt: float
    state: FloatArray
    rates: FloatArray
    landmarks: FloatArray
    scan_steps: np.ndarray
    scan_ids: list[np.ndarray] = field(default_factory=list)

    @property
    def steps(self) -> int:
        """K, the number of steps."""
        return int(self.rates.shape[0])


@dataclass(frozen=True)
class BoundModel:
    """The data model the bound is computed for (EKF-SLAM's, from a scenario).

    Attributes:
        settings: EKF-SLAM settings: extra process noise, bias states and their priors and
            random walks, whether the IMU noise enters Q.
        accel_sigma: Accelerometer white-noise std per sample in m/s².
        gyro_sigma: Gyro white-noise std per sample in rad/s.
        lidar_sigma: (3,) LiDAR noise std (σ_α rad, σ_β rad, σ_δ m).
        cov0: (9, 9) prior covariance of the pose ``(ρ, v_B, Λ)`` (may be singular).
        known_map: Localisation against the true map (no landmark states).
    """

    settings: EkfSlamSettings
    accel_sigma: float
    gyro_sigma: float
    lidar_sigma: FloatArray
    cov0: FloatArray
    known_map: bool


@dataclass
class BoundResult:
    """The PCRB along one true trajectory.

    Attributes:
        pose_cov: (K + 1, 9, 9) bound on the covariance of ``(ρ, v_B, Λ)`` at each step.
        bias_cov: (K + 1, 4, 4) bound on the bias states (b_ω, b_az), or ``None``.
        n_landmarks: (K + 1,) int, landmarks in the state (0 for a known map).
        landmark_var: (K + 1, L, 3) bound on the variance of each landmark's position error
            per NED axis in m² (the diagonal of its 3×3 block of eq. (1), the map block), NaN
            before the landmark's first sighting; ``None`` for a known map.
        landmark_cov: (L, 3, 3) bound on each landmark's error covariance at the last step
            in m² (NaN for a landmark never seen); ``None`` for a known map.
    """

    pose_cov: FloatArray
    bias_cov: FloatArray | None
    n_landmarks: np.ndarray
    landmark_var: FloatArray | None = None
    landmark_cov: FloatArray | None = None


def slam_bound(record: TruthRecord, model: BoundModel) -> BoundResult:
    """The PCRB of EKF-SLAM's model (module docstring) along ``record``'s true trajectory.

    Per step k: the transition at the true state ``x_k`` with the true input (the filter's
    :func:`~estimators.ekf.kernels.transition_matrices` and
    :func:`~estimators.ekf.kernels.propagate_covariance`); at a scan, the update with the
    truly visible landmarks already in the state, then the exact entry of the new ones
    (:func:`augment_without_prior`).

    Returns:
        The bound at ``t = 0 … K dt`` (step 0 is the prior), the map block with it when the
        map is unknown (:func:`landmark_blocks`).
    """
    settings = model.settings
    nv = settings.nv
    n_lm = 0 if model.known_map else int(record.landmarks.shape[0])
    nmax = nv + 3 * n_lm
    K = record.steps
    P = np.zeros((nmax, nmax))
    P[:POSE_DIM, :POSE_DIM] = model.cov0
    if settings.estimate_imu_bias:
        P[POSE_DIM:nv, POSE_DIM:nv] = np.diag(settings.initial_bias_variances())
    n = nv
    slot = np.full(record.landmarks.shape[0], -1, dtype=np.int64)
    qc = settings.continuous_noise()
    dt = float(record.dt)
    sa = model.accel_sigma * dt if settings.imu_noise_in_q else 0.0
    sg = model.gyro_sigma * dt if settings.imu_noise_in_q else 0.0
    r_diag = np.asarray(model.lidar_sigma, dtype=float) ** 2
    nl = settings.input_dim
    F, G = np.empty((POSE_DIM, POSE_DIM)), np.empty((POSE_DIM, nl))
    A, M, Phi = (np.empty((nv, nv)) for _ in range(3))
    Gam, Pvv, T = np.empty((nv, nl)), np.empty((nv, nv)), np.empty((nv, nmax))
    xb = np.empty(nv)
    scans = dict(zip(record.scan_steps.tolist(), record.scan_ids, strict=True))
    pose = np.empty((K + 1, POSE_DIM, POSE_DIM))
    bias = np.empty((K + 1, nv - POSE_DIM, nv - POSE_DIM)) if nv > POSE_DIM else None
    counts = np.zeros(K + 1, dtype=np.int64)
    lm_var = None if model.known_map else np.full((K + 1, n_lm, 3), np.nan)
    pose[0] = P[:POSE_DIM, :POSE_DIM]
    if bias is not None:
        bias[0] = P[POSE_DIM:nv, POSE_DIM:nv]
    for k in range(K):
        xb[:POSE_DIM] = record.state[k, :POSE_DIM]
        p, q, r = (float(c) for c in record.rates[k])
        transition_matrices(xb, nv, p, q, r, sa, sg, dt, F, G, A, M, Phi, Gam)
        if not propagate_covariance(P, n, nv, Phi, Gam, qc, dt, T, Pvv):
            raise FloatingPointError(f"PCRB: non-finite prediction at step {k}")
        store_rows(P, n, nv, T, Pvv)
        sync_lane(P, n, nv)
        ids = scans.get(k + 1)
        if ids is not None and ids.size:
            n = _scan(P, n, nv, record.state[k + 1], record.landmarks, ids, slot, r_diag, model)
        pose[k + 1] = P[:POSE_DIM, :POSE_DIM]
        if bias is not None:
            bias[k + 1] = P[POSE_DIM:nv, POSE_DIM:nv]
        counts[k + 1] = (n - nv) // 3
        if lm_var is not None and ids is not None:  # the map block moves at scans only
            seen = np.flatnonzero(slot >= 0)
            lm_var[k + 1, seen] = np.diagonal(landmark_blocks(P, nv, slot[seen]), 0, 1, 2)
        if lm_var is not None and ids is None:
            lm_var[k + 1] = lm_var[k]
    lm_cov = None
    if lm_var is not None:
        lm_cov = np.full((n_lm, 3, 3), np.nan)
        seen = np.flatnonzero(slot >= 0)
        lm_cov[seen] = landmark_blocks(P, nv, slot[seen])
    return BoundResult(pose, bias, counts, lm_var, lm_cov)


def landmark_blocks(P: FloatArray, nv: int, slots: np.ndarray) -> FloatArray:
    """The 3×3 diagonal blocks of the map in the SLAM bound ``P`` (eq. (1) in its covariance
    form): ``B_ll`` of each landmark, the bound on the covariance of its position error.

    Args:
        P: (n, n) bound of the state ``(x_v, l_0, l_1, …)``, vehicle part of size ``nv``.
        slots: (m,) int, the landmarks' positions in the state (order of entry).

    Returns:
        (m, 3, 3) in m² (NED).
    """
    idx = nv + 3 * np.asarray(slots, dtype=np.int64)[:, None] + np.arange(3)
    return np.asarray(P[idx[:, :, None], idx[:, None, :]], dtype=float)


def _scan(
    P: FloatArray,
    n: int,
    nv: int,
    state: FloatArray,
    landmarks: FloatArray,
    ids: np.ndarray,
    slot: np.ndarray,
    r_diag: FloatArray,
    model: BoundModel,
) -> int:
    """Update ``P[:n, :n]`` in place with the scan of ``ids`` from the true ``state``, enter
    the landmarks seen for the first time; returns the new state size."""
    xb = np.ascontiguousarray(state[:POSE_DIM])
    known = model.known_map
    seen = ids if known else ids[slot[ids] >= 0]
    new = np.empty(0, dtype=np.int64) if known else ids[slot[ids] < 0]
    if seen.size:
        lm_cols = None if known else (nv + 3 * slot[seen][:, None] + np.arange(3)).ravel()
        cols, _, H = stacked_model(xb, landmarks[seen], lm_cols)
        R = np.diag(np.tile(r_diag, seen.size))
        U = H @ P[cols, :n]
        S = U[:, cols] @ H.T + R
        W = cho_solve(cho_factor(S, lower=True), U)
        P[:n, :n] -= U.T @ W
        P[:n, :n] = 0.5 * (P[:n, :n] + P[:n, :n].T)
    if new.size:
        m = 3 * new.size
        cols, _, H = stacked_model(xb, landmarks[new], np.arange(POSE_DIM, POSE_DIM + m))
        R = np.diag(np.tile(r_diag, new.size))
        grown = augment_without_prior(
            P[:n, :n], cols[:POSE_DIM], H[:, :POSE_DIM], H[:, POSE_DIM:], R
        )
        P[: n + m, : n + m] = grown
        slot[new] = (n - nv) // 3 + np.arange(new.size)
        n += m
    return n


# ------------------------------------------------------------- bounds of the error metrics


def error_transforms(state: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Jacobians of the reported errors with respect to the pose at a true state.

    Args:
        state: (≥9,) true ``(ρ, v_B, Λ, …)``.

    Returns:
        ``(T_v, T_a)``: ``T_v`` (3, 6) = ``∂(C_NB v)/∂(v, Λ)`` (rows 0–2 of the process
        Jacobian F, eq. 28: ``ρ̇ = C_NB v``) and ``T_a`` (3, 3) = ``D(Λ)⁻¹``, which maps an
        Euler-angle error to the rotation vector of the attitude error in B (``Λ̇ = D(Λ) ω``,
        so a small ``δΛ`` is the rotation ``D⁻¹ δΛ``; its norm is the rotation angle that
        :mod:`quadslam_env.metrics` reports).
    """
    F, G = process_jacobians(np.asarray(state[:POSE_DIM], dtype=float), 0.0, np.zeros(3))
    T_a = np.asarray(np.linalg.inv(G[EUL, 1:4]), dtype=float)
    return F[POS, 3:9].copy(), T_a


def error_bounds(state: FloatArray, pose_cov: FloatArray) -> dict[str, FloatArray]:
    """Mean-square-error bounds of the metrics' position, velocity and attitude errors.

    Args:
        state: (K, ≥9) true states.
        pose_cov: (K, 9, 9) bound on the pose covariance at those states.

    Returns:
        ``pos_m2``, ``vel_m2ps2``, ``att_rad2`` (K,): the traces of the bounds on the
        position, inertial-velocity and attitude rotation-vector errors (lower bounds of the
        expected squared error norms); ``pos_var_axes`` (K, 3), ``vel_var_axes`` (K, 3)
        (inertial) and ``euler_var_axes`` (K, 3) per axis.
    """
    K = state.shape[0]
    vel = np.empty((K, 3, 3))
    att = np.empty((K, 3, 3))
    for k in range(K):
        T_v, T_a = error_transforms(state[k])
        vel[k] = T_v @ pose_cov[k, 3:9, 3:9] @ T_v.T
        att[k] = T_a @ pose_cov[k, EUL, EUL] @ T_a.T
    pos_axes = np.diagonal(pose_cov[:, POS, POS], axis1=1, axis2=2)
    vel_axes = np.diagonal(vel, axis1=1, axis2=2)
    return {
        "pos_m2": pos_axes.sum(axis=1),
        "vel_m2ps2": vel_axes.sum(axis=1),
        "att_rad2": np.trace(att, axis1=1, axis2=2),
        "pos_var_axes": pos_axes.copy(),
        "vel_var_axes": vel_axes.copy(),
        "euler_var_axes": np.diagonal(pose_cov[:, EUL, EUL], axis1=1, axis2=2).copy(),
    }


def map_error_bound(landmark_var: FloatArray, mapped: np.ndarray | None = None) -> FloatArray:
    """Mean-square bound of the map RMSE, eq. (2): ``(1/n) Σ_j tr B_{l_j l_j}`` per step.

    Args:
        landmark_var: (K, L, 3) per-axis variance bounds of the landmarks
            (:attr:`BoundResult.landmark_var`), NaN for a landmark not yet seen.
        mapped: (K, L) bool, the landmarks the estimate has mapped at each step (those the
            metric averages over), or ``None`` for every landmark the bound has seen.

    Returns:
        (K,) in m², NaN at a step with no landmark in the set.
    """
    trace = landmark_var.sum(axis=2)
    use = np.isfinite(trace) if mapped is None else np.asarray(mapped, bool) & np.isfinite(trace)
    count = use.sum(axis=1)
    total = np.where(use, trace, 0.0).sum(axis=1)
    out = np.full(trace.shape[0], np.nan)
    np.divide(total, count, out=out, where=count > 0)
    return out
