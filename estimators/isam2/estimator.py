"""A factor-graph estimator in the loop: iSAM2 over IMU-preintegration and LiDAR factors.

Registered as ``estimator.name: isam2`` (:func:`quadslam_env.estimation.register`); it needs GTSAM
(``pip install 'quadslam[gtsam]'``). The graph (docs/isam2.md):

* **Keyframes** at the LiDAR scans (10 Hz on the paper's sensor), each with a ``Pose3``
  ``X_k`` (``C_NB``, ρ in NED), a ``Vector3`` ``V_k`` (velocity in NED, m/s) and the IMU
  biases ``B_k`` (``imuBias.ConstantBias``: accelerometer m/s², gyro rad/s).
* **IMU factors** between consecutive keyframes: the IMU samples in between preintegrated on
  the manifold (Forster et al. 2017, "On-Manifold Preintegration for Real-Time
  Visual-Inertial Odometry", IEEE T-RO 33(1), eq. 33–38 and 44–45), GTSAM's
  ``CombinedImuFactor`` with the biases as a random walk, gravity ``(0, 0, +g)`` in NED, the
  white-noise densities from the samples' own stds (``σ² dt``, as the EKF gets them).
* **LiDAR factors**: each return (α, β, δ) with the LiDAR's own stds, the model of seed 001
  eq. 30–31 (:mod:`estimators.isam2.factors`). Known map: the landmarks are constants, one
  factor per scan on ``X_k``; unknown map: a ``Point3`` ``L_j`` per landmark id, added on
  first sight at the inverse LiDAR model (eq. 44–45) from the predicted pose.
* **Unlabeled returns** (``lidar.association: unknown``): labeled before the keyframe is added,
  by χ² gating and JCBB or nearest neighbour on the smoother's joint marginal of the predicted
  pose and the landmarks, with tentative landmarks for the unpaired returns
  (:mod:`estimators.isam2.associate`).
* **Priors** on ``X_0, V_0`` (the reset's covariance mapped to GTSAM's tangent space,
  :mod:`estimators.isam2.tangent`) and on ``B_0``.

The graph is solved incrementally by iSAM2 (Kaess et al. 2012), within a fixed lag
(``window_s``: older vehicle states are marginalised) or over the whole episode (``window_s:
null``), in the order of a sliding-window filter (:mod:`estimators.isam2.fixed_lag`: by time,
oldest states first, the landmarks last), so that the states leaving the window are leaves of
the Bayes tree; relinearised every ``relinearize_skip`` keyframes. Between keyframes the
estimate is the last keyframe's smoothed state predicted with the current preintegration, and
its covariance the keyframe's joint marginal (pose, velocity, biases) propagated through the
linearised IMU factor, which adds the preintegration noise; both are mapped to (ρ, v_B, Λ).

A GTSAM exception inside :meth:`Isam2Slam.update` or :meth:`Isam2Slam.predict` (an
indeterminate system, a failed Cholesky) and a non-finite IMU sample never escape: the
estimator sets ``diagnostics["diverged"] = 1`` (the env ends the episode as diverged,
:func:`~quadslam_env.estimation.health.health_codes`), keeps its last finite estimate and
dead-reckons from it (a non-finite sample is dropped).
"""

from __future__ import annotations

from functools import partial
from typing import Any

import numpy as np

from estimators.isam2.associate import Labeled, PosePrediction, ScanAssociation
from estimators.isam2.factors import known_map_error, landmark_error, scan_error
from estimators.isam2.fde import Isam2Monitor
from estimators.isam2.fixed_lag import FixedLagIsam2
from estimators.isam2.graph import (
    first_keyframe,
    held_bias_prior,
    keyframe_marginals,
    known_map,
    require_gtsam,
    sub_joint,
)
from estimators.isam2.history import ImuHistory, KeptSample
from estimators.isam2.output import Isam2Output
from estimators.isam2.settings import Isam2Settings
from estimators.isam2.team import TeamMember
from estimators.isam2.transition import NAV_DIM, ImuTransition
from estimators.memory import MemoryTerm, Workload, isam2_terms
from quadslam_env.estimation.measurements import Control, ImuSample, LidarScan
from quadslam_env.estimation.registry import register
from quadslam_env.estimation.snapshot import BatchEstimate, LaneMap
from quadslam_env.models.lidar import lidar_inverse
from quadslam_env.types import RATE, FloatArray


@register("isam2")
class Isam2Slam(Isam2Output, ImuHistory, TeamMember, Isam2Monitor):
    """Fixed-lag (or full) iSAM2 smoothing of IMU preintegration and LiDAR factors.

    Implements :class:`~quadslam_env.estimation.protocol.Estimator` in known-map
    (localisation) and unknown-map (SLAM) mode, with labeled scans or unlabeled ones
    (``associates_unlabeled``: :attr:`last_association` names each return's landmark). The
    team env's vehicles share one smoother through :meth:`~estimators.isam2.team.TeamMember.join`
    (``team.fusion: centralised``, :mod:`estimators.isam2.team`).

    Args:
        vehicle: Nominal vehicle parameters (unused: the IMU drives the motion model).
        **params: ``estimator.params``, see :class:`~estimators.isam2.settings.Isam2Settings`.

    Raises:
        ConfigError: GTSAM is not installed.
        ValueError: Unknown key, wrong type or out-of-range value of ``params`` (the message
            names the key, the value and what is allowed).
    """

    uses_truth = False
    associates_unlabeled = True
    # A scan measured in the past gets its keyframe at its own time (estimators.isam2.history):
    # a delayed LiDAR needs no copy (quadslam_env.estimation.TakesLateScans).
    takes_late_scans = True
    # GTSAM's smoother is native state with no copy: the scenario check refuses a slow IMU,
    # which runs a copy of the estimator (quadslam_env.estimation.copyable).
    copyable = False

    @classmethod
    def memory_terms(cls, load: Workload, params: dict[str, Any]) -> list[MemoryTerm]:
        """The graph of ``load``'s lanes over their window (:func:`estimators.memory.isam2_terms`).

        Raises:
            ConfigError: Invalid ``estimator.params``.
        """
        return isam2_terms(load, Isam2Settings.from_dict(params).window_s)

    def __init__(self, vehicle: Any = None, **params: Any) -> None:
        self.settings = Isam2Settings.from_dict(params)
        self._g = require_gtsam()
        self.vehicle = vehicle
        self.last_error = ""
        """Message of the exception that set ``diverged`` ("" while healthy)."""
        self._front = ScanAssociation(self.settings)
        self._team = [self]  # alone until it joins a team (estimators.isam2.team)
        self._vehicle = 0
        self._reset_state()

    def __deepcopy__(self, memo: dict[int, Any]) -> Isam2Slam:
        raise TypeError(
            "Isam2Slam cannot be copied (copyable = False): its GTSAM smoother has no copy"
        )

    # ------------------------------------------------------------------ state
    def _reset_state(self) -> None:
        self.last_error = ""
        self._smoother: Any = None
        self._isam: Any = None
        self._k = 0
        self._t = 0.0
        self._kf_t = 0.0  # the smoother's clock at keyframe k, s
        self._kept: list[KeptSample] = []  # the IMU samples since keyframe k
        self._kf_pose: Any = None
        self._kf_vel = np.zeros(3)
        self._kf_bias: Any = None
        self._kf_dcm = np.eye(3)
        self._kf_biases = (np.zeros(3), np.zeros(3))  # (accelerometer m/s², gyro rad/s)
        self._kf_cov = np.zeros((NAV_DIM, NAV_DIM))
        self._transition: ImuTransition | None = None  # built at the first prediction
        self._transition_current = False  # linearised at the current keyframe
        self._pim: Any = None
        self._pim_noise: tuple[float, float] | None = None
        self._params: Any = None
        self._known: dict[int, FloatArray] | None = None
        self._lm_means: dict[int, FloatArray] = {}
        # Each landmark's marginal at the current keyframe; None: not recovered yet (lazily,
        # on the first snapshot that needs them, :meth:`_landmark_covs`).
        self._lm_covs: dict[int, FloatArray] | None = {}
        # The keyframe's joint marginal with the landmarks (unknown association): their row
        # by id, and the (15 + 3L)² matrix.
        self._kf_joint: tuple[dict[int, int], FloatArray] | None = None
        self._lm_map: LaneMap | None = None  # the snapshots' landmarks, per keyframe
        self._unlabeled: bool | None = None
        self._rates = np.zeros(3)
        self._gyro: FloatArray | None = None
        self._diverged = False
        self._cache: BatchEstimate | None = None
        self._state_cache: BatchEstimate | None = None  # the same without landmark covs
        self._last: BatchEstimate | None = None
        self._reset_monitor()

    @property
    def known_map(self) -> bool:
        """True after a reset with ``known_landmarks`` (localisation only)."""
        return self._known is not None

    @property
    def last_association(self) -> np.ndarray:
        """(R,) int the landmark id each return of the last unlabeled scan was paired with
        (-1: none; a return that only fed a tentative landmark too)."""
        return self._front.last_association

    @property
    def tentative_count(self) -> int:
        """Tentative landmarks held outside the graph (unknown association)."""
        return self._front.tentative_count

    @property
    def keyframes(self) -> int:
        """Index of the latest keyframe (0 at reset)."""
        return self._k

    # ------------------------------------------------------------------ estimator protocol
    def reset(
        self,
        mean0: FloatArray,
        cov0: FloatArray,
        rng: np.random.Generator,
        known_landmarks: tuple[np.ndarray, FloatArray] | None = None,
    ) -> None:
        """Start a new run: keyframe 0 at the initial belief.

        Args:
            mean0: (12,) initial mean (ρ [m, N], v_B [m/s], Λ [rad], ω [rad/s]).
            cov0: (12, 12) initial covariance; its (9, 9) block over (ρ, v_B, Λ) becomes the
                prior on ``X_0, V_0`` (mapped to GTSAM's tangent, eigenvalues floored at
                :data:`~estimators.isam2.settings.PRIOR_VARIANCE_FLOOR`).
            rng: Unused (the smoother is deterministic); accepted for the protocol.
            known_landmarks: ``(ids (L,), positions (L, 3) [m, N])`` to localise against a
                known map; ``None`` for SLAM.

        Raises:
            ValueError: Wrong shapes, non-finite values, or a malformed known map; in a team,
                vehicle 0 not reset before the others.
        """
        del rng
        g = self._g
        mean0 = np.asarray(mean0, dtype=float).reshape(-1)
        cov0 = np.asarray(cov0, dtype=float)
        if mean0.shape != (12,) or not np.isfinite(mean0).all():
            raise ValueError(f"reset: mean0 must be a finite (12,) array, got shape {mean0.shape}")
        if cov0.shape != (12, 12) or not np.isfinite(cov0).all():
            raise ValueError(f"reset: cov0 must be a finite (12, 12) array, got shape {cov0.shape}")
        known = None if known_landmarks is None else known_map(*known_landmarks)
        self._reset_state()
        self._known = known
        self._front.reset(known=known is not None)
        self._rates = mean0[RATE].copy()
        s = self.settings
        self._smoother = self._team_smoother()  # a team's vehicle after the first: its graph
        if self._smoother is None:
            params = g.ISAM2Params()
            params.setRelinearizeThreshold(s.relinearize_threshold)
            params.setFactorization(s.factorization.upper())  # "QR" or "CHOLESKY"
            self._smoother = FixedLagIsam2(g, s.window_s, params, s.relinearize_skip)
        self._isam = self._smoother.isam
        keys = [self._key(c, 0) for c in "xvb"]
        first = first_keyframe(g, s, mean0, cov0, keys)
        self._set_keyframe(first.pose, first.vel, first.bias)
        self._kf_cov = first.cov
        try:
            self._solve(first.graph, first.values, dict.fromkeys(keys, 0.0))
            self._read_keyframe(0)
        except Exception as exc:  # a GTSAM failure: reported as divergence, never raised
            self._diverge(exc)

    def predict(self, imu: ImuSample, control: Control, dt: float) -> None:
        """Preintegrate one IMU sample held over ``dt`` (Forster et al. 2017, eq. 24–26).

        A sample with a NaN or infinite entry, or a GTSAM exception while preintegrating, is
        never raised: the sample is dropped (the smoother's clock still advances by ``dt``)
        and the estimator reports divergence, ``diagnostics["diverged"] = 1`` with its last
        finite estimate, as a failure in :meth:`update` does.

        Args:
            imu: Sample with ``accel`` (3,) specific force [m/s², B], ``gyro`` (3,) [rad/s,
                B] and their white-noise stds per sample (continuous densities ``σ² dt``).
            control: Applied control (unused: the IMU drives the motion model).
            dt: Sample period in s (> 0).

        Raises:
            ValueError: Before the first :meth:`reset`, or if ``dt`` is not a positive finite
                number.
        """
        del control
        if self._smoother is None:
            raise ValueError("predict: call reset first (the smoother starts at reset)")
        if not 0.0 < dt < np.inf:
            raise ValueError(f"predict: dt must be a positive finite number of seconds, got {dt}")
        accel = np.array(imu.accel, dtype=float).reshape(3)  # copies: a kept sample outlives
        gyro = np.array(imu.gyro, dtype=float).reshape(3)  # the caller's buffer
        clock = self._t + dt
        self._cache = self._state_cache = None
        if not (np.isfinite(accel).all() and np.isfinite(gyro).all()):
            self._t = clock
            bad = FloatingPointError(
                f"isam2: non-finite IMU sample at t = {float(imu.t):g} s (accel "
                f"{accel.tolist()} m/s², gyro {gyro.tolist()} rad/s)"
            )
            self._diverge(bad)
            return
        sample = KeptSample(float(imu.t), accel, gyro, imu.accel_sigma, imu.gyro_sigma, dt, clock)
        self._t = clock
        try:
            self._pim = self._preintegrate(self._pim, sample)
        except Exception as exc:  # a GTSAM failure (C++ exceptions arrive as RuntimeError)
            self._diverge(exc)
            return
        if not self._diverged:  # kept for a late scan (scans are ignored after a divergence)
            self._kept.append(sample)
        self._gyro = gyro
        self._rates = gyro - self._kf_biases[1]

    def update(self, scan: LidarScan) -> None:
        """Add a keyframe at the scan with its LiDAR factors and update the smoother.

        Every scan makes a keyframe (an empty one too: it bounds the preintegration). A scan
        whose time ``scan.t`` is before the latest IMU samples (a delayed LiDAR) gets its
        keyframe at that time and the samples since start the next interval
        (:mod:`estimators.isam2.history`; scans must arrive in time order). Ids
        outside the known map are ignored in known-map mode. An unlabeled scan (``ids`` None)
        is labeled first (:mod:`estimators.isam2.associate`; :attr:`last_association`). After
        a divergence the scans are ignored (the episode ends on that step).

        Args:
            scan: Labeled scan: sorted ``ids`` (k,), or ``None`` for unlabeled returns in any
                order; ``meas`` (k, 3) = (α rad, β rad, δ m); ``sigma`` (3,) noise stds.

        Raises:
            ValueError: Measurements that are not a finite (k, 3) array, or labeled and
                unlabeled scans mixed in one SLAM run.
        """
        unlabeled = scan.ids is None
        ids = [] if unlabeled else [int(i) for i in np.asarray(scan.ids).reshape(-1).tolist()]
        k = np.asarray(scan.meas).size // 3 if unlabeled else len(ids)
        meas = np.asarray(scan.meas, dtype=float).reshape(-1, 3) if k else np.zeros((0, 3))
        if meas.shape != (k, 3) or not np.isfinite(meas).all():
            raise ValueError(f"update: scan.meas must be a finite ({k}, 3) array")
        if self._known is None and self._unlabeled not in (None, unlabeled):
            raise ValueError(
                "update: labeled and unlabeled scans in one SLAM run (the labels would clash "
                "with the smoother's own landmark ids); allowed: one kind per run"
            )
        self._unlabeled = unlabeled
        sigma = np.asarray(scan.sigma, dtype=float).reshape(3)
        if unlabeled:
            self._front.last_association = np.full(k, -1, dtype=np.int64)
        if self._diverged or self._smoother is None:
            return
        try:
            pim, stamp, n = self._until(float(scan.t))  # a late scan: its own interval
            labeled = Labeled(ids, meas)
            if unlabeled or self.monitoring:  # both need the belief at the scan
                pred = self._scan_belief(pim)
                if unlabeled:
                    labeled = self._associate(meas, sigma, pred)
                if self.monitoring:
                    labeled = self._monitor_scan(labeled, sigma, pred, float(scan.t))
            self._keyframe(labeled, sigma, pim, stamp)
            self._resume(n, stamp)
        except Exception as exc:  # any GTSAM failure (C++ exceptions arrive as RuntimeError)
            self._diverge(exc)
        self._cache = self._state_cache = None

    # ------------------------------------------------------------------ graph
    def _solve(self, graph: Any, values: Any, stamps: dict[int, float]) -> None:
        """One smoother update with the new factors, then ``iterations − 1`` more."""
        if self._lm_covs is None:  # never asked for at this keyframe: after the update they
            self._lm_covs = {}  # cannot be recovered (reported as zero if the update fails)
        self._kf_joint = None  # the next keyframe's, once read
        self._smoother.update(graph, values, stamps)
        for _ in range(self.settings.iterations - 1):
            self._smoother.update()

    def _associate(self, meas: FloatArray, sigma: FloatArray, pred: PosePrediction) -> Labeled:
        """Label an unlabeled scan on the belief ``pred`` (:mod:`estimators.isam2.associate`)."""
        if self._known is not None:
            lms, covs = self._known, dict.fromkeys(self._known, np.zeros((3, 3)))
        else:
            lms, covs = self._lm_means, self._landmark_covs()
        return self._front.associate(meas, sigma, pred, lms, covs, partial(self._scan_joint, pred))

    def _scan_belief(self, pim: Any) -> PosePrediction:
        """The smoother's belief at a scan: the latest keyframe predicted with ``pim``."""
        k, pose = self._k, self._kf_pose
        F, Q = np.eye(NAV_DIM), np.zeros((NAV_DIM, NAV_DIM))
        if pim is not None and pim.deltaTij() > 0.0:
            k += 1
            pose, _, F, Q = self._link()(pim)
        Fp = F[:6]  # the pose rows: (δθ, δt) of the scan's keyframe
        pose_cov = Fp @ self._kf_cov @ Fp.T + Q[:6, :6]
        return PosePrediction(pose.rotation().matrix(), pose.translation(), pose_cov, k, Fp)

    def _scan_joint(self, pred: PosePrediction, ids: list[int]) -> FloatArray:
        """(6 + 3M)² covariance of the pose ``pred`` and landmarks ``ids``: the keyframe's joint
        marginal through the IMU transition (cross terms ``F Σ_kl``); a known map's are zero."""
        n = 3 * len(ids)
        out = np.zeros((6 + n, 6 + n))
        out[:6, :6] = pred.cov
        if self._known is None:
            full = self._joint_marginal([self._key(c, self._k) for c in "xvb"], ids)
            out[:6, 6:] = pred.F_pose @ full[:NAV_DIM, NAV_DIM:]
            out[6:, :6] = out[:6, 6:].T
            out[6:, 6:] = full[NAV_DIM:, NAV_DIM:]
        return out

    def _joint_marginal(self, nav: list[int], ids: list[int]) -> FloatArray:
        """(15 + 3M)² joint marginal of keyframe k (``nav``) and the landmarks ``ids``: read off
        the keyframe's query when it holds them all, else one more Bayes-tree query."""
        if self._kf_joint is not None and all(i in self._kf_joint[0] for i in ids):
            rows, joint = self._kf_joint
            return sub_joint(joint, NAV_DIM, [rows[i] for i in ids])
        keys = nav + [self._key("l", i) for i in ids]
        return np.asarray(self._isam.jointMarginalCovariance(keys).fullMatrix())

    def _keyframe(self, scan: Labeled, sigma: FloatArray, pim: Any, t: float) -> None:
        """Add keyframe k+1 at the clock ``t`` s with the IMU factor ``pim`` (or, without IMU
        samples since keyframe k, factors on k) with the scan's returns, and the earlier
        sightings of landmarks it confirms."""
        ids, meas = scan.ids, scan.meas
        g = self._g
        graph = g.NonlinearFactorGraph()
        values = g.Values()
        stamps: dict[int, float] = {}
        k = self._k
        pose = self._kf_pose
        if pim is not None and pim.deltaTij() > 0.0:
            k += 1
            self._check_keyframe(k)
            xi, vi, bi = self._key("x", k - 1), self._key("v", k - 1), self._key("b", k - 1)
            xj, vj, bj = self._key("x", k), self._key("v", k), self._key("b", k)
            graph.add(g.CombinedImuFactor(xi, vi, xj, vj, bi, bj, pim))
            nav = pim.predict(g.NavState(self._kf_pose, self._kf_vel), self._kf_bias)
            pose = nav.pose()
            values.insert(xj, pose)
            values.insert(vj, nav.velocity())
            values.insert(bj, self._kf_bias)
            stamps.update({xj: t, vj: t, bj: t})
            held = held_bias_prior(g, self.settings, bj)
            if held is not None:
                graph.add(held)
        xk = self._key("x", k)
        noise = g.noiseModel.Diagonal.Sigmas(sigma)
        scan_noise = g.noiseModel.Diagonal.Sigmas(np.tile(sigma, len(ids)))
        known = self._known
        if known is not None:
            rows = [j for j, i in enumerate(ids) if i in known]
            if rows:
                lms = np.array([known[ids[j]] for j in rows])
                graph.add(
                    g.CustomFactor(
                        g.noiseModel.Diagonal.Sigmas(np.tile(sigma, len(rows))),
                        [xk],
                        known_map_error(lms, meas[rows]),
                    )
                )
        new: list[int] = []
        if self._known is None and ids:
            dcm = pose.rotation().matrix()
            rho = pose.translation()
            for j, i in enumerate(ids):
                if i not in self._lm_means:  # first sight: the inverse model (eq. 44-45)
                    values.insert(self._key("l", i), lidar_inverse(rho, dcm, meas[j]))
                    new.append(i)
            if self.settings.factor_per_return:
                for j, i in enumerate(ids):
                    lk = self._key("l", i)
                    graph.add(g.CustomFactor(noise, [xk, lk], landmark_error(meas[j])))
            else:
                keys = [xk] + [self._key("l", i) for i in ids]
                graph.add(g.CustomFactor(scan_noise, keys, scan_error(meas)))
            for kf, i, z in scan.earlier:  # a confirmed landmark's earlier sightings
                if self._isam.valueExists(self._key("x", kf)):
                    lk = self._key("l", i)
                    graph.add(g.CustomFactor(noise, [self._key("x", kf), lk], landmark_error(z)))
        # The landmarks have no stamp: they never leave the window, also through scans without
        # a return (the map out of view for longer than the window), so a landmark seen again
        # keeps its variable.
        self._solve(graph, values, stamps)
        self._read_keyframe(k, new)

    def _read_keyframe(self, k: int, new: list[int] | None = None) -> None:
        """Take keyframe k's smoothed state, its joint marginal and the landmarks (the
        mapped ones and ``new``, the ids added with this keyframe)."""
        isam = self._isam  # one variable at a time: the whole window's estimate costs more
        xk, vk, bk = self._key("x", k), self._key("v", k), self._key("b", k)
        pose = isam.calculateEstimatePose3(xk)
        vel = np.asarray(isam.calculateEstimateVector(vk), dtype=float).reshape(3)
        bias = isam.calculateEstimateConstantBias(bk)
        mapped = sorted({*self._lm_means, *(new or [])})
        points = np.array(
            [isam.calculateEstimatePoint3(self._key("l", i)) for i in mapped], dtype=float
        )
        points = points.reshape(-1, 3)
        # The association's screen needs the landmarks' marginals at the next scan: one query
        # with the keyframe's. Otherwise they are recovered when a snapshot asks for them.
        eager = bool(self._unlabeled)
        lm_ids = mapped if eager else []
        cov, blocks, joint = keyframe_marginals(
            self._isam, [xk, vk, bk], [self._key("l", i) for i in lm_ids]
        )
        covs = dict(zip(lm_ids, blocks, strict=True))
        # The same query answers the next scan's association (the smoother does not move
        # before it): its joint marginals of the keyframe and some landmarks are sub-blocks.
        self._kf_joint = (dict(zip(lm_ids, range(len(lm_ids)), strict=True)), joint)
        parts = (pose.matrix().ravel(), vel, bias.vector(), cov.ravel(), points.ravel())
        finite = np.isfinite(np.concatenate(parts)).all()
        if not finite:
            raise FloatingPointError(f"isam2: non-finite smoothed state at keyframe {k}")
        self._k = k
        self._set_keyframe(pose, vel, bias)
        self._transition_current = False  # moved to the new keyframe on first use
        self._kf_cov = 0.5 * (cov + cov.T)
        self._share_map(dict(zip(mapped, points, strict=True)))  # rows: read, never written
        self._lm_covs = covs if eager or not self.settings.landmark_covariances else None
        self._lm_map = None
        self._pim = None  # the next sample starts a new preintegration at the new bias
        if self._gyro is not None:
            self._rates = self._gyro - self._kf_biases[1]

    def _set_keyframe(self, pose: Any, vel: FloatArray, bias: Any) -> None:
        """The keyframe's state, with its attitude and biases as arrays for every step's
        prediction and snapshot."""
        self._kf_pose, self._kf_vel, self._kf_bias = pose, vel, bias
        self._kf_dcm = np.ascontiguousarray(pose.rotation().matrix(), dtype=float)
        accel = np.asarray(bias.accelerometer(), dtype=float)
        self._kf_biases = (accel, np.asarray(bias.gyroscope(), dtype=float))
