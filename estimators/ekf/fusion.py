"""Map fusion of EKF-SLAM: another vehicle's landmark estimates fused into one lane's state
(docs/team-fusion.md).

A message is k landmark estimates of another vehicle, by landmark id: means ``y_j`` (k, 3) and
either the sender's joint covariance ``Q`` (3k, 3k) of them or only its 3×3 blocks ``Q_jj``
(k, 3, 3), in the N frame both vehicles share (known start poses, known association). Of them,
the landmarks the lane has mapped are fused in one step as a linear measurement of its stacked
landmark block: ``z = (y_j)``, ``H`` selecting the columns of those landmarks in x.

**Covariance intersection** (``ci``; Julier & Uhlmann 1997, "A non-divergent estimation
algorithm in the presence of unknown correlations", Proc. ACC; Uijt de Haag & Martens §2
eq. 17). The errors of the lane's state and of the message are correlated in an unknown way
(the vehicles exchange maps, so each one's map soon holds the other's information), and so are
the sender's landmarks among themselves (only their 3×3 blocks are sent). Both are covered:

- the stacked message is ``(y, R)`` with the sender's joint covariance, ``R = Q`` (the rows
  and columns of the fused landmarks); with only the blocks sent, ``R = k · blockdiag(Q_jj)``,
  consistent whatever the sender's cross-covariances, since ``Q ≤ k · blockdiag(Q_jj)`` for any
  positive semi-definite Q with those diagonal blocks (Cauchy–Schwarz:
  ``(Σ vⱼᵀeⱼ)² ≤ k Σ (vⱼᵀeⱼ)²``). The bound costs much: a vehicle's landmarks share the error
  of the poses it mapped them from (its initial position error, unobservable, most of it), so
  Q is close to that bound and the blocks carry about 1/k of the information;
- CI of the lane's whole state ``(x, P)`` with it, ``P⁺⁻¹ = ω P⁻¹ + (1 − ω) Hᵀ R_k⁻¹ H``,
  is consistent whatever the correlation between the two; it is the Kalman update of the prior
  ``(x, P / ω)`` by ``z`` with noise ``R_k / (1 − ω)``, which is how it is computed here (the
  vehicle states and the landmarks not in the message move through their correlations with the
  fused ones, and P stays one consistent joint covariance).

ω ∈ (0, 1) minimises the trace of the whole fused covariance ``tr P⁺(ω)`` (:func:`ci_weight`,
convex in ω; with one landmark as the whole state, the textbook two-estimate rule). The trace of
the fused landmark block alone is not used: when the sender knows a landmark far better than the
lane it drives ω towards 0, and the P / ω of every other state with it (measured: the vehicles'
pose covariances diverged on the figure-8, docs/team.md). A message of k landmarks is fused once
rather than landmark by landmark, since each CI step divides all of P by its ω.

**Naive** (``naive``): the same update with ω = 1 and ``R = Q`` (or ``blockdiag(Q_jj)``), a
Kalman update as if the message were independent of the lane's state and its landmarks of
each other; kept to show what double counting does (the fused covariance shrinks below the errors).

A landmark of the message the lane has not mapped is left out (not registered): its estimate
from the message has an unknown correlation with the lane's vehicle states, and entering it with
zero cross-covariance would be inconsistent; the lane maps it when it sees it.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import block_diag

from estimators.ekf.correction import correction, stacked_gain
from estimators.ekf.kernels import D_DIVERGED
from estimators.ekf.state import EkfState
from estimators.ekf.update import subtract_outer
from quadslam_env.models.jit import kernel
from quadslam_env.types import FloatArray

FUSION_MODES = ("ci", "naive")
"""The fusion rules of :func:`fuse_lane`."""

OMEGA_MIN = 1e-6
"""ω is searched in ``[OMEGA_MIN, 1 − OMEGA_MIN]`` (ω = 0 or 1 would divide by zero)."""

_GOLD = 0.5 * (5.0**0.5 - 1.0)
_SECTIONS = 80
"""Golden-section steps: the interval shrinks by 0.618⁸⁰ ≈ 2·10⁻¹⁷, below float resolution."""


def ci_trace(
    P: FloatArray, idx: np.ndarray, R: FloatArray, A: FloatArray | None = None
) -> tuple[float, FloatArray, FloatArray, FloatArray]:
    """The trace of the CI-fused joint covariance as a function of ω, in closed form.

    The fused covariance of ``P`` (n, n) and a measurement of its entries ``idx`` (m,) with
    noise ``R`` (m, m) is the Kalman update of the prior ``P / ω`` by the noise ``R / (1 − ω)``,
    ``P⁺(ω) = (ω P⁻¹ + (1 − ω) Hᵀ R⁻¹ H)⁻¹``. With ``R = L Lᵀ`` and
    ``L⁻¹ P_mm L⁻ᵀ = V diag(d) Vᵀ`` (``P_mm = P[idx][:, idx]``), ``g = diag(Vᵀ L⁻¹ G L⁻ᵀ V)``
    for ``G = P[idx, :] P[:, idx]``,

        tr P⁺(ω) = (T − Σᵢ gᵢ (1 − ω) / (dᵢ (1 − ω) + ω)) / ω,   T = tr P,

    convex in ω (the matrix inverse is operator convex and its argument affine in ω). With
    ``idx`` every entry (H = I) this is the two-estimate CI, ``(ω P⁻¹ + (1 − ω) R⁻¹)⁻¹``.
    A measurement ``H = A`` on the entries ``idx`` (zero elsewhere) is the same with
    ``P_mm → A P_mm Aᵀ`` and ``P[idx, :] → A P[idx, :]`` (the derivation only uses ``H P Hᵀ``
    and ``H P``).

    Args:
        P: (n, n) the receiver's covariance (weight ω), positive definite.
        idx: (q,) int the measured entries.
        R: (m, m) the measurement's covariance (weight 1 − ω), positive definite.
        A: (m, q) the measurement's rows on the entries ``idx``; ``None``: the identity
            (H selects them, m = q).

    Returns:
        ``(T, g, d, V)``: the trace, (m,) ``g`` and ``d``, and (m, m) ``V``.

    Raises:
        numpy.linalg.LinAlgError: ``R`` is not positive definite.
    """
    L = np.linalg.cholesky(R)
    P_mm, rows = P[np.ix_(idx, idx)], P[idx, :]
    if A is not None:
        P_mm, rows = A @ P_mm @ A.T, A @ rows
    M = np.linalg.solve(L, np.linalg.solve(L, P_mm).T)  # L⁻¹ P_mm L⁻ᵀ
    d, V = np.linalg.eigh(0.5 * (M + M.T))
    C = np.linalg.solve(L, rows).T @ V  # (n, m): (Vᵀ L⁻¹ P[idx, :])ᵀ
    return float(np.trace(P)), np.einsum("ij,ij->j", C, C), np.maximum(d, 0.0), V


def fused_trace(omega: float, T: float, g: FloatArray, d: FloatArray) -> float:
    """``tr P⁺(ω)`` from :func:`ci_trace`'s terms."""
    w = 1.0 - omega
    return float((T - np.sum(g * w / (d * w + omega))) / omega)


def ci_weight(P: FloatArray, idx: np.ndarray, R: FloatArray, A: FloatArray | None = None) -> float:
    """ω ∈ [OMEGA_MIN, 1 − OMEGA_MIN] minimising the trace of the fused joint covariance
    (Julier & Uhlmann 1997's minimum-trace rule over the receiver's whole state).

    ``tr P⁺`` is convex in ω (:func:`ci_trace`), so a golden-section search finds its minimum.

    Args:
        P: (n, n) covariance of the estimate weighted ω.
        idx: (q,) int its entries measured.
        R: (m, m) covariance of the measurement weighted 1 − ω.
        A: (m, q) the measurement's rows on ``idx`` (``None``: the identity; :func:`ci_trace`).

    Returns:
        ω.
    """
    T, g, d, _ = ci_trace(P, idx, R, A)
    lo, hi = OMEGA_MIN, 1.0 - OMEGA_MIN
    a, b = hi - _GOLD * (hi - lo), lo + _GOLD * (hi - lo)
    fa, fb = fused_trace(a, T, g, d), fused_trace(b, T, g, d)
    for _ in range(_SECTIONS):
        if fa <= fb:
            hi, b, fb = b, a, fa
            a = hi - _GOLD * (hi - lo)
            fa = fused_trace(a, T, g, d)
        else:
            lo, a, fa = a, b, fb
            b = lo + _GOLD * (hi - lo)
            fb = fused_trace(b, T, g, d)
    return 0.5 * (lo + hi)


def fuse_lane(
    xb: FloatArray,
    Pb: FloatArray,
    nb: int,
    cols: np.ndarray,
    means: FloatArray,
    R: FloatArray,
    mode: str,
) -> float:
    """Fuse a message of k landmarks into one lane's state, in place (module docstring).

    Args:
        xb: (≥ nb,) the lane's total mean; its landmark columns ``cols`` are the fused ones.
        Pb: (≥ nb, ≥ nb) the lane's total covariance, fully symmetric (synced).
        nb: Used size n of the lane's state.
        cols: (k,) int first column in x of each fused landmark (``nv + 3 · slot``).
        means: (k, 3) the sender's landmark means, m, N frame.
        R: (3k, 3k) the message's covariance of them, m² (the sender's joint covariance, or
            ``k · blockdiag`` of its blocks for ``ci``).
        mode: ``ci`` or ``naive``.

    Returns:
        The ω used (1 for ``naive``); NaN if the update failed (nothing is changed then: the
        innovation covariance not positive definite, or a non-finite result).
    """
    idx = (cols[:, None] + np.arange(3)).ravel()
    return ci_update(xb, Pb, nb, idx, means.reshape(-1) - xb[idx], R, mode)


def ci_update(
    xb: FloatArray,
    Pb: FloatArray,
    nb: int,
    idx: np.ndarray,
    nu: FloatArray,
    R: FloatArray,
    mode: str,
    A: FloatArray | None = None,
) -> float:
    """The CI (or naive) update of one lane's state by a measurement of its entries ``idx``,
    in place: the Kalman update of the prior ``(x, P / ω)`` with noise ``R / (1 − ω)``, ω of
    :func:`ci_weight` (module docstring; Julier & Uhlmann 1997), by the filter's Cholesky gain
    kernels (``S = L Lᵀ``, ``Wᵀ = L⁻¹ H P / ω``, ``x += W L⁻¹ ν``, ``P = P / ω − W Wᵀ``).

    Args:
        xb: (≥ nb,) the lane's total mean.
        Pb: (≥ nb, ≥ nb) the lane's total covariance, fully symmetric (synced).
        nb: Used size n of the lane's state.
        idx: (q,) int the measured entries of x.
        nu: (m,) the innovation ``z − h(x)``.
        R: (m, m) the measurement's covariance.
        mode: ``ci`` or ``naive`` (ω = 1).
        A: (m, q) the measurement Jacobian on the entries ``idx`` (H = A there, zero
            elsewhere); ``None``: the identity (H selects them).

    Returns:
        The ω used (1 for ``naive``); NaN if the update failed (nothing is changed then: the
        innovation covariance not positive definite, or a non-finite result).
    """
    P_mm, HP = Pb[np.ix_(idx, idx)], Pb[idx, :nb]
    if A is not None:
        P_mm, HP = A @ P_mm @ A.T, A @ HP
    if mode == "ci":
        omega = ci_weight(Pb[:nb, :nb], idx, R, A)
        prior, noise = 1.0 / omega, R / (1.0 - omega)
    else:
        omega, prior, noise = 1.0, 1.0, R
    U = prior * HP  # H (P / ω)
    S = prior * P_mm + noise
    m = nu.shape[0]
    Wt, z, dx = np.empty((m, nb)), np.empty(m), np.empty(nb)
    if not stacked_gain(S, U, nu, np.arange(m), Wt, z):
        return float("nan")
    correction(Wt, z, dx)
    if not (np.isfinite(dx).all() and np.isfinite(Wt).all()):
        return float("nan")
    xb[:nb] += dx
    if prior != 1.0:
        Pb[:nb, :nb] *= prior
    subtract_outer(Pb, Wt, nb)
    return float(omega)


@kernel
def gather_landmark_blocks(
    P: FloatArray,
    nv: int,
    slot_of_id: np.ndarray,
    mapped: np.ndarray,
    known: np.ndarray,
    out: FloatArray,
) -> None:
    """Each lane's 3×3 landmark blocks of P by id, in place.

    Args:
        P: (B, n, n) the lanes' covariances.
        nv: Vehicle states before the first landmark.
        slot_of_id: (B, Lmax) int each id's map slot.
        mapped: (B, Lmax) bool the mapped ids.
        known: (B,) bool known-map lanes (their blocks are zeros).
        out: (B, Lmax, 3, 3) m²: the blocks of the mapped ids, zeros elsewhere.
    """
    for b in range(out.shape[0]):
        for j in range(out.shape[1]):
            c = nv + 3 * slot_of_id[b, j]
            for r in range(3):
                for q in range(3):
                    out[b, j, r, q] = P[b, c + r, c + q] if mapped[b, j] and not known[b] else 0.0


def message_noise(covs: FloatArray, keep: np.ndarray, mode: str) -> FloatArray:
    """The covariance R (3m, 3m) m² of a message's ``keep`` (k,) bool landmarks (m of them).

    Args:
        covs: (3k, 3k) the sender's joint covariance of its k landmarks, or (k, 3, 3) only
            their blocks.
        keep: (k,) bool the landmarks fused.
        mode: ``ci`` or ``naive``: with blocks only, ``ci`` takes ``m · blockdiag`` (the bound
            on the unknown cross-covariances, module docstring), ``naive`` the blocks as they
            are.
    """
    if covs.ndim == 2:
        rows = (3 * np.flatnonzero(keep)[:, None] + np.arange(3)).ravel()
        return np.array(covs[np.ix_(rows, rows)])
    blocks = covs[keep]
    R = block_diag(*blocks)
    return R * blocks.shape[0] if mode == "ci" else R


class LandmarkFusion:
    """:class:`~quadslam_env.estimation.protocol.FusesLandmarks` for
    :class:`~estimators.ekf.filter.EkfSlamBatch` (a mixin over its
    :class:`~estimators.ekf.state.EkfState`)."""

    fuses_landmarks = True
    state: EkfState
    nv: int
    _landmark_covs: FloatArray | None = None

    def fuse_landmarks(
        self, lane: int, ids: np.ndarray, means: FloatArray, covs: FloatArray, mode: str
    ) -> tuple[int, float]:
        """Fuse another vehicle's landmark estimates into lane ``lane`` (:func:`fuse_lane`).

        Args:
            lane: The receiving lane.
            ids: (k,) int landmark ids of the message.
            means: (k, 3) their means, m, N frame.
            covs: (3k, 3k) the sender's joint covariance of them, or (k, 3, 3) only its
                blocks, m².
            mode: ``ci`` or ``naive`` (:data:`FUSION_MODES`).

        Returns:
            ``(fused, ω)``: how many of the ids the lane had mapped and fused, and the weight
            (NaN when none was fused, or when the update failed, which flags the lane
            ``diverged`` and changes nothing).

        Raises:
            ValueError: An unknown mode, or shapes that do not match.
        """
        if mode not in FUSION_MODES:
            raise ValueError(f"fuse_landmarks: mode got {mode!r}; allowed: one of {FUSION_MODES}")
        ids = np.asarray(ids, dtype=np.int64).reshape(-1)
        k = ids.shape[0]
        means = np.asarray(means, dtype=float).reshape(k, 3)
        covs = np.asarray(covs, dtype=float)
        if covs.shape not in ((k, 3, 3), (3 * k, 3 * k)):
            raise ValueError(
                f"fuse_landmarks: covs got shape {covs.shape}; allowed: ({k}, 3, 3) or "
                f"({3 * k}, {3 * k}) for {k} ids"
            )
        st = self.state
        if st.known[lane] or k == 0:
            return 0, float("nan")
        inside = (ids >= 0) & (ids < st.landmark_capacity)
        keep = np.zeros(k, dtype=bool)
        keep[inside] = st.mapped[lane, ids[inside]] & ~st.tentative[lane, ids[inside]]
        if not keep.any():
            return 0, float("nan")
        self.state.sync(lane, self.nv)
        cols = self.nv + 3 * st.slot_of_id[lane, ids[keep]]
        R = message_noise(covs, keep, mode)
        omega = fuse_lane(st.x[lane], st.P[lane], int(st.n[lane]), cols, means[keep], R, mode)
        if omega != omega:  # NaN: not applied
            st.diag[D_DIVERGED, lane] = 1.0
        return int(keep.sum()), omega

    def landmark_covariance(self, lane: int, ids: np.ndarray) -> FloatArray:
        """The joint covariance (3k, 3k) m² of lane ``lane``'s mapped landmarks ``ids`` (k,), in
        their order (a copy).

        Raises:
            ValueError: An id the lane has not mapped.
        """
        st = self.state
        ids = np.asarray(ids, dtype=np.int64).reshape(-1)
        inside = (ids >= 0) & (ids < st.landmark_capacity)
        if not inside.all() or not st.mapped[lane, ids].all():
            raise ValueError(
                f"landmark_covariance: ids {ids.tolist()} not all mapped in lane {lane}"
            )
        self.state.sync(lane, self.nv)
        rows = ((self.nv + 3 * st.slot_of_id[lane, ids])[:, None] + np.arange(3)).ravel()
        return np.array(st.P[lane][np.ix_(rows, rows)])

    def landmark_covariances(self) -> FloatArray:
        """(B, Lmax, 3, 3) m² every lane's landmark covariances by id
        (:class:`~quadslam_env.estimation.protocol.ReportsLandmarkCovariances`): the 3×3
        diagonal blocks of P of the mapped landmarks, zeros elsewhere and in known-map lanes.
        No sync is needed: only the ``P_mv`` block lags after a prediction, never a landmark's
        own block."""
        st = self.state
        if self._landmark_covs is None or self._landmark_covs.shape[:2] != st.mapped.shape:
            self._landmark_covs = np.zeros((*st.mapped.shape, 3, 3))
        gather_landmark_blocks(st.P, self.nv, st.slot_of_id, st.mapped, st.known,
                               self._landmark_covs)  # fmt: skip
        return self._landmark_covs
