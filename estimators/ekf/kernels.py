"""Numba kernels of the batched EKF-SLAM: prediction over lanes, column sync and outputs.

Every kernel works on one lane's slices of the batch arrays (``x[b]`` (nmax,), ``P[b]``
(nmax, nmax)) or loops over the lanes itself, so the Python layer calls one compiled function
per batch operation. ``fastmath`` stays off (IEEE semantics, no reassociation): the loops are
written with the contiguous index innermost so LLVM vectorises them anyway.

Diagnostics of all lanes live in one (15, B) float array whose rows are indexed by the ``D_*``
constants below, so :meth:`EkfSlamBatch.estimate` hands out row views without conversion.
"""

from __future__ import annotations

import math

import numpy as np

from quadslam_env.estimation.integrity import COUNT_KEYS, SEPARATION_KEYS
from quadslam_env.models.frames import dcm_and_partials, wrap_pi
from quadslam_env.models.jit import inline_kernel, kernel
from quadslam_env.models.strapdown import strapdown_jacobians, strapdown_rk4
from quadslam_env.types import POSE_DIM, FloatArray

D_NIS, D_NIS_DOF, D_N_REJECTED, D_N_REJECTED_LAST, D_N_UPDATES, D_N_MAPPED, D_DIVERGED = range(7)
D_FDE_TESTS, D_FDE_ALARMS, D_FDE_EXCLUSIONS, D_FDE_UNRESOLVED = range(7, 11)
D_SEPARATION = 11
"""First of the rows (N, E, D separation variances, then the hypotheses) of the monitor's last
scan (:data:`quadslam_env.estimation.integrity.SEPARATION_KEYS`)."""
DIAGNOSTIC_NAMES = (
    "nis",
    "nis_dof",
    "n_rejected",
    "n_rejected_last",
    "n_updates",
    "n_mapped",
    "diverged",
    *COUNT_KEYS,
    *SEPARATION_KEYS,
)
"""Names of the rows of the diagnostics array, in row order (keys of a snapshot's diagnostics);
the integrity monitor's (:mod:`estimators.ekf.fde`) stay 0 without it."""

MAX_PITCH = math.radians(89.0)
"""|θ̂| beyond which D(Λ) (1/cos θ) is treated as singular and the lane flagged diverged."""


@inline_kernel
def discretise(
    A: FloatArray,
    nv: int,
    G: FloatArray,
    sa: float,
    sg: float,
    M: FloatArray,
    Phi: FloatArray,
    Gam: FloatArray,
) -> None:
    """``M = I + ½A``, ``Φ = I + A M`` and ``Γ = M G diag(σ_a, σ_ω, σ_ω, σ_ω[, σ_a, σ_a]) dt``
    from ``A = F dt`` (nv, nv) and ``G`` (9, nλ) (seed 001 eq. 27; :func:`transition_matrices`,
    whose ``sa``, ``sg`` carry the dt); the bias and wind rows of G are zero."""
    # The products run with the output index innermost (independent sums, same k order) and
    # skip the many exact zeros of A.
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
                for j in range(4, G.shape[1]):
                    Gam[i, j] += a * (G[k, j] * sa)


@kernel
def transition_matrices(
    xb: FloatArray,
    nv: int,
    p: float,
    q: float,
    r: float,
    sa: float,
    sg: float,
    dt: float,
    F: FloatArray,
    G: FloatArray,
    A: FloatArray,
    M: FloatArray,
    Phi: FloatArray,
    Gam: FloatArray,
) -> None:
    """Discrete transition ``Φ`` and noise input ``Γ`` of one IMU sample (seed 001 eq. 27–28).

    ``A = F dt`` over ``(s, b)`` (the biases enter through ``λ = λ̃ - b``, so ``∂f/∂b = -G``),
    ``M = I + ½A``, ``Φ = I + A M = I + A + ½A²`` (eq. 27 to second order) and
    ``Γ = M G diag(σ_a, σ_ω, σ_ω, σ_ω[, σ_a, σ_a]) dt``: the IMU white noise (per-sample std
    held over the sample) mapped into the state, so that ``Q_d = Γ Γᵀ + Q dt``
    (:func:`propagate_covariance`). The EKF evaluates this at its estimate; the posterior
    Cramér–Rao bound (:mod:`estimators.pcrb`) at the true state. With the whole specific force
    (``G`` of 6 columns, :mod:`quadslam_env.models.strapdown`) the horizontal accelerometer
    axes are two more inputs, and with their biases (nv = 15) two more bias columns.

    Args:
        xb: (≥nv,) state whose first 9 entries are the linearisation point s.
        nv: Vehicle-state size (9; 13 with the biases (b_ω, b_az); 15 with (b_ω, b_az, b_ax,
            b_ay), the whole specific force's).
        p, q, r: Bias-corrected body rates in rad/s.
        sa: Accelerometer white-noise std times dt (0: no IMU noise in Q_d).
        sg: Gyro white-noise std times dt (0 likewise).
        dt: Sample period in s.
        F: (9, 9) receives ``∂f_s/∂s``; G: (9, nλ) receives ``∂f_s/∂λ`` (nλ = 4, or 6 for
            the whole specific force).
        A, M, Phi: (nv, nv) receive ``F dt`` (bias columns included), ``I + ½A`` and ``Φ``.
        Gam: (nv, nλ) receives ``Γ``.
    """
    strapdown_jacobians(xb, p, q, r, F, G)
    full = G.shape[1] > 4
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
        if full and nv > POSE_DIM + 4:
            A[i, 13], A[i, 14] = -G[i, 4] * dt, -G[i, 5] * dt
    discretise(A, nv, G, sa, sg, M, Phi, Gam)


@kernel
def propagate_covariance(
    Pb: FloatArray,
    nb: int,
    nv: int,
    Phi: FloatArray,
    Gam: FloatArray,
    qc: FloatArray,
    dt: float,
    T: FloatArray,
    Pvv: FloatArray,
) -> bool:
    """Covariance prediction of eq. 27/29 into scratch, without touching ``Pb``.

    ``T = Φ P[:nv, :n]`` (the rows of the vehicle block and its cross-covariances, eq. 29) and
    ``P_vv = ½(X + Xᵀ) + Γ Γᵀ + Q dt`` with ``X = T[:, :nv] Φᵀ = Φ P_vv Φᵀ`` (eq. 27);
    :func:`store_rows` writes them back. Returns False if a result is not finite.

    Args:
        Pb: (≥n, ≥n) covariance whose rows ``:nv`` and the block ``[:nv, :nv]`` are current.
        nb: State size n.
        nv: Vehicle-state size.
        Phi: (nv, nv) transition; Gam: (nv, nλ) noise input (:func:`transition_matrices`).
        qc: (nv,) diagonal of the continuous process-noise density.
        dt: Sample period in s.
        T: (nv, ≥n) receives ``Φ P[:nv, :n]``.
        Pvv: (nv, nv) receives the predicted vehicle block.
    """
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
    for i in range(nv):
        for j in range(i + 1):
            xij = 0.0
            xji = 0.0
            for k in range(nv):
                xij += T[i, k] * Phi[j, k]
                xji += T[j, k] * Phi[i, k]
            gg = 0.0
            for k in range(Gam.shape[1]):
                gg += Gam[i, k] * Gam[j, k]
            v = (xij + xji) * 0.5 + gg
            if i == j:
                v += qc[i] * dt
            Pvv[i, j] = v
            Pvv[j, i] = v
            finite &= v * 0.0 == 0.0
    return finite


@kernel
def store_rows(Pb: FloatArray, nb: int, nv: int, T: FloatArray, Pvv: FloatArray) -> None:
    """Write the prediction of :func:`propagate_covariance` into the rows ``P[:nv, :n]``; the
    mirrored columns ``P[nv:n, :nv]`` become stale (:func:`sync_lane` rebuilds them)."""
    # Element loops, not slice copies (see fill_outputs); unsigned indices spare the
    # negative-index wrap-around, so LLVM vectorises the copies (faster than the slices were).
    for i in range(nv):
        for j in range(nv):
            Pb[i, j] = Pvv[i, j]
        for k in range(nv, nb):
            j = np.uint64(k)
            Pb[i, j] = T[i, j]


@kernel
def _predict_lane(
    xb: FloatArray,
    Pb: FloatArray,
    nb: int,
    nv: int,
    ax: float,
    ay: float,
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
    stages, y, F, G, A, M, Phi, Gam, Pvv, T = work
    # Mean: RK4 on y = (s, ω) with ω and the specific force held (eq. 26); ŝ⁺ = y[:9].
    for i in range(POSE_DIM):
        y[i] = xb[i]
    y[9], y[10], y[11] = p, q, r
    strapdown_rk4(y, ax, ay, az, dt, stages)
    s_new = y[:POSE_DIM]
    # Covariance: Jacobians at the prior mean, P_vv ← Φ P_vv Φᵀ + Q_d, P_vm ← Φ P_vm.
    transition_matrices(xb, nv, p, q, r, sa, sg, dt, F, G, A, M, Phi, Gam)
    finite = propagate_covariance(Pb, nb, nv, Phi, Gam, qc, dt, T, Pvv)
    return commit_prediction(xb, Pb, nb, nv, s_new, T, Pvv, finite)


@inline_kernel
def commit_prediction(
    xb: FloatArray,
    Pb: FloatArray,
    nb: int,
    nv: int,
    s_new: FloatArray,
    T: FloatArray,
    Pvv: FloatArray,
    finite: bool,
) -> bool:
    """Write one lane's predicted mean ``s_new`` (9,) and covariance rows (``T``, ``P_vv`` of
    :func:`propagate_covariance`) into ``xb``, ``Pb``, angles wrapped; returns False and changes
    nothing when the result is not ``finite`` or the pitch reaches :data:`MAX_PITCH` (every
    process model's prediction ends here)."""
    for i in range(POSE_DIM):
        finite &= s_new[i] * 0.0 == 0.0
    if not (finite and abs(s_new[7]) < MAX_PITCH):
        return False
    store_rows(Pb, nb, nv, T, Pvv)
    s_new[6] = wrap_pi(s_new[6])
    s_new[8] = wrap_pi(s_new[8])
    for i in range(POSE_DIM):
        xb[i] = s_new[i]
    return True


@kernel
def predict_work(nv: int, nmax: int, nl: int) -> tuple:
    """Scratch of :func:`_predict_lane`: RK4 work (6, 12), y = (s, ω) (12,), F (9, 9), G (9, nλ),
    A, M, Φ (nv, nv), Γ (nv, nλ), P_vv (nv, nv) and T (nv, nmax) (nλ = ``nl``, 4 or 6)."""
    return (
        np.empty((6, 12)),
        np.empty(12),
        np.empty((POSE_DIM, POSE_DIM)),
        np.empty((POSE_DIM, nl)),
        np.empty((nv, nv)),
        np.empty((nv, nv)),
        np.empty((nv, nv)),
        np.empty((nv, nl)),
        np.empty((nv, nv)),
        np.empty((nv, nmax)),
    )


@kernel
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
    full: bool,
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
        diag: (15, B) diagnostics (row ``D_DIVERGED`` is set on failure).
        active: (B,) bool, lanes to propagate.
        accel: (B, 3) measured specific force in m/s² (only the z column is used, eq. 25,
            unless ``full``).
        gyro: (B, 3) measured body rates in rad/s.
        full: The whole specific force (:mod:`quadslam_env.models.strapdown`); its biases
            (b_ax, b_ay) are the states 13–14 when nv = 15.
        sa: Accelerometer white-noise std times dt (0 to leave IMU noise out of Q_d).
        sg: Gyro white-noise std times dt (0 likewise).
        dt: Sample period in s.
        qc: (nv,) diagonal of the continuous process-noise density.
    """
    work = predict_work(nv, x.shape[1], 6 if full else 4)
    for b in range(x.shape[0]):
        if not active[b]:
            continue
        xb = x[b]
        p, q, r, az = gyro[b, 0], gyro[b, 1], gyro[b, 2], accel[b, 2]
        ax = accel[b, 0] if full else 0.0
        ay = accel[b, 1] if full else 0.0
        if nv > POSE_DIM:
            p -= xb[9]
            q -= xb[10]
            r -= xb[11]
            az -= xb[12]
        if nv > POSE_DIM + 4:
            ax -= xb[13]
            ay -= xb[14]
        if _predict_lane(xb, P[b], n[b], nv, ax, ay, az, p, q, r, sa, sg, dt, qc, work):
            stale[b] = stale[b] or n[b] > nv
            rates[b, 0], rates[b, 1], rates[b, 2] = p, q, r
        else:
            diag[D_DIVERGED, b] = 1.0


@kernel
def sync_lane(Pb: FloatArray, nb: int, nv: int) -> None:
    """Rebuild the stale columns ``P[nv:n, :nv]`` of one lane from the rows ``P[:nv, nv:n]``."""
    for i in range(nv, nb):
        Pi = Pb[i]
        for j in range(nv):
            Pi[j] = Pb[j, i]


# ---------------------------------------------------------------------- outputs
@kernel
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
            if mapped[b, j]:  # element by element: an array assignment would compile numba's
                c = nv + 3 * slot_of_id[b, j]  # shape-mismatch message (~2 s of first use)
                for i in range(3):
                    landmark_means[b, j, i] = known_pos[b, j, i] if known[b] else xb[c + i]


@kernel
def remove_landmark(
    xb: FloatArray,
    Pb: FloatArray,
    nb: int,
    nv: int,
    slot_of_id: np.ndarray,
    id_of_slot: np.ndarray,
    label: int,
) -> None:
    """Delete landmark ``label`` from one lane's state: its 3 entries of x and rows and
    columns of P (marginalisation); later slots move down by one. The caller sets
    ``n -= 3`` and unmaps the label."""
    s = slot_of_id[label]
    c = nv + 3 * s
    m = nb - 3
    for i in range(c, m):
        xb[i] = xb[i + 3]
        for j in range(nb):
            Pb[i, j] = Pb[i + 3, j]
    for i in range(m):
        for j in range(c, m):
            Pb[i, j] = Pb[i, j + 3]
    for i in range(m, nb):
        xb[i] = 0.0
        for j in range(nb):
            Pb[i, j] = 0.0
            Pb[j, i] = 0.0
    n_slots = (nb - nv) // 3
    for t in range(s, n_slots - 1):
        id_of_slot[t] = id_of_slot[t + 1]
        slot_of_id[id_of_slot[t]] = t
    id_of_slot[n_slots - 1] = -1
    slot_of_id[label] = -1
