"""The stacked Kalman correction of EKF-SLAM and its Gauss–Newton iteration (numba kernels).

:func:`stacked_gain` (seed 001 eq. 41–43): with ``S = L Lᵀ`` (Cholesky), ``Wᵀ = L⁻¹ U``
(``U = H P``) and ``z = L⁻¹ ν``, so that ``K ν = W z`` and ``K S Kᵀ = W Wᵀ``.

:func:`relinearise`: the iterated update (Bell & Cathey 1993, "The iterated Kalman filter
update as a Gauss–Newton method", IEEE TAC 38(2)). The first-order update linearises h at the
prior mean x⁻. When the correction is large against the measurement's scale — after a long
gap without landmarks, a position error of metres at 10–20 m range turns the bearings by
degrees — h(x⁺) departs from that linearisation, the update stops short and its covariance is
far too small: every later scan then fails the χ² gate and the filter dead-reckons with the
landmarks in view. The iterated update is the Gauss–Newton solution of the same MAP problem,

    x_{i+1} = x⁻ + K_i (y − h(x_i) − H_i (x⁻ − x_i)),   K_i from H_i = ∂h/∂x at x_i,

repeated until an iterate moves the predicted measurements by less than
:data:`CONVERGED` noise stds, with ``P⁺ = P⁻ − K_i S_i K_iᵀ`` at the last iterate. It runs only
when the first-order update's linearisation error ``h(x⁺) − h(x⁻) − H (x⁺ − x⁻)`` exceeds
``tol`` noise stds on some channel (``estimator.params.relinearise_tolerance``), so ordinary
updates are the first-order ones bit for bit.
"""

from __future__ import annotations

import math

import numpy as np

from quadslam_env.models.frames import dcm_and_partials, wrap_pi
from quadslam_env.models.jit import inline_kernel, kernel
from quadslam_env.models.lidar import lidar_models
from quadslam_env.models.linalg import cholesky_lower
from quadslam_env.types import POS, FloatArray

CONVERGED = 0.01
"""An iterate that moves every predicted measurement by less than this many noise stds ends
the iteration."""


@kernel
def predicted_measurements(xb: FloatArray, lms: FloatArray, h: FloatArray, H: FloatArray) -> None:
    """``h`` (k, 3) and Jacobian blocks ``H`` (k, 3, 9) = ``[∂h/∂ρ, ∂h/∂Λ, ∂h/∂l]`` of the
    landmarks ``lms`` (k, 3) seen from the pose in ``xb`` (eq. 34, 40)."""
    C = np.empty((3, 3))
    dC = np.empty((3, 3, 3))
    dcm_and_partials(xb[6], xb[7], xb[8], C, dC)
    lidar_models(xb[POS], C, dC, lms, h, H)


@kernel
def _stacked_rows(Pb: FloatArray, nb: int, H: FloatArray, cols: np.ndarray, U: FloatArray) -> None:
    """``U = H P[idx, :n]`` (3k, n), with H given as blocks (k, 3, 9) over the columns
    ``ρ, Λ`` and the landmark's own ``cols[i] … cols[i] + 2`` (cols < 0: known landmark)."""
    P0, P1, P2, P6, P7, P8 = Pb[0], Pb[1], Pb[2], Pb[6], Pb[7], Pb[8]
    for i in range(H.shape[0]):
        c = cols[i]
        for r in range(3):
            h = H[i, r]
            h0, h1, h2, h3, h4, h5 = h[0], h[1], h[2], h[3], h[4], h[5]
            Ur = U[3 * i + r]
            # One expression per output row: LLVM vectorises it over j (measured 3.5x faster
            # than updating three rows in one loop, which defeats its alias analysis).
            for j in range(nb):
                Ur[j] = h0 * P0[j] + h1 * P1[j] + h2 * P2[j] + h3 * P6[j] + h4 * P7[j] + h5 * P8[j]
            if c >= 0:
                h6, h7, h8 = h[6], h[7], h[8]
                La, Lb, Lc = Pb[c], Pb[c + 1], Pb[c + 2]
                for j in range(nb):
                    Ur[j] = Ur[j] + h6 * La[j] + h7 * Lb[j] + h8 * Lc[j]


@kernel
def innovation_covariance(
    xb: FloatArray,
    Pb: FloatArray,
    nb: int,
    lms: FloatArray,
    cols: np.ndarray,
    r_diag: FloatArray,
    h: FloatArray,
    U: FloatArray,
    S: FloatArray,
) -> None:
    """Predictions and joint innovation covariance of k landmarks seen from one lane's pose.

    Writes ``h`` (k, 3) the predicted (α, β, δ) (eq. 34), ``U`` (3k, n) = ``H P[:n, :n]``
    and ``S`` (3k, 3k) = ``H P Hᵀ + R`` (eq. 38) for the landmarks ``lms`` (k, 3) whose state
    columns start at ``cols`` (k,) (-1: known landmarks, not in the state).
    """
    k = lms.shape[0]
    H = np.empty((k, 3, 9))
    predicted_measurements(xb, lms, h, H)
    _stacked_rows(Pb, nb, H, cols, U)
    for a in range(3 * k):
        Ua = U[a]
        for i in range(k):
            c = cols[i]
            for r in range(3):
                acc = 0.0
                for t in range(3):
                    acc += Ua[t] * H[i, r, t] + Ua[6 + t] * H[i, r, 3 + t]
                    if c >= 0:
                        acc += Ua[c + t] * H[i, r, 6 + t]
                S[a, 3 * i + r] = acc
        S[a, a] += r_diag[a % 3]


@kernel
def stacked_gain(
    S: FloatArray, U: FloatArray, nu: FloatArray, idx: np.ndarray, Wt: FloatArray, z: FloatArray
) -> bool:
    """``Wᵀ = L⁻¹ U[idx]`` into ``Wt`` (m, n) and ``z = L⁻¹ ν[idx]`` into ``z`` (m,), where
    ``L Lᵀ = S[idx][:, idx]`` (m = len(idx)); returns False if that block is not positive
    definite (``Wt``, ``z`` are then undefined)."""
    m = idx.shape[0]
    nb = U.shape[1]
    L = np.empty((m, m))
    for a in range(m):
        for c in range(a + 1):
            L[a, c] = S[idx[a], idx[c]]
    if not cholesky_lower(L):
        return False
    # Forward substitution, so that K = W L⁻¹ and K ν = W z.
    for a in range(m):
        Wa, Ua = Wt[a], U[idx[a]]
        for k in range(Wa.shape[0]):  # unsigned index: a vectorised copy (kernels.store_rows)
            j = np.uint64(k)
            Wa[j] = Ua[j]
        za = nu[idx[a]]
        a4 = a - a % 4
        # Four rows per pass over Wa (same operation order as one at a time): fewer
        # loads and stores of Wa per multiply-add.
        for c in range(0, a4, 4):
            l0, l1, l2, l3 = L[a, c], L[a, c + 1], L[a, c + 2], L[a, c + 3]
            W0, W1, W2, W3 = Wt[c], Wt[c + 1], Wt[c + 2], Wt[c + 3]
            for j in range(nb):
                Wa[j] = Wa[j] - l0 * W0[j] - l1 * W1[j] - l2 * W2[j] - l3 * W3[j]
        for c in range(a4, a):
            lac = L[a, c]
            Wc = Wt[c]
            for j in range(nb):
                Wa[j] -= lac * Wc[j]
        for c in range(a):
            za -= L[a, c] * z[c]
        inv = L[a, a]
        for j in range(nb):
            Wa[j] /= inv
        z[a] = za / inv
    return True


@kernel
def correction(Wt: FloatArray, z: FloatArray, dx: FloatArray) -> None:
    """``dx = W z`` (n,) for ``Wt = Wᵀ`` (m, n), z (m,)."""
    dx[:] = 0.0
    for a in range(Wt.shape[0]):
        Wa = Wt[a]
        za = z[a]
        for j in range(dx.shape[0]):
            dx[j] += Wa[j] * za


@kernel
def _models(
    xb: FloatArray, lms: FloatArray, cols: np.ndarray, h: FloatArray, H: FloatArray
) -> None:
    """h (k, 3) and H blocks (k, 3, 9) of landmarks ``lms`` (k, 3) from the pose in ``xb``;
    landmarks with a state column (``cols`` ≥ 0) are first read from ``xb``."""
    for i in range(cols.shape[0]):
        c = cols[i]
        if c >= 0:
            lms[i, 0], lms[i, 1], lms[i, 2] = xb[c], xb[c + 1], xb[c + 2]
    predicted_measurements(xb, lms, h, H)


@kernel
def _apply_jacobian(H: FloatArray, cols: np.ndarray, d: FloatArray, out: FloatArray) -> None:
    """``out`` (3k,) = H d for H as blocks (k, 3, 9) over ρ, Λ and each landmark's columns."""
    for i in range(H.shape[0]):
        c = cols[i]
        for r in range(3):
            acc = 0.0
            for t in range(3):
                acc += H[i, r, t] * d[t] + H[i, r, 3 + t] * d[6 + t]
                if c >= 0:
                    acc += H[i, r, 6 + t] * d[c + t]
            out[3 * i + r] = acc


@kernel
def _largest_scaled(v: FloatArray, sigma: FloatArray) -> float:
    """max over the channels of |v| / σ (v (3k,) in (α, β, δ) triples, angles wrapped)."""
    worst = 0.0
    for a in range(v.shape[0]):
        r = a % 3
        e = wrap_pi(v[a]) if r < 2 else v[a]
        worst = max(worst, abs(e) / sigma[r])
    return worst


@inline_kernel
def _first_order_error(
    xb: FloatArray,
    lms: FloatArray,
    cols: np.ndarray,
    dx: FloatArray,
    hi: FloatArray,
    sigma: FloatArray,
) -> float:
    """How far the first-order update is from linear, in noise stds: the largest
    ``|h(x⁻ + dx) − h(x⁻) − H(x⁻) dx| / σ`` over the k landmarks' channels.

    Args:
        xb: (≥n,) prior mean x⁻. lms: (k, 3) the landmarks at x⁻ (N, m; not modified).
        cols: (k,) their first state column (-1: known landmark).
        dx: (n,) first-order correction. hi: (k, 3) ``h(x⁻ + dx)``.
        sigma: (3,) measurement noise stds.
    """
    k = lms.shape[0]
    h0 = np.empty((k, 3))
    H0 = np.empty((k, 3, 9))
    _models(xb, lms.copy(), cols, h0, H0)
    lin = np.empty(3 * k)
    _apply_jacobian(H0, cols, dx, lin)
    err = np.empty(3 * k)
    for i in range(k):
        for r in range(3):
            err[3 * i + r] = hi[i, r] - h0[i, r] - lin[3 * i + r]
    return _largest_scaled(err, sigma)


@inline_kernel
def _take_iterate(
    dn: FloatArray, Wn: FloatArray, zn: FloatArray, dx: FloatArray, Wt: FloatArray, z: FloatArray
) -> bool:
    """Copy an iterate's correction ``dn`` (n,), ``Wᵀ`` and ``z`` into ``dx``, ``Wt``, ``z``;
    False (nothing copied) when ``dn`` is not finite."""
    nb = dn.shape[0]
    for j in range(nb):
        if not math.isfinite(dn[j]):
            return False
    for j in range(nb):  # element by element: see estimators.ekf.update
        dx[j] = dn[j]
    for a in range(Wt.shape[0]):
        for j in range(Wt.shape[1]):
            Wt[a, j] = Wn[a, j]
    for a in range(z.shape[0]):
        z[a] = zn[a]
    return True


@kernel
def relinearise(
    xb: FloatArray,
    Pb: FloatArray,
    nb: int,
    lms: FloatArray,
    cols: np.ndarray,
    y: FloatArray,
    r_diag: FloatArray,
    tol: float,
    max_iter: int,
    dx: FloatArray,
    Wt: FloatArray,
    z: FloatArray,
) -> int:
    """Iterate the correction of one lane when its first-order update is not linear enough.

    Args:
        xb: (≥n,) prior mean x⁻ (not modified). Pb: (≥n, ≥n) prior covariance (not modified).
        nb: State size n.
        lms: (k, 3) the accepted landmarks' positions at x⁻ (N, m); overwritten.
        cols: (k,) their first state column (-1: known landmark).
        y: (k, 3) their measurements (α rad, β rad, δ m).
        r_diag: (3,) measurement noise variances.
        tol: Linearisation error, in noise stds, that starts the iteration.
        max_iter: Most iterations.
        dx: (n,) first-order correction ``x⁺ − x⁻``; receives the iterated one.
        Wt: (3k, n) and z (3k,): the first-order ``Wᵀ`` and ``z``; receive the last iterate's.

    Returns:
        The iterations made: 0 when the first-order update stands (linear enough, or an
        iterate's S was not positive definite).
    """
    k = lms.shape[0]
    m = 3 * k
    sigma = np.sqrt(r_diag)
    xi = xb[:nb] + dx[:nb]
    lms_i = lms.copy()
    hi = np.empty((k, 3))
    Hi = np.empty((k, 3, 9))
    _models(xi, lms_i, cols, hi, Hi)
    if _first_order_error(xb, lms, cols, dx, hi, sigma) <= tol:
        return 0
    idx = np.arange(m)
    U = np.empty((m, nb))
    S = np.empty((m, m))
    nu = np.empty(m)
    Wn = np.empty((m, nb))
    zn = np.empty(m)
    dn = np.empty(nb)
    shift = np.empty(m)
    step = np.empty(nb)
    done = 0
    for it in range(1, max_iter + 1):
        innovation_covariance(xi, Pb, nb, lms_i, cols, r_diag, hi, U, S)
        _models(xi, lms_i, cols, hi, Hi)
        for j in range(nb):
            step[j] = xi[j] - xb[j]
        _apply_jacobian(Hi, cols, step, shift)
        for i in range(k):  # y − h(x_i) − H_i (x⁻ − x_i)
            nu[3 * i] = wrap_pi(y[i, 0] - hi[i, 0]) + shift[3 * i]
            nu[3 * i + 1] = wrap_pi(y[i, 1] - hi[i, 1]) + shift[3 * i + 1]
            nu[3 * i + 2] = y[i, 2] - hi[i, 2] + shift[3 * i + 2]
        if not stacked_gain(S, U, nu, idx, Wn, zn):
            return done
        correction(Wn, zn, dn)
        for j in range(nb):
            step[j] = xb[j] + dn[j] - xi[j]
        _apply_jacobian(Hi, cols, step, shift)
        if not _take_iterate(dn, Wn, zn, dx, Wt, z):
            return done
        done = it
        for j in range(nb):
            xi[j] = xb[j] + dn[j]
        if _largest_scaled(shift, sigma) <= CONVERGED:
            break
    return done
