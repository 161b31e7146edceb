"""The iSAM2 estimator on a linear-Gaussian problem equals a Kalman filter and an RTS smoother.

**The problem** ("IMU in a flat world with point landmarks, no rotation"). The vehicle flies
ballistically at the identity attitude: thrown upwards, its true specific force is zero and the
gyro reads exactly zero. The accelerometer, sampled at 100 Hz, reads ``a_m = b_a + n`` with a
white noise n of std σ_a per sample and a random-walk bias b_a. A keyframe every 10 samples
(10 Hz, the LiDAR's rate) observes known landmarks as world-frame displacements
``z = l − p + ν``, ``ν ~ N(0, diag σ_z²)`` per landmark (some scans see fewer landmarks, one sees
none). Per sample, the state ``x = (p, v, b_a)`` (9,) (NED, m, m/s, m/s²) evolves linearly:

    p' = p + v dt + ½ (a_m − b_a + g) dt²,   v' = v + (a_m − b_a + g) dt,   b_a' = b_a + w,

with the estimator's documented noise model (docs/isam2.md, :class:`Isam2Settings`): the
accelerometer noise of variance ``σ_a² + q_v / dt`` per sample through ``(½ dt², dt)`` (the
sample's density ``σ_a² dt`` plus the v block of ``process_noise``), a position noise
``(integration_sigma² + q_ρ) dt`` per sample, and a bias walk ``σ_w² dt``; with the biases held
(``estimate_imu_bias: false``) every keyframe also has the prior ``b_a ~ N(0, σ_b0²)``, which
the filter takes as the pseudo-measurement ``0 = b_a + ν`` at each scan. The prior is Gaussian
over (p, v) with a position–velocity cross-covariance, and ``b_a ~ N(0, σ_b0²)``. The data are
drawn from this model (without the pseudo-measurements: with held biases σ_b0 and σ_w are
1e-5, far below the noise). The reference is the textbook Kalman filter at the sample rate and the
Rauch–Tung–Striebel smoother, in plain numpy below.

**What runs through the project's code.** The estimator itself, :class:`Isam2Slam`: ``reset``
(the prior mapped to GTSAM's tangent as a ``LinearContainerFactor``, the bias prior), ``predict``
(the preintegration parameters: densities from the samples' stds, process noise, integration
noise, bias walks; GTSAM's ``PreintegratedCombinedMeasurements``), ``update`` (one keyframe per
scan with a ``CombinedImuFactor``, the known-map factor with the noise the estimator builds from
``scan.sigma``, full iSAM2 or the fixed-lag smoother), and its read-out (the keyframe's joint
marginal, and between keyframes the state and covariance propagated through the linearised IMU
factor). One piece is replaced: the LiDAR's (azimuth, elevation, range) error, nonlinear in the
position for any geometry, by the displacement error above (:func:`_displacement_error`,
patched in for :func:`estimators.isam2.factors.known_map_error` where the estimator calls it:
the same factor on the keyframe pose, the same noise model).

**Why the equality holds.** At the identity attitude with zero gyro readings, the IMU factor's
error is linear in (p, v, b_a): GTSAM corrects the preintegrated ΔP, ΔV to first order in the
bias, which is exact when ΔR = I, and gravity enters as a known input. Its covariance is the
per-sample model above summed exactly (held samples). So the Gaussian over the keyframes'
(p, v, b_a) that the smoother holds is the Kalman filter's model marginalised to the
keyframes: the smoother's mean is the RTS mean, its marginals the RTS covariances, and the last
keyframe's marginal is the filtered one. Compared: after each scan, the last keyframe's mean
and (p, v, b_a) marginal against the filter's; halfway between scans, the estimator's
prediction against the filter's; at the end of the full smoother, every keyframe's smoothed
mean (``calculateBestEstimate``, the full back-substitution) and joint marginal against RTS.

**Why not to machine precision, and the tolerance.** Each keyframe also carries an attitude and
a gyro bias, which a ``CombinedImuFactor`` always has. Their priors are floored — attitude
variance :data:`~estimators.isam2.settings.PRIOR_VARIANCE_FLOOR` (1e-8 rad²), gyro bias and
walk :data:`~estimators.isam2.settings.FIXED_BIAS_SIGMA`, gyro density
:data:`~estimators.isam2.settings.NOISE_FLOOR` — so the attitude keeps a variance Σ_θ of about
1e-8 rad². GTSAM's error chart (residuals in the body frame) couples it to (p, v) through terms
proportional to the residuals and to the bias-corrected specific force, both noise-sized here.
(Hence the ballistic flight: hovering, with the specific force g, the same run differs from the
filter by 5e-4, the tilt uncertainty turned into acceleration, which a filter over (p, v, b_a)
does not have.) The differences — means in units of the filter's std, covariances in
correlation units ``|ΔP_ij| / √(P_ii P_jj)`` — are therefore of order Σ_θ times squared
whitened residuals: 2e-8 for the full smoother, 7e-8 for the fixed lag (whose marginalised
factors keep their linearisation points). The bound is 30 Σ_θ (3e-7). With the attitude floor
lowered to 1e-12 rad² the differences drop to 5e-10 (the third case), which shows that they are
this coupling and not the model: a 1 % error in the accelerometer's density, or 10 % in the
bias walk or the position process noise, shows at 3e-6 or more.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pytest

import estimators.isam2.estimator as isam2_estimator
import estimators.isam2.graph as isam2_graph
from estimators.isam2.estimator import Isam2Slam
from estimators.isam2.factors import ErrorFunction
from estimators.isam2.settings import FIXED_BIAS_SIGMA, NOISE_FLOOR, PRIOR_VARIANCE_FLOOR
from quadslam_env.estimation.measurements import Control, ImuSample, LidarScan
from quadslam_env.types import GRAVITY, FloatArray

gtsam = pytest.importorskip("gtsam")

DT = 0.01
"""IMU sample period, s."""
SAMPLES_PER_SCAN = 10
"""IMU samples between two scans (keyframes at 10 Hz)."""
SCANS = 20
"""Keyframes after the first (2 s of flight)."""
ACCEL_SIGMA = 0.05
"""Accelerometer white-noise std per sample, m/s²."""
RETURN_SIGMA = np.array([0.05, 0.04, 0.08])
"""Std of a landmark displacement per axis (N, E, D), m."""
LANDMARKS = np.array([[5.0, 2.0, -1.0], [-3.0, 4.0, 0.0], [2.0, -6.0, -2.0], [0.0, 0.0, -8.0]])
"""Known landmark positions in N, m."""
PROCESS_NOISE = (1e-6, 1e-6, 1e-6, 4e-5, 4e-5, 4e-5, 0.0, 0.0, 0.0)
"""``process_noise`` over (ρ m²/s, v m²/s³, Λ rad²/s): none on the attitude, which stays pinned."""
P0 = np.array(
    [
        [0.04, 0.0, 0.0, 0.01, 0.0, 0.0],
        [0.0, 0.04, 0.0, 0.0, 0.0, 0.0],
        [0.0, 0.0, 0.09, 0.0, 0.0, 0.0],
        [0.01, 0.0, 0.0, 0.01, 0.0, 0.0],
        [0.0, 0.0, 0.0, 0.0, 0.01, 0.0],
        [0.0, 0.0, 0.0, 0.0, 0.0, 0.02],
    ]
)
"""Prior covariance over (p m, v m/s), with a north position–velocity cross term."""
COUPLING_BOUND = 30.0
"""Bound on the differences in units of the attitude variance Σ_θ (module docstring)."""


def _displacement_error(landmarks: FloatArray, measured: FloatArray) -> ErrorFunction:
    """Linear stand-in for :func:`~estimators.isam2.factors.known_map_error`: one scan of
    world-frame displacements ``z = l − p`` on the keyframe pose.

    The error ``(l − t) − z`` (3k,) depends on the translation t only: GTSAM's ``Pose3``
    perturbation ``t ← t + C_NB δt`` gives the Jacobian ``(0, −C_NB)`` per return over
    ``(δθ, δt)``, no attitude column, so the factor does not couple to the attitude.

    Args:
        landmarks: (k, 3) known positions of the observed landmarks in N, m.
        measured: (k, 3) their displacements from the vehicle in N, m.
    """
    lms = np.array(landmarks, dtype=float).reshape(-1, 3)
    meas = np.array(measured, dtype=float).reshape(-1, 3)
    k = lms.shape[0]

    def error(this: Any, values: Any, H: Any) -> FloatArray:
        pose = values.atPose3(this.keys()[0])
        if H is not None:
            jac = np.zeros((3 * k, 6))
            jac[:, 3:6] = np.tile(-pose.rotation().matrix(), (k, 1))
            H[0] = jac
        return np.asarray((lms - pose.translation()) - meas).reshape(-1)

    return error


# ------------------------------------------------------------------ the linear-Gaussian model


@dataclass(frozen=True)
class LinearModel:
    """The per-sample linear model of the module docstring, from the estimator's parameters.

    Attributes:
        params: ``estimator.params`` given to :class:`Isam2Slam`.
        bias_sigma0: Prior std per axis of the accelerometer bias, m/s².
        bias_walk: Its random-walk density, m/s²/√s.
        bias_held: The biases are held (``estimate_imu_bias: false``): the prior of std
            ``bias_sigma0`` on every keyframe's bias, not only the first.
        F: (9, 9) transition of ``(p, v, b_a)`` over one sample.
        G: (9, 3) the sample's input ``a_m + g`` into the state.
        Q: (9, 9) process-noise covariance per sample.
    """

    params: dict[str, Any]
    bias_sigma0: float
    bias_walk: float
    bias_held: bool = False
    F: FloatArray = field(init=False)
    G: FloatArray = field(init=False)
    Q: FloatArray = field(init=False)

    def __post_init__(self) -> None:
        eye = np.eye(3)
        F = np.eye(9)
        F[0:3, 3:6] = DT * eye
        F[0:3, 6:9] = -0.5 * DT**2 * eye
        F[3:6, 6:9] = -DT * eye
        G = np.zeros((9, 3))
        G[0:3] = 0.5 * DT**2 * eye
        G[3:6] = DT * eye
        q = self.params["process_noise"]
        accel_var = ACCEL_SIGMA**2 + q[3] / DT  # density σ_a² dt + q_v, per sample
        Q = accel_var * G @ G.T
        Q[0:3, 0:3] += (self.params["integration_sigma"] ** 2 + q[0]) * DT * eye
        Q[6:9, 6:9] += self.bias_walk**2 * DT * eye
        object.__setattr__(self, "F", F)
        object.__setattr__(self, "G", G)
        object.__setattr__(self, "Q", Q)

    @classmethod
    def of(cls, estimate_bias: bool, window_s: float | None) -> LinearModel:
        """The model with the accelerometer bias estimated (prior 0.05 m/s², walk 2e-3
        m/s²/√s) or held at zero (:data:`FIXED_BIAS_SIGMA` for both); the gyro bias is
        held at zero (its prior and walk at the floor) so the attitude stays pinned."""
        params: dict[str, Any] = {
            "window_s": window_s,
            "process_noise": list(PROCESS_NOISE),
            "estimate_imu_bias": estimate_bias,
            "accel_bias_sigma0": 0.05,
            "accel_bias_walk": 2e-3,
            "gyro_bias_sigma0": 0.0,
            "gyro_bias_walk": 0.0,
            "integration_sigma": 1e-4,
            # Relinearised at every keyframe: the equalities below are the Gaussian algebra's,
            # which the default schedule (every 50 keyframes) meets only to ~1e-6 σ.
            "relinearize_skip": 1,
        }
        if estimate_bias:
            return cls(params, 0.05, 2e-3)
        return cls(params, FIXED_BIAS_SIGMA, FIXED_BIAS_SIGMA, bias_held=True)


@dataclass
class Flight:
    """Data drawn from :class:`LinearModel`: what the estimator and the filter receive.

    Attributes:
        mean0: (6,) prior mean of (p, v).
        accel: (SCANS, SAMPLES_PER_SCAN, 3) accelerometer samples, m/s².
        scans: Per scan, the visible landmark ids (sorted) and their displacements (k, 3).
    """

    mean0: FloatArray
    accel: FloatArray
    scans: list[tuple[list[int], FloatArray]]


def _simulate(model: LinearModel, rng: np.random.Generator) -> Flight:
    """A ballistic flight from the model: thrown up and north-west, zero true specific force."""
    p, v = np.zeros(3), np.array([1.0, -0.5, -3.0])
    b = rng.normal(0.0, model.bias_sigma0, 3)
    mean0 = np.concatenate((p, v)) + np.linalg.cholesky(P0) @ rng.normal(size=6)
    g = np.array([0.0, 0.0, GRAVITY])
    accel = np.empty((SCANS, SAMPLES_PER_SCAN, 3))
    scans = []
    for k in range(SCANS):
        for j in range(SAMPLES_PER_SCAN):
            accel[k, j] = b + rng.normal(0.0, ACCEL_SIGMA, 3)
            p, v = p + v * DT + 0.5 * g * DT**2, v + g * DT
            b = b + rng.normal(0.0, model.bias_walk * np.sqrt(DT), 3)
        ids = [] if k == 6 else [i for i in range(len(LANDMARKS)) if (k + i) % 3 != 0]
        z = LANDMARKS[ids] - p + rng.normal(size=(len(ids), 3)) * RETURN_SIGMA
        scans.append((ids, z.reshape(-1, 3)))
    return Flight(mean0, accel, scans)


# ------------------------------------------------------------------ the textbook reference


@dataclass
class KalmanRun:
    """Kalman filter and RTS smoother at the sample rate.

    Attributes:
        predicted: Per sample n = 0 … N, ``(x (9,), P (9, 9))`` before the scan at n.
        filtered: Per sample, after the scan at n (the prediction where there is none).
        smoothed: Per sample, the RTS estimate given every scan.
    """

    predicted: list[tuple[FloatArray, FloatArray]]
    filtered: list[tuple[FloatArray, FloatArray]]
    smoothed: list[tuple[FloatArray, FloatArray]]


def _kalman(model: LinearModel, flight: Flight) -> KalmanRun:
    """The Kalman filter (Joseph-form update) and the Rauch–Tung–Striebel smoother."""
    x = np.concatenate((flight.mean0, np.zeros(3)))
    P = np.zeros((9, 9))
    P[0:6, 0:6] = P0
    P[6:9, 6:9] = model.bias_sigma0**2 * np.eye(3)
    g = np.array([0.0, 0.0, GRAVITY])
    predicted, filtered = [(x, P)], [(x, P)]
    for k in range(SCANS):
        for j in range(SAMPLES_PER_SCAN):
            x = model.F @ x + model.G @ (flight.accel[k, j] + g)
            P = model.F @ P @ model.F.T + model.Q
            predicted.append((x, P))
            filtered.append((x, P))
        ids, z = flight.scans[k]
        if ids:
            H = np.zeros((3 * len(ids), 9))
            H[:, 0:3] = np.tile(-np.eye(3), (len(ids), 1))
            R = np.diag(np.tile(RETURN_SIGMA**2, len(ids)))
            residual = z.reshape(-1) - (LANDMARKS[ids] - x[0:3]).reshape(-1)
            gain = np.linalg.solve(H @ P @ H.T + R, H @ P).T
            A = np.eye(9) - gain @ H
            x, P = x + gain @ residual, A @ P @ A.T + gain @ R @ gain.T
            filtered[-1] = (x, P)
        if model.bias_held:  # the keyframe's bias prior: the pseudo-measurement 0 = b_a + ν
            H = np.zeros((3, 9))
            H[:, 6:9] = np.eye(3)
            gain = np.linalg.solve(H @ P @ H.T + model.bias_sigma0**2 * np.eye(3), H @ P).T
            A = np.eye(9) - gain @ H
            x, P = A @ x, A @ P @ A.T + model.bias_sigma0**2 * gain @ gain.T
            filtered[-1] = (x, P)
    smoothed = [filtered[-1]]
    for n in range(len(filtered) - 2, -1, -1):
        (xf, Pf), (xp, Pp), (xs, Ps) = filtered[n], predicted[n + 1], smoothed[0]
        C = np.linalg.solve(Pp, model.F @ Pf).T  # Pf Fᵀ Pp⁻¹
        smoothed.insert(0, (xf + C @ (xs - xp), Pf + C @ (Ps - Pp) @ C.T))
    return KalmanRun(predicted, filtered, smoothed)


# ------------------------------------------------------------------ the estimator


def _tangent_state(pose: Any, vel: Any, bias: Any) -> FloatArray:
    """(p, v_N, b_a) (9,) of a keyframe's GTSAM values."""
    return np.concatenate(
        (np.asarray(pose.translation()), np.asarray(vel), np.asarray(bias.accelerometer()))
    )


# (δt, δv_N, δb_a) in the keyframe tangent (δθ, δt, δv_N, δb_a, δb_ω): = (p, v, b_a) at C_NB = I.
_PVB = np.r_[3:12]


@dataclass
class EstimatorRun:
    """What the estimator reported.

    Attributes:
        filtered: Per keyframe 0 … SCANS, the last keyframe's (p, v, b_a) mean and marginal
            covariance right after its scan.
        midway: Per scan interval, the estimator's (p, v) mean and covariance halfway, and the
            public estimate's position and its covariance block.
        estimator: The estimator after the last scan.
    """

    filtered: list[tuple[FloatArray, FloatArray]] = field(default_factory=list)
    midway: list[tuple[FloatArray, FloatArray, FloatArray, FloatArray]] = field(
        default_factory=list
    )
    estimator: Any = None


def _run_estimator(
    model: LinearModel, flight: Flight, monkeypatch: pytest.MonkeyPatch
) -> EstimatorRun:
    """Fly the data through :class:`Isam2Slam` with the displacement factor patched in."""
    monkeypatch.setattr(isam2_estimator, "known_map_error", _displacement_error)
    est = Isam2Slam(**model.params)
    mean0 = np.zeros(12)
    mean0[0:6] = flight.mean0  # at Λ = 0, v_B = v_N
    cov0 = np.zeros((12, 12))
    cov0[0:6, 0:6] = P0  # attitude and rates known: variance 0 (floored by the estimator)
    known = (np.arange(len(LANDMARKS)), LANDMARKS)
    est.reset(mean0, cov0, np.random.default_rng(0), known_landmarks=known)
    run = EstimatorRun(estimator=est)
    control = Control(0.0, np.zeros(3))  # unused by the estimator: the IMU drives the motion

    def record() -> None:
        mean = _tangent_state(est._kf_pose, est._kf_vel, est._kf_bias)
        run.filtered.append((mean, est._kf_cov[np.ix_(_PVB, _PVB)]))

    record()
    for k in range(SCANS):
        for j in range(SAMPLES_PER_SCAN):
            t = DT * (k * SAMPLES_PER_SCAN + j + 1)
            sample = ImuSample(t, flight.accel[k, j], np.zeros(3), ACCEL_SIGMA, 0.0)
            est.predict(sample, control, DT)
            if j == SAMPLES_PER_SCAN // 2 - 1:
                pose, vel, _, cov = est._predicted()
                snap = est.estimate()
                mean = np.concatenate((np.asarray(pose.translation()), vel))
                position = np.asarray(snap.position[0])
                assert snap.pose_cov is not None
                run.midway.append((mean, cov[3:9, 3:9], position, snap.pose_cov[0, 0:3, 0:3]))
        ids, z = flight.scans[k]
        t = DT * SAMPLES_PER_SCAN * (k + 1)
        est.update(LidarScan(t, np.array(ids, dtype=np.int64), z, RETURN_SIGMA))
        assert est.last_error == "", est.last_error
        record()
    return run


def _differences(
    mean: FloatArray, cov: FloatArray, ref_mean: FloatArray, ref_cov: FloatArray
) -> tuple[float, float]:
    """``(max |Δmean| / σ, max |ΔP_ij| / √(P_ii P_jj))`` against the reference."""
    std = np.sqrt(np.diag(ref_cov))
    return (
        float(np.max(np.abs(mean - ref_mean) / std)),
        float(np.max(np.abs(cov - ref_cov) / np.outer(std, std))),
    )


def _attitude_variance(floor: float) -> float:
    """Σ_θ at the end of the flight (rad²): the prior floor, the gyro bias's prior and walk at
    :data:`FIXED_BIAS_SIGMA` (an upper bound where the bias is held by a prior at every
    keyframe), the gyro density at :data:`NOISE_FLOOR`."""
    T = SCANS * SAMPLES_PER_SCAN * DT
    return floor + FIXED_BIAS_SIGMA**2 * (T**2 + T**3 / 3.0) + NOISE_FLOOR * T


# ------------------------------------------------------------------ tests


@pytest.mark.parametrize(
    ("estimate_bias", "floor"),
    [(True, PRIOR_VARIANCE_FLOOR), (False, PRIOR_VARIANCE_FLOOR), (True, 1e-12)],
    ids=["bias-estimated", "bias-held", "attitude-floor-1e-12"],
)
def test_full_smoother_equals_kalman_filter_and_rts_smoother(
    estimate_bias: bool, floor: float, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Full iSAM2 (``window_s: null``): after each scan its last keyframe is the Kalman
    filter's estimate, halfway between scans its prediction is the filter's, and at the end
    every keyframe's smoothed mean and marginal are the RTS smoother's (module docstring)."""
    monkeypatch.setattr(isam2_graph, "PRIOR_VARIANCE_FLOOR", floor)
    model = LinearModel.of(estimate_bias, window_s=None)
    flight = _simulate(model, np.random.default_rng(7))
    kf = _kalman(model, flight)
    run = _run_estimator(model, flight, monkeypatch)
    bound = COUPLING_BOUND * _attitude_variance(floor)
    worst = [0.0, 0.0]

    def check(diffs: tuple[float, float], what: str) -> None:
        assert max(diffs) < bound, f"{what}: mean {diffs[0]:.1e} σ, cov {diffs[1]:.1e}"
        worst[:] = np.maximum(worst, diffs).tolist()

    for k, (mean, cov) in enumerate(run.filtered):
        ref_mean, ref_cov = kf.filtered[k * SAMPLES_PER_SCAN]
        check(_differences(mean, cov, ref_mean, ref_cov), f"keyframe {k} against the filter")
    for k, (mean, cov, position, position_cov) in enumerate(run.midway):
        ref_mean, ref_cov = kf.predicted[k * SAMPLES_PER_SCAN + SAMPLES_PER_SCAN // 2]
        check(_differences(mean, cov, ref_mean[0:6], ref_cov[0:6, 0:6]), f"halfway {k}")
        check(
            _differences(position, position_cov, ref_mean[0:3], ref_cov[0:3, 0:3]),
            f"estimate() halfway {k}",
        )
    isam = run.estimator._isam
    best = isam.calculateBestEstimate()  # every keyframe back-substituted in full
    for k in range(SCANS + 1):
        keys = [gtsam.symbol(c, k) for c in "xvb"]
        mean = _tangent_state(
            best.atPose3(keys[0]), best.atVector(keys[1]), best.atConstantBias(keys[2])
        )
        cov = np.asarray(isam.jointMarginalCovariance(keys).fullMatrix())[np.ix_(_PVB, _PVB)]
        ref_mean, ref_cov = kf.smoothed[k * SAMPLES_PER_SCAN]
        check(_differences(mean, cov, ref_mean, ref_cov), f"keyframe {k} against RTS")
    print(
        f"largest difference: mean {worst[0]:.1e} σ, covariance {worst[1]:.1e} (bound {bound:.1e})"
    )


@pytest.mark.parametrize("every", [1, 3])
def test_fixed_lag_last_state_equals_kalman_filter(
    every: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Fixed lag (``window_s: 0.35``, older keyframes marginalised every fifth keyframe,
    relinearised at every keyframe or every third): after each scan the last keyframe is the
    Kalman filter's estimate, and halfway between scans the prediction is."""
    model = LinearModel.of(True, window_s=0.35)
    model.params["relinearize_skip"] = every
    flight = _simulate(model, np.random.default_rng(8))
    kf = _kalman(model, flight)
    run = _run_estimator(model, flight, monkeypatch)
    bound = COUPLING_BOUND * _attitude_variance(PRIOR_VARIANCE_FLOOR)
    worst = np.zeros(2)
    for k, (mean, cov) in enumerate(run.filtered):
        ref_mean, ref_cov = kf.filtered[k * SAMPLES_PER_SCAN]
        diffs = _differences(mean, cov, ref_mean, ref_cov)
        assert max(diffs) < bound, f"keyframe {k}: mean {diffs[0]:.1e} σ, cov {diffs[1]:.1e}"
        worst = np.maximum(worst, diffs)
    for k, (mean, cov, _, _) in enumerate(run.midway):
        ref_mean, ref_cov = kf.predicted[k * SAMPLES_PER_SCAN + SAMPLES_PER_SCAN // 2]
        diffs = _differences(mean, cov, ref_mean[0:6], ref_cov[0:6, 0:6])
        assert max(diffs) < bound, f"halfway {k}: mean {diffs[0]:.1e} σ, cov {diffs[1]:.1e}"
        worst = np.maximum(worst, diffs)
    # The window did marginalise: the first keyframes are gone from the smoother.
    values = run.estimator._smoother.calculateEstimate()
    assert not values.exists(gtsam.symbol("x", 0)) and values.exists(gtsam.symbol("x", SCANS))
    print(
        f"largest difference: mean {worst[0]:.1e} σ, covariance {worst[1]:.1e} (bound {bound:.1e})"
    )
