"""Data association front end of the iSAM2 smoother (``lidar.association: unknown``).

Each unlabeled scan is labeled before its keyframe enters the graph, on the smoother's own
belief: the keyframe pose ``X_j`` predicted with the IMU (:mod:`estimators.isam2.transition`)
and the joint marginal of ``X_j`` and the mapped landmarks. Seed 004 §5.1 (the Mahalanobis
distance of an innovation, a χ² gate, the nearest-neighbour rule) and Neira & Tardós 2001
(joint compatibility), with the project's functions of :mod:`estimators.association`:

1. **Prediction.** Landmark ``l_m`` (mean ``μ_m``) is predicted at ``h_m = h(C_NBᵀ(μ_m − ρ))``
   (seed 001 eq. 30–31) with the Jacobians ``H_x,m`` (3×6, over the Pose3 tangent) and
   ``H_l,m`` (3×3) of the LiDAR factor (:func:`~estimators.isam2.factors.lidar_error`), and
   return ``z_r`` has the innovation ``ν_rm = z_r − h_m`` (angles wrapped).
2. **Screen** (cost: only the landmarks that can gate enter the joint marginal). With the
   pose's covariance ``Σ_x`` and the landmark's marginal ``Σ_m`` (both from the smoother),
   ``B_m = 2 (H_x Σ_x H_xᵀ + H_l Σ_m H_lᵀ) + R`` bounds the true innovation covariance from
   above, whatever the cross-covariance: ``Cov(a + b) ≼ 2 (Cov a + Cov b)`` since
   ``(a − b)(a − b)ᵀ ≽ 0``. So ``ν_rmᵀ B_m⁻¹ ν_rm ≤ ν_rmᵀ S_mm⁻¹ ν_rm``, and a landmark whose
   bound exceeds the new-landmark gate for every return cannot gate any of them: it is left
   out, exactly.
3. **Joint innovation covariance** of the M candidates, in the layout of
   :mod:`estimators.association` (3M × 3M, landmark blocks in candidate order):
   ``S = J Σ Jᵀ + I_M ⊗ R`` with ``Σ`` the (6 + 3M)² joint marginal of ``(X_j, l_1 … l_M)``
   and ``J`` rows ``[H_x,m, 0 … H_l,m … 0]``; its off-diagonal blocks are the correlations
   through the shared pose and map errors that JCBB needs.
4. **Association**: :func:`~estimators.association.individual_nis`, then
   :func:`~estimators.association.jcbb` or :func:`~estimators.association.nearest_neighbour`
   at the χ²₃(``gate_probability``) gate.
5. **New landmarks.** A return outside the χ²₃(``new_landmark_probability``) gate of every
   landmark feeds the tentative landmarks of :mod:`estimators.tentative` (the M-of-N rule that
   EKF-SLAM and FastSLAM use), at its inverse-model position ``p = ρ + C_NB ϱ(z)`` (seed 001
   eq. 44–45) with ``P = G_y R G_yᵀ + G_x Σ_x G_xᵀ``, ``G_y = C_NB ∂ϱ/∂y`` (eq. 50) and
   ``G_x = [−C_NB [ϱ]×, C_NB]``. Unlike EKF-SLAM, a tentative landmark is *not* in the graph
   (a smoother cannot cheaply take a variable out again): each sighting is kept aside with its
   keyframe, and when the candidate is confirmed it enters as a new landmark with a factor for
   every sighting whose keyframe is still in the smoother. A false return, almost never seen
   again inside a gate, leaves no trace in the graph; a true landmark loses no information.
   A return between the two gates (a landmark's rare return outside the association gate),
   and every unpaired return with a known map, is dropped.

Labels are the estimator's own landmark ids (0, 1, … in order of confirmation, never reused);
with a known map they are the map's ids.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from estimators.association import (
    UNASSOCIATED,
    individual_nis,
    jcbb,
    joint_thresholds,
    nearest_neighbour,
)
from estimators.isam2.factors import lidar_error
from estimators.isam2.settings import Isam2Settings
from estimators.tentative import Candidates, age_candidates, observe_candidate_slot
from quadslam_env.models.frames import skew, wrap_angle
from quadslam_env.models.lidar import body_from_measure, lidar_inverse, measure_inverse_jacobian
from quadslam_env.types import FloatArray

SIGMA_FLOOR = 1e-9
"""Smallest LiDAR std in R (keeps S invertible for a noise-free sensor and a known pose)."""

CANDIDATE_SLOTS = 32
"""Tentative landmarks held at least (twice the largest scan if more; a return that finds all
in use is dropped)."""

JointMarginal = Callable[[list[int]], FloatArray]
"""``joint(ids)`` → (6 + 3M, 6 + 3M) joint covariance of the scan's pose tangent (δθ rad, δt m)
and the landmarks ``ids`` (m, N), in that order (zero landmark blocks for a known map)."""


@dataclass(frozen=True)
class PosePrediction:
    """The scan's keyframe pose as the smoother predicts it.

    Attributes:
        dcm: (3, 3) ``C_NB``.
        position: (3,) ρ in N, m.
        cov: (6, 6) its marginal covariance over GTSAM's Pose3 tangent (δθ rad, δt m; B).
        keyframe: Index of the keyframe the scan's factors go on.
        F_pose: (6, 15) the pose rows of the IMU transition from the latest keyframe's error
            (pose, velocity, biases) to this pose's (identity rows at the keyframe itself):
            the cross-covariances with the landmarks are ``F_pose Σ_kl``.
    """

    dcm: FloatArray
    position: FloatArray
    cov: FloatArray
    keyframe: int
    F_pose: FloatArray = field(default_factory=lambda: np.eye(6, 15))


@dataclass
class Labeled:
    """One scan after association: what goes into the graph.

    Attributes:
        ids: Landmark id of each used return (paired, or confirming a new landmark).
        meas: (len(ids), 3) those returns (α rad, β rad, δ m).
        earlier: ``(keyframe, id, return (3,))`` the earlier sightings of the landmarks
            confirmed by this scan (their factors go on those keyframes, if still present).
    """

    ids: list[int]
    meas: FloatArray
    earlier: list[tuple[int, int, FloatArray]] = field(default_factory=list)


def predict_returns(
    dcm: FloatArray, position: FloatArray, landmarks: FloatArray, meas: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Innovations of every (return, landmark) pair and the landmarks' Jacobians (step 1).

    Args:
        dcm: (3, 3) ``C_NB``. position: (3,) ρ in N, m.
        landmarks: (M, 3) landmark means in N, m.
        meas: (R, 3) returns (α rad, β rad, δ m).

    Returns:
        ``(nu (R, M, 3), H_pose (M, 3, 6), H_lm (M, 3, 3))``: ``z_r − h_m`` with wrapped
        angles, and ``∂h/∂(δθ, δt)``, ``∂h/∂l`` at the prediction.
    """
    h, H_pose, H_lm = lidar_error(dcm, position, landmarks, np.zeros(landmarks.shape))
    nu = meas[:, None, :] - h[None, :, :]
    nu[..., :2] = wrap_angle(nu[..., :2])
    return nu, H_pose, H_lm


def screen(
    nu: FloatArray,
    H_pose: FloatArray,
    H_lm: FloatArray,
    pose_cov: FloatArray,
    marginals: FloatArray,
    r_diag: FloatArray,
    gate: float,
) -> np.ndarray:
    """The landmarks that may gate some return (step 2): ``min_r ν_rmᵀ B_m⁻¹ ν_rm ≤ gate``.

    Args:
        nu: (R, M, 3) innovations. H_pose: (M, 3, 6), H_lm: (M, 3, 3) Jacobians.
        pose_cov: (6, 6) ``Σ_x``. marginals: (M, 3, 3) the landmarks' marginals ``Σ_m``.
        r_diag: (3,) measurement variances. gate: The widest gate used.

    Returns:
        (M,) bool, True for the landmarks to keep.
    """
    B = 2.0 * (H_pose @ pose_cov @ H_pose.transpose(0, 2, 1))
    B += 2.0 * (H_lm @ marginals @ H_lm.transpose(0, 2, 1)) + np.diag(r_diag)
    bound = np.einsum("rmi,mij,rmj->rm", nu, np.linalg.inv(B), nu)
    return np.asarray((bound <= gate).any(axis=0))


def innovation_covariance(
    H_pose: FloatArray, H_lm: FloatArray, joint: FloatArray, r_diag: FloatArray
) -> FloatArray:
    """(3M, 3M) joint innovation covariance ``S = J Σ Jᵀ + I_M ⊗ R`` (step 3).

    Args:
        H_pose: (M, 3, 6), H_lm: (M, 3, 3) the candidates' Jacobians.
        joint: (6 + 3M, 6 + 3M) joint covariance of the pose tangent and the M landmarks.
        r_diag: (3,) measurement variances.
    """
    J = stacked_jacobian(H_pose, H_lm)
    S = J @ joint @ J.T + np.diag(np.tile(r_diag, H_pose.shape[0]))
    return np.ascontiguousarray(0.5 * (S + S.T))


def stacked_jacobian(H_pose: FloatArray, H_lm: FloatArray) -> FloatArray:
    """(3M, 6 + 3M) ``J``: row block m is ``[H_x,m, 0 … H_l,m … 0]`` over (pose, l_1 … l_M).

    Args:
        H_pose: (M, 3, 6), H_lm: (M, 3, 3) the Jacobians of M returns, each of its own landmark.
    """
    m = H_pose.shape[0]
    J = np.zeros((3 * m, 6 + 3 * m))
    for a in range(m):
        J[3 * a : 3 * a + 3, 0:6] = H_pose[a]
        J[3 * a : 3 * a + 3, 6 + 3 * a : 9 + 3 * a] = H_lm[a]
    return J


def new_landmark(
    pred: PosePrediction, z: FloatArray, r_diag: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Inverse-model position (m, N) and covariance (m²) of a return (step 5)."""
    rho_b = body_from_measure(z)
    G_y = pred.dcm @ measure_inverse_jacobian(z)
    G_x = np.hstack((-pred.dcm @ skew(rho_b), pred.dcm))
    P = G_y @ np.diag(r_diag) @ G_y.T + G_x @ pred.cov @ G_x.T
    return lidar_inverse(pred.position, pred.dcm, z), 0.5 * (P + P.T)


class ScanAssociation:
    """Labels unlabeled scans for :class:`~estimators.isam2.estimator.Isam2Slam` (module doc).

    Args:
        settings: The estimator's settings (association method, gates, M-of-N rule).
    """

    def __init__(self, settings: Isam2Settings) -> None:
        self.settings = settings
        self.reset(known=False)

    def reset(self, known: bool) -> None:
        """Forget the tentative landmarks and labels; ``known``: a known map (no new ones)."""
        self.known = known
        self.next_id = 0
        self.candidates = Candidates(1, CANDIDATE_SLOTS)
        self._sightings: dict[int, list[tuple[int, FloatArray]]] = {}
        self._thresholds = joint_thresholds(0, self.settings.gate_probability)
        self.last_association = np.zeros(0, dtype=np.int64)
        """(R,) int the landmark id of each return of the last scan (-1: none)."""

    @property
    def tentative_count(self) -> int:
        """Tentative landmarks held (not in the graph)."""
        return int(self.candidates.active()[0])

    def associate(
        self,
        meas: FloatArray,
        sigma: FloatArray,
        pred: PosePrediction,
        landmarks: dict[int, FloatArray],
        marginals: dict[int, FloatArray],
        joint: JointMarginal,
    ) -> Labeled:
        """Label one scan and update the tentative landmarks.

        Args:
            meas: (R, 3) finite returns (α rad, β rad, δ m), in any order.
            sigma: (3,) LiDAR stds (σ_α rad, σ_β rad, σ_δ m).
            pred: The scan's predicted keyframe pose.
            landmarks: Mapped landmark id → mean (3,) in N, m (the known map: its positions).
            marginals: id → marginal covariance (3, 3) in m² (zeros for a known map).
            joint: The joint marginal of the pose and given landmarks (called once, for the
                landmarks that pass the screen).

        Returns:
            The returns to add to the graph with their landmark ids; :attr:`last_association`
            holds every return's id afterwards.
        """
        s = self.settings
        r = meas.shape[0]
        r_diag = np.maximum(np.asarray(sigma, dtype=float).reshape(3), SIGMA_FLOOR) ** 2
        paired = np.full(r, UNASSOCIATED, dtype=np.int64)
        gated = np.zeros(r, dtype=bool)
        ids = np.array(sorted(landmarks), dtype=np.int64)
        if r and ids.size:
            lms = np.array([landmarks[i] for i in ids.tolist()])
            nu, H_pose, H_lm = predict_returns(pred.dcm, pred.position, lms, meas)
            covs = np.array([marginals[i] for i in ids.tolist()])
            keep = np.flatnonzero(
                screen(nu, H_pose, H_lm, pred.cov, covs, r_diag, max(s.gate, s.new_gate))
            )
            if keep.size:
                S = innovation_covariance(
                    H_pose[keep], H_lm[keep], joint(ids[keep].tolist()), r_diag
                )
                if not np.isfinite(S).all():
                    raise FloatingPointError("isam2: non-finite innovation covariance")
                nu_c = np.ascontiguousarray(nu[:, keep])
                d2 = np.empty((r, keep.size))
                individual_nis(nu_c, S, d2)
                gated = np.asarray((d2 <= s.new_gate).any(axis=1))
                out = np.full(r, UNASSOCIATED, dtype=np.int64)
                if s.association == "jcbb":
                    if self._thresholds.size <= r:
                        self._thresholds = joint_thresholds(r, s.gate_probability)
                    jcbb(nu_c, S, d2, s.gate, self._thresholds, out)
                else:
                    nearest_neighbour(d2, s.gate, out)
                paired = np.where(out >= 0, ids[keep][np.maximum(out, 0)], UNASSOCIATED)
        labels = paired.copy()
        used = [i for i in range(r) if paired[i] >= 0]
        earlier: list[tuple[int, int, FloatArray]] = []
        if not self.known:
            self.candidates = self.candidates.at_least(max(CANDIDATE_SLOTS, 2 * r))
            for i in range(r):
                if paired[i] < 0 and not gated[i]:
                    confirmed = self._observe(meas[i], pred, r_diag)
                    if confirmed is not None:
                        labels[i] = self.next_id
                        earlier += [(kf, self.next_id, z) for kf, z in confirmed[:-1]]
                        self.next_id += 1
                        used.append(i)
            c = self.candidates
            age_candidates(c.age[0], c.matched[0], s.confirm_window)
        self.last_association = labels
        return Labeled([int(labels[i]) for i in used], meas[used].reshape(-1, 3), earlier)

    def _observe(
        self, z: FloatArray, pred: PosePrediction, r_diag: FloatArray
    ) -> list[tuple[int, FloatArray]] | None:
        """Feed one return to the tentative landmarks (:func:`observe_candidate`).

        Returns:
            The candidate's sightings ``(keyframe, return)``, oldest first, when this return
            confirms it; else ``None``.
        """
        c = self.candidates
        p, P = new_landmark(pred, z, r_diag)
        m = self.settings.confirm_hits
        key = int(
            observe_candidate_slot(
                c.pos[0], c.cov[0], c.hits[0], c.age[0], c.matched[0], p, P, self.settings.gate, m
            )
        )
        if key < 0:  # every slot in use: dropped
            return None
        sighting = (pred.keyframe, np.array(z, dtype=float))
        if c.hits[0, key] == 1:  # a new candidate (or confirmed at once, M = 1)
            self._sightings[key] = [sighting]
        else:
            self._sightings[key].append(sighting)
        return self._sightings.pop(key) if c.hits[0, key] >= m else None
