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
* **Priors** on ``X_0, V_0`` (the reset's covariance mapped to GTSAM's tangent space,
  :mod:`estimators.isam2.tangent`) and on ``B_0``.

The graph is solved incrementally by iSAM2 (Kaess et al. 2012), within a fixed lag
(``window_s``, GTSAM's ``IncrementalFixedLagSmoother``: older vehicle states are marginalised)
or over the whole episode (``window_s: null``). Between keyframes the estimate is the last
keyframe's smoothed state predicted with the current preintegration, and its covariance the
keyframe's joint marginal (pose, velocity, biases) propagated through the linearised IMU
factor, which adds the preintegration noise; both are mapped to (ρ, v_B, Λ).

A GTSAM exception inside :meth:`Isam2Slam.update` (an indeterminate system, a failed
Cholesky) never escapes: the estimator sets ``diagnostics["diverged"] = 1`` (the env ends the
episode as diverged, :func:`~quadslam_env.estimation.health.health_codes`), keeps its last
finite estimate and dead-reckons from it.
"""

from __future__ import annotations

import importlib
from typing import Any

import numpy as np

from estimators.isam2.factors import known_map_error, landmark_error, scan_error
from estimators.isam2.settings import NOISE_FLOOR, PRIOR_VARIANCE_FLOOR, Isam2Settings
from estimators.isam2.tangent import state_covariance, tangent_covariance
from quadslam_env.config_schema import ConfigError
from quadslam_env.estimation import Estimate, register
from quadslam_env.measurements import Control, ImuSample, LidarScan
from quadslam_env.models.frames import dcm_from_euler, euler_from_dcm
from quadslam_env.models.lidar import lidar_inverse
from quadslam_env.types import GRAVITY, POSE_DIM, FloatArray

GTSAM_INSTALL = "pip install 'quadslam[gtsam]'"
"""How to install the optional dependency (GTSAM 4.3)."""

NAV_DIM = 15
"""Keyframe tangent (δθ, δt, δv_N, δb_a, δb_ω): Pose3 (6) + velocity (3) + biases (6)."""

# Column blocks of the linearised CombinedImuFactor, keys (X_i, V_i, X_j, V_j, B_i, B_j).
_COLS_I = np.r_[0:9, 18:24]
_COLS_J = np.r_[9:18, 24:30]


def require_gtsam() -> Any:
    """Import GTSAM, or fail with the install command.

    Returns:
        The ``gtsam`` module.

    Raises:
        ConfigError: GTSAM is not installed (it is the optional extra ``quadslam[gtsam]``).
    """
    try:
        return importlib.import_module("gtsam")
    except ImportError as exc:
        raise ConfigError(
            "estimator.name: got 'isam2', which needs GTSAM (not installed: "
            f"{exc}); allowed: install the optional extra with `{GTSAM_INSTALL}`, or another "
            "estimator (ekf_slam, fastslam, fastslam_kinematic, oracle)"
        ) from exc


def _symbol(gtsam: Any, char: str, index: int) -> int:
    return int(gtsam.symbol(char, index))


@register("isam2")
class Isam2Slam:
    """Fixed-lag (or full) iSAM2 smoothing of IMU preintegration and LiDAR factors.

    Implements :class:`~quadslam_env.estimation.protocol.Estimator` with known data
    association, in known-map (localisation) and unknown-map (SLAM) mode (module docstring).

    Args:
        vehicle: Nominal vehicle parameters (unused: the IMU drives the motion model).
        **params: ``estimator.params``, see :class:`~estimators.isam2.settings.Isam2Settings`.

    Raises:
        ConfigError: GTSAM is not installed.
        ValueError: Unknown key, wrong type or out-of-range value of ``params`` (the message
            names the key, the value and what is allowed).
    """

    uses_truth = False
    associates_unlabeled = False

    def __init__(self, vehicle: Any = None, **params: Any) -> None:
        self.settings = Isam2Settings.from_params(params)
        self._g = require_gtsam()
        self.vehicle = vehicle
        self.last_error = ""
        """Message of the exception that set ``diverged`` ("" while healthy)."""
        self._reset_state()

    def __deepcopy__(self, memo: dict[int, Any]) -> Isam2Slam:
        raise ConfigError(
            "estimator.name: got 'isam2', whose GTSAM smoother cannot be copied; the env "
            "copies its estimator only for an IMU slower than the control (imu.rate_hz < "
            "episode.control_hz), so allowed: imu.rate_hz null or >= episode.control_hz with "
            "isam2, or another estimator"
        )

    # ------------------------------------------------------------------ state
    def _reset_state(self) -> None:
        self.last_error = ""
        self._smoother: Any = None
        self._isam: Any = None
        self._k = 0
        self._t = 0.0
        self._kf_pose: Any = None
        self._kf_vel = np.zeros(3)
        self._kf_bias: Any = None
        self._kf_cov = np.zeros((NAV_DIM, NAV_DIM))
        self._pim: Any = None
        self._pim_noise: tuple[float, float] | None = None
        self._params: Any = None
        self._known: dict[int, FloatArray] | None = None
        self._lm_means: dict[int, FloatArray] = {}
        self._lm_covs: dict[int, FloatArray] = {}
        self._rates = np.zeros(3)
        self._gyro: FloatArray | None = None
        self._diverged = False
        self._cache: Estimate | None = None
        self._last: Estimate | None = None

    @property
    def known_map(self) -> bool:
        """True after a reset with ``known_landmarks`` (localisation only)."""
        return self._known is not None

    @property
    def keyframes(self) -> int:
        """Index of the latest keyframe (0 at reset)."""
        return self._k

    def _key(self, char: str, index: int) -> int:
        return _symbol(self._g, char, index)

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
            ValueError: Wrong shapes, non-finite values, or a malformed known map.
        """
        del rng
        g = self._g
        mean0 = np.asarray(mean0, dtype=float).reshape(-1)
        cov0 = np.asarray(cov0, dtype=float)
        if mean0.shape != (12,) or not np.isfinite(mean0).all():
            raise ValueError(f"reset: mean0 must be a finite (12,) array, got shape {mean0.shape}")
        if cov0.shape != (12, 12) or not np.isfinite(cov0).all():
            raise ValueError(f"reset: cov0 must be a finite (12, 12) array, got shape {cov0.shape}")
        known = None
        if known_landmarks is not None:
            ids = np.asarray(known_landmarks[0]).astype(np.int64).reshape(-1)
            pos = np.asarray(known_landmarks[1], dtype=float).reshape(-1, 3)
            if ids.shape[0] != pos.shape[0] or not np.isfinite(pos).all():
                raise ValueError(
                    "reset: known_landmarks must be (ids (L,), finite positions (L, 3)), got "
                    f"{ids.shape[0]} ids and {pos.shape[0]} positions"
                )
            known = {int(i): pos[j].copy() for j, i in enumerate(ids.tolist())}
        self._reset_state()
        self._known = known
        self._rates = mean0[9:12].copy()
        s = self.settings
        params = g.ISAM2Params()
        params.setRelinearizeThreshold(s.relinearize_threshold)
        params.relinearizeSkip = s.relinearize_skip
        if s.window_s is None:
            self._smoother = self._isam = g.ISAM2(params)
        else:
            self._smoother = g.IncrementalFixedLagSmoother(s.window_s, params)
        euler = mean0[6:9]
        dcm = dcm_from_euler(euler)
        pose0 = g.Pose3(g.Rot3(dcm), mean0[0:3].copy())
        vel0 = dcm @ mean0[3:6]
        x0, v0, b0 = self._key("x", 0), self._key("v", 0), self._key("b", 0)
        sigma = tangent_covariance(
            0.5 * (cov0[:POSE_DIM, :POSE_DIM] + cov0[:POSE_DIM, :POSE_DIM].T),
            dcm,
            mean0[3:6],
            euler,
            floor=PRIOR_VARIANCE_FLOOR,
        )
        W = np.linalg.inv(np.linalg.cholesky(sigma))  # whitening: Wᵀ W = Σ⁻¹
        prior = g.JacobianFactor(
            x0, W[:, 0:6], v0, W[:, 6:9], np.zeros(POSE_DIM), g.noiseModel.Unit.Create(POSE_DIM)
        )
        linpoint = g.Values()
        linpoint.insert(x0, pose0)
        linpoint.insert(v0, vel0)
        graph = g.NonlinearFactorGraph()
        graph.add(g.LinearContainerFactor(prior, linpoint))
        sa, sg = s.bias_prior_sigmas()
        bias0 = g.imuBias.ConstantBias()
        graph.add(
            g.PriorFactorConstantBias(
                b0, bias0, g.noiseModel.Diagonal.Sigmas(np.array([sa] * 3 + [sg] * 3))
            )
        )
        values = g.Values()
        values.insert(x0, pose0)
        values.insert(v0, vel0)
        values.insert(b0, bias0)
        self._kf_pose, self._kf_vel, self._kf_bias = pose0, vel0, bias0
        self._kf_cov[:POSE_DIM, :POSE_DIM] = sigma
        self._kf_cov[POSE_DIM:, POSE_DIM:] = np.diag(np.array([sa] * 3 + [sg] * 3) ** 2)
        try:
            self._solve(graph, values, {x0: 0.0, v0: 0.0, b0: 0.0})
            self._read_keyframe(0)
        except Exception as exc:  # a GTSAM failure: reported as divergence, never raised
            self._diverge(exc)

    def predict(self, imu: ImuSample, control: Control, dt: float) -> None:
        """Preintegrate one IMU sample held over ``dt`` (Forster et al. 2017, eq. 24–26).

        Args:
            imu: Sample with ``accel`` (3,) specific force [m/s², B], ``gyro`` (3,) [rad/s,
                B] and their white-noise stds per sample (continuous densities ``σ² dt``).
            control: Applied control (unused: the IMU drives the motion model).
            dt: Sample period in s (> 0).

        Raises:
            ValueError: Before the first :meth:`reset`, if ``dt`` is not a positive finite
                number, or if the sample is not finite.
        """
        del control
        if self._smoother is None:
            raise ValueError("predict: call reset first (the smoother starts at reset)")
        if not 0.0 < dt < np.inf:
            raise ValueError(f"predict: dt must be a positive finite number of seconds, got {dt}")
        accel = np.asarray(imu.accel, dtype=float).reshape(3)
        gyro = np.asarray(imu.gyro, dtype=float).reshape(3)
        if not (np.isfinite(accel).all() and np.isfinite(gyro).all()):
            raise ValueError("predict: the IMU sample must be finite")
        if self._pim is None:
            self._pim = self._g.PreintegratedCombinedMeasurements(
                self._preintegration_params(imu.accel_sigma, imu.gyro_sigma, dt), self._kf_bias
            )
        self._pim.integrateMeasurement(accel, gyro, dt)
        self._t += dt
        self._gyro = gyro
        self._rates = gyro - np.asarray(self._kf_bias.gyroscope())
        self._cache = None

    def update(self, scan: LidarScan) -> None:
        """Add a keyframe at the scan with its LiDAR factors and update the smoother.

        Every scan makes a keyframe (an empty one too: it bounds the preintegration). Ids
        outside the known map are ignored in known-map mode. After a divergence the scans are
        ignored (the episode ends on that step).

        Args:
            scan: Labeled scan: sorted ``ids`` (k,), ``meas`` (k, 3) = (α rad, β rad, δ m),
                ``sigma`` (3,) noise stds.

        Raises:
            ValueError: On an unlabeled scan (``lidar.association: unknown`` is not supported)
                or measurements that are not a finite (k, 3) array.
        """
        if scan.ids is None:
            raise ValueError(
                "update: isam2 needs labeled scans (lidar.association: known); unknown data "
                "association is not implemented"
            )
        ids = [int(i) for i in np.asarray(scan.ids).reshape(-1).tolist()]
        meas = np.asarray(scan.meas, dtype=float).reshape(-1, 3) if ids else np.zeros((0, 3))
        if meas.shape != (len(ids), 3) or not np.isfinite(meas).all():
            raise ValueError(f"update: scan.meas must be a finite ({len(ids)}, 3) array")
        sigma = np.asarray(scan.sigma, dtype=float).reshape(3)
        if self._diverged or self._smoother is None:
            return
        try:
            self._keyframe(ids, meas, sigma)
        except Exception as exc:  # any GTSAM failure (C++ exceptions arrive as RuntimeError)
            self._diverge(exc)
        self._cache = None

    def estimate(self) -> Estimate:
        """Snapshot of the belief (copies), landmarks sorted by id.

        Returns:
            :class:`Estimate` with the keyframe's smoothed state predicted to now with the
            current preintegration, ``pose_cov`` (9, 9) over (ρ, v_B, Λ), ``rates`` = last
            gyro minus the gyro-bias estimate, the landmarks (known map: the map, zero
            covariance), the biases when estimated and the diagnostics ``diverged``,
            ``n_keyframes``, ``n_mapped``.
        """
        if self._cache is None and self._smoother is None:  # before the first reset
            self._cache = self._neutral()
        if self._cache is None:
            try:
                est = self._build_estimate()
            except Exception as exc:  # a failed prediction or covariance: keep the last one
                self._diverge(exc)
                est = self._fallback()
            self._cache = est
            if not self._diverged:
                self._last = est
        return self._cache

    # ------------------------------------------------------------------ graph
    def _preintegration_params(self, accel_sigma: float, gyro_sigma: float, dt: float) -> Any:
        """GTSAM preintegration settings (NED, gravity ``(0, 0, +g)``) for samples with the
        white-noise stds ``accel_sigma`` (m/s²) and ``gyro_sigma`` (rad/s) per step ``dt``.

        Continuous densities: accelerometer ``σ_a² dt + Q_v``, gyro ``σ_ω² dt + Q_Λ``,
        integration ``integration_sigma² + Q_ρ``, bias walks squared (Forster et al. 2017,
        eq. 35-38 discretise them back with the step).
        """
        noise = (float(accel_sigma) ** 2 * dt, float(gyro_sigma) ** 2 * dt)
        if self._params is not None and self._pim_noise == noise:
            return self._params
        s = self.settings
        q = np.asarray(s.process_noise)
        p = self._g.PreintegrationCombinedParams(np.array([0.0, 0.0, GRAVITY]))
        p.setAccelerometerCovariance(np.diag(np.maximum(noise[0] + q[3:6], NOISE_FLOOR)))
        p.setGyroscopeCovariance(np.diag(np.maximum(noise[1] + q[6:9], NOISE_FLOOR)))
        p.setIntegrationCovariance(
            np.diag(np.maximum(s.integration_sigma**2 + q[0:3], NOISE_FLOOR))
        )
        walk_a, walk_g = s.bias_walks()
        p.setBiasAccCovariance(np.eye(3) * walk_a**2)
        p.setBiasOmegaCovariance(np.eye(3) * walk_g**2)
        self._params, self._pim_noise = p, noise
        return p

    def _solve(self, graph: Any, values: Any, stamps: dict[int, float]) -> None:
        """One smoother update with the new factors, then ``iterations − 1`` more."""
        if self.settings.window_s is None:
            self._smoother.update(graph, values)
            for _ in range(self.settings.iterations - 1):
                self._smoother.update()
        else:
            self._smoother.update(graph, values, stamps)
            for _ in range(self.settings.iterations - 1):
                self._smoother.update()
            self._isam = self._smoother.getISAM2()

    def _keyframe(self, ids: list[int], meas: FloatArray, sigma: FloatArray) -> None:
        """Add keyframe k+1 (or, without IMU samples since keyframe k, factors on k)."""
        g = self._g
        graph = g.NonlinearFactorGraph()
        values = g.Values()
        stamps: dict[int, float] = {}
        t = self._t
        k = self._k
        pose = self._kf_pose
        pim = self._pim
        if pim is not None and pim.deltaTij() > 0.0:
            k += 1
            xi, vi, bi = self._key("x", k - 1), self._key("v", k - 1), self._key("b", k - 1)
            xj, vj, bj = self._key("x", k), self._key("v", k), self._key("b", k)
            graph.add(g.CombinedImuFactor(xi, vi, xj, vj, bi, bj, pim))
            nav = pim.predict(g.NavState(self._kf_pose, self._kf_vel), self._kf_bias)
            pose = nav.pose()
            values.insert(xj, pose)
            values.insert(vj, nav.velocity())
            values.insert(bj, self._kf_bias)
            stamps.update({xj: t, vj: t, bj: t})
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
            # Landmarks never leave the window: a landmark seen again keeps its variable.
            stamps.update({self._key("l", i): t for i in [*self._lm_means, *new]})
        self._solve(graph, values, stamps)
        self._read_keyframe(k, new)

    def _read_keyframe(self, k: int, new: list[int] | None = None) -> None:
        """Take keyframe k's smoothed state, its joint marginal and the landmarks (the
        mapped ones and ``new``, the ids added with this keyframe)."""
        est = self._smoother.calculateEstimate()
        xk, vk, bk = self._key("x", k), self._key("v", k), self._key("b", k)
        pose = est.atPose3(xk)
        vel = np.asarray(est.atVector(vk), dtype=float).reshape(3)
        bias = est.atConstantBias(bk)
        cov = np.asarray(self._isam.jointMarginalCovariance([xk, vk, bk]).fullMatrix())
        mapped = sorted({*self._lm_means, *(new or [])})
        means = {i: np.asarray(est.atPoint3(self._key("l", i)), float) for i in mapped}
        covs: dict[int, FloatArray] = {}
        if self.settings.landmark_covariances:
            for i in means:
                covs[i] = np.asarray(self._isam.marginalCovariance(self._key("l", i)))
        finite = (
            np.isfinite(pose.matrix()).all()
            and np.isfinite(vel).all()
            and np.isfinite(bias.vector()).all()
            and np.isfinite(cov).all()
            and all(np.isfinite(m).all() for m in means.values())
        )
        if not finite:
            raise FloatingPointError(f"isam2: non-finite smoothed state at keyframe {k}")
        self._k = k
        self._kf_pose, self._kf_vel, self._kf_bias = pose, vel, bias
        self._kf_cov = 0.5 * (cov + cov.T)
        self._lm_means = means
        self._lm_covs = covs
        self._pim = None  # the next sample starts a new preintegration at the new bias
        if self._gyro is not None:
            self._rates = self._gyro - np.asarray(bias.gyroscope())

    def _diverge(self, exc: BaseException) -> None:
        self._diverged = True
        self.last_error = f"{type(exc).__name__}: {exc}"

    # ------------------------------------------------------------------ output
    def _predicted(self) -> tuple[Any, FloatArray, FloatArray]:
        """``(pose, v_N (3,), Σ (9, 9) over (δθ, δt, δv_N))`` now: the keyframe state
        predicted with the current preintegration, its covariance propagated."""
        g = self._g
        pim = self._pim
        if pim is None or pim.deltaTij() <= 0.0:
            return self._kf_pose, self._kf_vel, self._kf_cov[:POSE_DIM, :POSE_DIM]
        nav = pim.predict(g.NavState(self._kf_pose, self._kf_vel), self._kf_bias)
        pose, vel = nav.pose(), np.asarray(nav.velocity(), dtype=float)
        # Linearise the IMU factor from the keyframe to the prediction (its error is zero
        # there): whitened rows A_i δx_i + A_j δx_j, so Σ_j = A_j⁻¹ (A_i Σ_i A_iᵀ + I) A_j⁻ᵀ.
        factor = g.CombinedImuFactor(0, 1, 2, 3, 4, 5, pim)
        values = g.Values()
        values.insert(0, self._kf_pose)
        values.insert(1, self._kf_vel)
        values.insert(2, pose)
        values.insert(3, vel)
        values.insert(4, self._kf_bias)
        values.insert(5, self._kf_bias)
        A = np.asarray(factor.linearize(values).jacobian()[0])
        Ai, Aj = A[:, _COLS_I], A[:, _COLS_J]
        inner = Ai @ self._kf_cov @ Ai.T + np.eye(A.shape[0])
        Aj_inv = np.linalg.inv(Aj)
        cov = Aj_inv @ inner @ Aj_inv.T
        return pose, vel, cov[:POSE_DIM, :POSE_DIM]

    def _build_estimate(self) -> Estimate:
        pose, vel_n, cov_t = self._predicted()
        dcm = np.asarray(pose.rotation().matrix(), dtype=float)
        position = np.asarray(pose.translation(), dtype=float).reshape(3)
        euler = euler_from_dcm(dcm)
        vel_body = dcm.T @ vel_n
        pose_cov = state_covariance(cov_t, dcm, vel_body, euler)
        if not (
            np.isfinite(position).all()
            and np.isfinite(vel_n).all()
            and np.isfinite(euler).all()
            and np.isfinite(pose_cov).all()
        ):
            raise FloatingPointError("isam2: non-finite prediction")
        ids, means, covs = self._landmarks()
        bias = self._kf_bias
        accel_bias = gyro_bias = None
        if self.settings.estimate_imu_bias:
            accel_bias = np.asarray(bias.accelerometer(), dtype=float).copy()
            gyro_bias = np.asarray(bias.gyroscope(), dtype=float).copy()
        return Estimate(
            position=position.copy(),
            vel_body=vel_body,
            vel_inertial=vel_n.copy(),
            euler=euler,
            rates=self._rates.copy(),
            pose_cov=pose_cov,
            landmark_ids=ids,
            landmark_means=means,
            landmark_covs=covs,
            accel_bias=accel_bias,
            gyro_bias=gyro_bias,
            diagnostics=self._diagnostics(ids.size),
        )

    def _landmarks(self) -> tuple[np.ndarray, FloatArray, FloatArray]:
        """``(ids (n,), means (n, 3), covs (n, 3, 3))`` sorted by id."""
        if self._known is not None:
            ids = np.array(sorted(self._known), dtype=np.int64)
            means = np.array([self._known[i] for i in ids.tolist()]).reshape(-1, 3)
            return ids, means, np.zeros((ids.size, 3, 3))
        ids = np.array(sorted(self._lm_means), dtype=np.int64)
        means = np.array([self._lm_means[i] for i in ids.tolist()]).reshape(-1, 3)
        covs = np.array([self._lm_covs.get(i, np.zeros((3, 3))) for i in ids.tolist()]).reshape(
            -1, 3, 3
        )
        return ids, means, covs

    def _diagnostics(self, n_mapped: int) -> dict[str, float]:
        return {
            "diverged": float(self._diverged),
            "n_keyframes": float(self._k),
            "n_mapped": float(n_mapped),
        }

    def _neutral(self) -> Estimate:
        """Zero state and covariance, no landmarks (before the first reset, as the EKF)."""
        return Estimate(
            position=np.zeros(3),
            vel_body=np.zeros(3),
            vel_inertial=np.zeros(3),
            euler=np.zeros(3),
            rates=np.zeros(3),
            pose_cov=np.zeros((POSE_DIM, POSE_DIM)),
            landmark_ids=np.zeros(0, dtype=np.int64),
            landmark_means=np.zeros((0, 3)),
            landmark_covs=np.zeros((0, 3, 3)),
            diagnostics=self._diagnostics(0),
        )

    def _fallback(self) -> Estimate:
        """The last finite estimate with the divergence flag (or a neutral one)."""
        last = self._last if self._last is not None else self._neutral()
        diagnostics = {**last.diagnostics, "diverged": 1.0}
        return Estimate(
            position=last.position.copy(),
            vel_body=last.vel_body.copy(),
            vel_inertial=last.vel_inertial.copy(),
            euler=last.euler.copy(),
            rates=last.rates.copy(),
            pose_cov=None if last.pose_cov is None else last.pose_cov.copy(),
            landmark_ids=last.landmark_ids.copy(),
            landmark_means=last.landmark_means.copy(),
            landmark_covs=last.landmark_covs.copy(),
            accel_bias=last.accel_bias,
            gyro_bias=last.gyro_bias,
            diagnostics=diagnostics,
        )
