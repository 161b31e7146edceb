"""Numba kernels of EKF-SLAM's landmark registration: the landmarks a scan observes for the
first time enter the state from the pose (seed 001 eq. 44–53).

:func:`register_new` is called by :func:`estimators.ekf.update.update_lanes` after a lane's
correction.
"""

from __future__ import annotations

import numpy as np

from estimators.ekf.kernels import D_DIVERGED, D_N_MAPPED
from quadslam_env.models.frames import dcm_and_partials
from quadslam_env.models.jit import inline_kernel, kernel
from quadslam_env.models.lidar import lidar_inverse_models
from quadslam_env.types import POS, FloatArray


@kernel
def inverse_measurements(
    xb: FloatArray,
    Pb: FloatArray,
    nb: int,
    y: FloatArray,
    r_diag: FloatArray,
    lms: FloatArray,
    Plx: FloatArray,
    Pll: FloatArray,
) -> None:
    """Landmarks observed as ``y`` (kn, 3) from one lane's pose, with their covariances.

    ``lms`` (kn, 3) = ``g(ŝ, y) = ρ + C_NB ϱ(y)`` (eq. 44), ``Plx`` (3kn, nb) =
    ``G_s P[s, :nb]`` (eq. 50) and ``Pll`` (3kn, 3kn) = ``G_s P_ss G_sᵀ + G_y R G_yᵀ`` (eq. 48,
    exactly symmetric), with ``G_s = [I, 0, ∂g/∂Λ]``. With ``nb = 9`` this is the pose-only
    part (what a landmark candidate outside the state needs).
    """
    kn = y.shape[0]
    C = np.empty((3, 3))
    dC = np.empty((3, 3, 3))
    dcm_and_partials(xb[6], xb[7], xb[8], C, dC)
    G_eul = np.empty((kn, 3, 3))
    G_y = np.empty((kn, 3, 3))
    P6, P7, P8 = Pb[6], Pb[7], Pb[8]
    lidar_inverse_models(xb[POS], C, dC, y, lms, G_eul, G_y)
    for i in range(kn):
        for r in range(3):
            g0, g1, g2 = G_eul[i, r, 0], G_eul[i, r, 1], G_eul[i, r, 2]
            Pr, row = Pb[r], Plx[3 * i + r]
            for j in range(nb):
                row[j] = Pr[j] + (g0 * P6[j] + g1 * P7[j] + g2 * P8[j])
    ml = 3 * kn
    for a in range(ml):
        for i in range(kn):
            for r in range(3):
                acc = Plx[a, r]
                for c in range(3):
                    acc += Plx[a, 6 + c] * G_eul[i, r, c]
                Pll[a, 3 * i + r] = acc
    for i in range(kn):  # + G_y R G_yᵀ on the diagonal blocks (eq. 48)
        for r in range(3):
            for t in range(3):
                acc = 0.0
                for c in range(3):
                    acc += (G_y[i, r, c] * r_diag[c]) * G_y[i, t, c]
                Pll[3 * i + r, 3 * i + t] += acc
    for a in range(ml):
        for c in range(a):
            v = 0.5 * (Pll[a, c] + Pll[c, a])
            Pll[a, c] = v
            Pll[c, a] = v


@kernel
def register(
    xb: FloatArray,
    Pb: FloatArray,
    nb: int,
    y: FloatArray,
    r_diag: FloatArray,
) -> bool:
    """Augment one lane's x and P with the landmarks observed as ``y`` (kn, 3) (eq. 44–53).

    ``l = g(ŝ⁺, y) = ρ + C_NB ϱ(y)``, ``P_ll = G_s P_ss G_sᵀ + G_y R G_yᵀ``,
    ``P_lx = G_s [P_ss P_sm]`` with ``G_s = [I, 0, ∂g/∂Λ]``. All new landmarks of the scan go
    in as one block; this equals registering them one at a time (eq. 46–53), since
    registration leaves ŝ unchanged and the cross-covariance of two new landmarks is
    ``G_si P_ss G_sjᵀ`` either way. Returns False (nothing written) on a non-finite result.
    """
    kn = y.shape[0]
    ml = 3 * kn
    lms = np.empty((kn, 3))
    Plx = np.empty((ml, nb))  # eq. 50
    Pll = np.empty((ml, ml))
    inverse_measurements(xb, Pb, nb, y, r_diag, lms, Plx, Pll)
    if not (np.isfinite(lms).all() and np.isfinite(Pll).all() and np.isfinite(Plx).all()):
        return False
    if nb + ml > xb.shape[0]:
        raise ValueError("EKF-SLAM registration beyond the state capacity")
    for a in range(ml):
        Pa, Ra = Pb[nb + a], Plx[a]
        for j in range(nb):
            Pa[j] = Ra[j]
            Pb[j, nb + a] = Ra[j]
        for c in range(ml):
            Pa[nb + c] = Pll[a, c]
    for i in range(kn):
        for r in range(3):
            xb[nb + 3 * i + r] = lms[i, r]
    return True


@inline_kernel
def register_new(
    b: int,
    new: np.ndarray,
    x: FloatArray,
    P: FloatArray,
    n: np.ndarray,
    nv: int,
    meas: FloatArray,
    r_diag: FloatArray,
    slot_of_id: np.ndarray,
    id_of_slot: np.ndarray,
    mapped: np.ndarray,
    diag: FloatArray,
) -> None:
    """Register lane ``b``'s unmapped observed ids ``new`` (k,) in ascending order (eq.
    44–53), or flag the lane diverged if the result is not finite."""
    k, nb = new.shape[0], n[b]
    y = np.empty((k, 3))
    for i in range(k):
        for r in range(3):
            y[i, r] = meas[b, new[i], r]
    if not register(x[b], P[b], nb, y, r_diag):
        diag[D_DIVERGED, b] = 1.0
        return
    nm = (nb - nv) // 3
    for i in range(k):
        slot_of_id[b, new[i]] = nm + i
        id_of_slot[b, nm + i] = new[i]
        mapped[b, new[i]] = True
    n[b] = nb + 3 * k
    diag[D_N_MAPPED, b] = nm + k
