"""The iSAM2 estimator (``estimator.name: isam2``, :mod:`estimators.isam2`): factor Jacobians,
agreement with batch Levenberg–Marquardt, determinism, and flight in the env."""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from conftest import fly_dflqr

import estimators
import quadslam_env  # noqa: F401  (registers the env ids)
from agents.control.dflqr import DFLQRPolicy
from estimators.isam2.factors import (
    known_map_error,
    landmark_error,
    lidar_error,
    lidar_error_one,
    scan_error,
)
from estimators.isam2.settings import Isam2Settings
from estimators.isam2.tangent import state_jacobian, tangent_covariance
from quadslam_env.config.scenario import load_scenario
from quadslam_env.models.frames import dcm_from_euler, euler_from_dcm
from quadslam_env.models.lidar import lidar_measure, measure_from_body, measure_jacobian_body
from quadslam_env.schema import ConfigError

gtsam = pytest.importorskip("gtsam")

SCENARIO = "paper_ekf_figure8_known"
SCENARIO_ENV = "QuadSLAM-v0"


def _pose(rng: np.random.Generator) -> Any:
    euler = rng.uniform([-0.4, -0.4, -np.pi], [0.4, 0.4, np.pi])
    return gtsam.Pose3(gtsam.Rot3(dcm_from_euler(euler)), rng.normal(0.0, 2.0, 3))


def _numerical(fun: Callable[[Any], np.ndarray], x: Any, dim: int, eps: float = 1e-6) -> Any:
    """Central differences of ``fun(x.retract(δ))`` over the tangent (dim,) of ``x``."""
    cols = []
    for i in range(dim):
        d = np.zeros(dim)
        d[i] = eps
        plus = fun(x.retract(d) if hasattr(x, "retract") else x + d)
        minus = fun(x.retract(-d) if hasattr(x, "retract") else x - d)
        cols.append((plus - minus) / (2 * eps))
    return np.stack(cols, axis=-1)


# ------------------------------------------------------------------ factors


def test_lidar_factor_jacobians_match_finite_differences() -> None:
    rng = np.random.default_rng(0)
    sigma = np.array([0.006, 0.005, 0.1])
    noise = gtsam.noiseModel.Diagonal.Sigmas(sigma)
    for _ in range(20):
        pose = _pose(rng)
        # A landmark 5-20 m away in a random direction (including near the azimuth's wrap).
        lm = pose.translation() + rng.normal(size=3) * rng.uniform(5.0, 20.0)
        meas = lidar_measure(pose.translation(), pose.rotation().matrix(), lm) + rng.normal(
            0, sigma
        )
        xk, lk = gtsam.symbol("x", 0), gtsam.symbol("l", 0)
        factor = gtsam.CustomFactor(noise, [xk, lk], landmark_error(meas))
        values = gtsam.Values()
        values.insert(xk, pose)
        values.insert(lk, lm)
        A, _ = factor.linearize(values).jacobian()
        H = A * sigma[:, None]  # unwhiten the rows

        def err_pose(p, lm=lm, meas=meas):
            return lidar_error_one(p.rotation().matrix(), p.translation(), lm, meas)[0]

        def err_lm(point, pose=pose, meas=meas):
            return lidar_error_one(pose.rotation().matrix(), pose.translation(), point, meas)[0]

        np.testing.assert_allclose(H[:, 0:6], _numerical(err_pose, pose, 6), atol=1e-6)
        np.testing.assert_allclose(H[:, 6:9], _numerical(err_lm, lm, 3), atol=1e-6)
        # The factor's compiled loop is the model's vectorised h and ∂h/∂c composed as in
        # the module docstring (∂e/∂δθ = Hc [c]×, ∂e/∂δt = −Hc, ∂e/∂l = Hc C_NBᵀ).
        dcm = pose.rotation().matrix()
        e, H_pose, H_lm = lidar_error(dcm, pose.translation(), lm[None], meas[None])
        c = (lm - pose.translation()) @ dcm
        Hc = measure_jacobian_body(c)
        want = measure_from_body(c) - meas
        want[:2] = (want[:2] + np.pi) % (2 * np.pi) - np.pi
        skew = np.array([[0.0, -c[2], c[1]], [c[2], 0.0, -c[0]], [-c[1], c[0], 0.0]])
        np.testing.assert_allclose(e[0], want, atol=1e-12)
        np.testing.assert_allclose(H_pose[0], np.hstack((Hc @ skew, -Hc)), atol=1e-12)
        np.testing.assert_allclose(H_lm[0], Hc @ dcm.T, atol=1e-12)


def test_scan_factor_is_the_per_return_factors_stacked() -> None:
    """One factor per scan (keys pose, l_1 … l_k): the per-return errors and Jacobians."""
    rng = np.random.default_rng(3)
    pose = _pose(rng)
    lms = pose.translation() + rng.normal(size=(4, 3)) * 10.0
    sigma = np.array([0.006, 0.005, 0.1])
    meas = lidar_measure(pose.translation(), pose.rotation().matrix(), lms)
    meas += rng.normal(0.0, 1.0, (4, 3)) * sigma
    xk = gtsam.symbol("x", 0)
    lks = [gtsam.symbol("l", j) for j in range(4)]
    values = gtsam.Values()
    values.insert(xk, pose)
    for lk, lm in zip(lks, lms, strict=True):
        values.insert(lk, lm)
    scan = gtsam.CustomFactor(
        gtsam.noiseModel.Diagonal.Sigmas(np.tile(sigma, 4)), [xk, *lks], scan_error(meas)
    )
    A, b = scan.linearize(values).jacobian()
    for j, lk in enumerate(lks):
        one = gtsam.CustomFactor(
            gtsam.noiseModel.Diagonal.Sigmas(sigma), [xk, lk], landmark_error(meas[j])
        )
        A1, b1 = one.linearize(values).jacobian()
        rows = slice(3 * j, 3 * j + 3)
        np.testing.assert_allclose(b[rows], b1, atol=1e-12)
        np.testing.assert_allclose(A[rows, 0:6], A1[:, 0:6], atol=1e-9)
        others = np.delete(A[rows, 6:], np.s_[3 * j : 3 * j + 3], axis=1)
        np.testing.assert_allclose(A[rows, 6 + 3 * j : 9 + 3 * j], A1[:, 6:9], atol=1e-9)
        assert not others.any()


def test_known_map_factor_stacks_returns_and_wraps_azimuth() -> None:
    rng = np.random.default_rng(1)
    pose = _pose(rng)
    lms = pose.translation() + rng.normal(size=(5, 3)) * 10.0
    meas = lidar_measure(pose.translation(), pose.rotation().matrix(), lms)
    meas[0, 0] += 2 * np.pi - 1e-3  # the same direction, one turn on: error -1e-3 rad
    sigma = np.array([0.006, 0.005, 0.1])
    xk = gtsam.symbol("x", 0)
    factor = gtsam.CustomFactor(
        gtsam.noiseModel.Diagonal.Sigmas(np.tile(sigma, 5)), [xk], known_map_error(lms, meas)
    )
    values = gtsam.Values()
    values.insert(xk, pose)
    e = factor.unwhitenedError(values)
    assert e.shape == (15,)
    assert e[0] == pytest.approx(1e-3, abs=1e-9)
    np.testing.assert_allclose(e[1:], 0.0, atol=1e-9)
    A, _ = factor.linearize(values).jacobian()
    fun = known_map_error(lms, meas)

    class _Keys:
        def keys(self):
            return [xk]

    def err(p):
        v = gtsam.Values()
        v.insert(xk, p)
        return fun(_Keys(), v, None)

    np.testing.assert_allclose(A * np.tile(sigma, 5)[:, None], _numerical(err, pose, 6), atol=1e-6)


def test_state_jacobian_maps_gtsam_tangent_to_env_state() -> None:
    """∂(ρ, v_B, Λ)/∂(δθ, δt, δv_N) against finite differences of GTSAM's retraction."""
    rng = np.random.default_rng(2)
    for _ in range(10):
        pose = _pose(rng)
        vel_n = rng.normal(0.0, 2.0, 3)

        def state(delta, pose=pose, vel_n=vel_n):
            p = pose.retract(delta[0:6])
            C = p.rotation().matrix()
            return np.concatenate((p.translation(), C.T @ (vel_n + delta[6:9]), euler_from_dcm(C)))

        C = pose.rotation().matrix()
        euler = euler_from_dcm(C)
        J = state_jacobian(C, C.T @ vel_n, euler)
        np.testing.assert_allclose(J, _numerical(state, np.zeros(9), 9), atol=1e-6)
        # The inverse map used for the prior is the inverse.
        P = np.diag(rng.uniform(0.01, 1.0, 9))
        S = tangent_covariance(P, C, C.T @ vel_n, euler)
        np.testing.assert_allclose(J @ S @ J.T, P, atol=1e-10)


# ------------------------------------------------------------------ settings


def test_settings_validate_keys_and_values() -> None:
    with pytest.raises(ValueError) as err:
        Isam2Settings.from_dict({"relinearise_tolerance": 2.0})  # an EKF-only key
    message = str(err.value)
    assert message.startswith("estimator.params.relinearise_tolerance: unknown key; allowed:")
    assert "'window_s'" in message and "'estimate_imu_bias'" in message
    with pytest.raises(ValueError, match=r"estimator\.params\.window_s: got -1\.0"):
        Isam2Settings.from_dict({"window_s": -1.0})
    with pytest.raises(ValueError, match=r"estimator\.params\.iterations: got 0"):
        Isam2Settings.from_dict({"iterations": 0})
    with pytest.raises(ValueError, match=r"estimator\.params\.process_noise"):
        Isam2Settings.from_dict({"process_noise": [0.0] * 8})
    with pytest.raises(
        ValueError, match=r"estimator\.params\.estimate_imu_bias: got 1; allowed: true or false"
    ):
        Isam2Settings.from_dict({"estimate_imu_bias": 1})
    with pytest.raises(ValueError, match=r"factorization: got 'lu'; allowed: one of \['qr'"):
        Isam2Settings.from_dict({"factorization": "lu"})
    assert Isam2Settings.from_dict({"window_s": None}).window_s is None
    assert Isam2Settings.from_dict({}).window_s == 3.0
    # The EKF's shared keys keep their meaning, so a scenario's EKF params carry over.
    s = Isam2Settings.from_dict({"process_noise": [0.0] * 9, "estimate_imu_bias": True})
    assert s.estimate_imu_bias
    np.testing.assert_array_equal(s.bias_prior_sigmas(), [0.05] * 3 + [0.01] * 3)


def test_env_rejects_bad_params_and_accepts_unknown_association() -> None:
    with pytest.raises(ValueError, match=r"estimator\.params\.max_iterations: unknown key"):
        gym.make(
            SCENARIO_ENV,
            scenario=SCENARIO,
            estimator_name="isam2",
            estimator={"params": {"max_iterations": 3}},
        )
    scenario = load_scenario(
        SCENARIO, {"lidar": {"association": "unknown"}}, estimator_name="isam2"
    )
    assert scenario.lidar.association == "unknown" and scenario.estimator.name == "isam2"


def test_missing_gtsam_is_a_config_error_naming_the_extra(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "gtsam", None)  # `import gtsam` raises ImportError
    assert "isam2" in estimators.available()
    with pytest.raises(ConfigError, match=r"pip install 'quadslam\[gtsam\]'"):
        estimators.make("isam2")
    with pytest.raises(ConfigError, match=r"quadslam\[gtsam\]"):
        gym.make(SCENARIO_ENV, scenario=SCENARIO, estimator_name="isam2")


# ------------------------------------------------------------------ in the env


def _make(params: dict[str, Any] | None = None, duration: float = 5.0, **kw: Any) -> gym.Env:
    return gym.make(
        SCENARIO_ENV,
        scenario=kw.pop("scenario", SCENARIO),
        estimator={"name": "isam2", "params": params or {}},
        episode={"duration_s": duration},
        **kw,
    )


def _fly(env: gym.Env, seed: int, steps: int | None = None) -> list[dict[str, Any]]:
    infos, terminated = fly_dflqr(env, seed, steps)
    assert not terminated, infos[-1]["termination_reason"]
    return infos


def _rmse(infos: list[dict[str, Any]]) -> float:
    return float(np.sqrt(np.mean([i["est_pos_err_m"] ** 2 for i in infos])))


def test_flies_dflqr_known_map_like_ekf_slam() -> None:
    env = _make()
    infos = _fly(env, seed=0)
    assert len(infos) == 500 and infos[-1]["est_n_visible"] > 0
    ekf = gym.make(SCENARIO_ENV, scenario=SCENARIO, episode={"duration_s": 5.0})
    ekf_infos = _fly(ekf, seed=0)
    isam, ref = _rmse(infos), _rmse(ekf_infos)
    print(f"est position RMSE over 5 s, seed 0: isam2 {isam:.4f} m, ekf_slam {ref:.4f} m")
    # Same sensors, same noise models: the smoother is at least as good as the filter, within
    # a few millimetres either way on one seed.
    assert isam < ref + 0.005
    nees = np.array([i["est_nees_pose"] for i in infos])
    assert np.isfinite(nees).all() and np.mean(nees) < 3 * 9  # 9-DOF pose NEES, consistent


def test_two_rollouts_with_the_same_seed_are_identical() -> None:
    runs = []
    for _ in range(2):
        env = _make(duration=1.5)
        infos = _fly(env, seed=4)
        est = env.unwrapped.estimator.lane_estimate(0)
        runs.append(([i["est_pos_err_m"] for i in infos], est.position[0], est.pose_cov[0]))
    assert runs[0][0] == runs[1][0]
    np.testing.assert_array_equal(runs[0][1], runs[1][1])
    np.testing.assert_array_equal(runs[0][2], runs[1][2])


def test_slam_maps_landmarks_with_covariances() -> None:
    env = _make({"estimate_imu_bias": True}, duration=2.0, scenario="paper_ekf_figure8")
    infos = _fly(env, seed=1)
    est = env.unwrapped.estimator.lane_estimate(0)
    assert est.landmark_ids().size > 5
    assert np.all(np.diff(est.landmark_ids()) > 0)
    assert est.mapped_landmarks()[2].shape == (est.landmark_ids().size, 3, 3)
    for cov in est.mapped_landmarks()[2]:
        assert np.all(np.linalg.eigvalsh(cov) > 0.0)
    assert est.accel_bias is not None and est.gyro_bias is not None
    assert infos[-1]["est_pos_err_m"] < 0.2
    assert est.diagnostics["diverged"][0] == 0.0 and est.diagnostics["n_keyframes"][0] == 20.0


def test_gtsam_exception_becomes_divergence() -> None:
    env = _make(duration=2.0)
    policy = DFLQRPolicy.from_env(env)
    obs, _ = env.reset(seed=0)
    est = env.unwrapped.estimator.lanes[0]

    class Broken:
        """The smoother, whose next update fails as GTSAM does on a singular system."""

        def __init__(self, smoother: object) -> None:
            self.smoother = smoother

        def update(self, *args: object) -> None:
            raise RuntimeError("Indeterminant linear system detected while working near variable")

        def __getattr__(self, name: str) -> object:
            return getattr(self.smoother, name)

    for _ in range(5):
        obs, *_ = env.step(policy.predict(obs)[0])
    est._smoother = Broken(est._smoother)
    reason = ""
    for _ in range(10):
        obs, _, terminated, _, info = env.step(policy.predict(obs)[0])
        assert np.isfinite(obs).all()
        if terminated:
            reason = info["termination_reason"]
            break
    assert reason == "estimator_diverged: estimator reported divergence"
    assert est.last_error.startswith("RuntimeError: Indeterminant")
    snap = est.estimate()
    assert snap.diagnostics["diverged"][0] == 1.0 and np.isfinite(snap.position[0]).all()


def test_non_finite_prediction_becomes_divergence() -> None:
    """A NaN in the keyframe's marginal, met between keyframes by the snapshot's propagation,
    ends the episode as diverged and never reaches the observation or the estimate."""
    env = _make(duration=2.0)
    policy = DFLQRPolicy.from_env(env)
    obs, _ = env.reset(seed=0)
    est = env.unwrapped.estimator.lanes[0]
    for _ in range(3):  # between the first two keyframes (scans every 10 steps)
        obs, *_ = env.step(policy.predict(obs)[0])
    est._kf_cov = est._kf_cov.copy()
    est._kf_cov[4, 4] = np.nan  # a position variance
    obs, _, terminated, _, info = env.step(policy.predict(obs)[0])
    assert terminated
    assert info["termination_reason"] == "estimator_diverged: estimator reported divergence"
    assert est.last_error.startswith("FloatingPointError: isam2: non-finite prediction")
    assert np.isfinite(obs).all()
    snap = est.estimate()
    assert snap.diagnostics["diverged"][0] == 1.0
    assert snap.pose_cov is not None and np.isfinite(snap.pose_cov).all()


# ------------------------------------------------------------------ smoother vs batch


def test_isam2_matches_batch_levenberg_marquardt() -> None:
    """Full iSAM2 on 1.5 s of SLAM (15 keyframes, IMU + LiDAR factors, landmarks as variables)
    reaches the optimum that batch Levenberg–Marquardt finds on the same graph."""
    # Every variable relinearised at every update: each update is a Gauss-Newton step.
    params = {
        "window_s": None,
        "estimate_imu_bias": True,
        "relinearize_threshold": 1e-9,
        "relinearize_skip": 1,
    }
    env = _make(params, duration=1.5, scenario="paper_ekf_figure8")
    _fly(env, seed=2)
    est = env.unwrapped.estimator.lanes[0]
    isam = est._isam
    for _ in range(5):  # iterate the incremental solution to convergence (relinearised)
        est._smoother.update()
    smoothed = isam.calculateBestEstimate()
    graph = isam.getFactorsUnsafe()
    # LM from the smoothed values perturbed by ~1 cm, 1 mrad, 1 cm/s (not from the answer).
    rng = np.random.default_rng(0)
    start = gtsam.Values()
    for key in smoothed.keys():  # noqa: SIM118 (gtsam.Values has no __iter__)
        char = chr(gtsam.Symbol(key).chr())
        if char == "x":
            start.insert(key, smoothed.atPose3(key).retract(rng.normal(0.0, 0.01, 6)))
        elif char == "b":
            start.insert(key, smoothed.atConstantBias(key))
        elif char == "v":
            start.insert(key, smoothed.atVector(key) + rng.normal(0.0, 0.01, 3))
        else:
            start.insert(key, smoothed.atPoint3(key) + rng.normal(0.0, 0.01, 3))
    lm = gtsam.LevenbergMarquardtParams()
    lm.setRelativeErrorTol(1e-14)
    lm.setAbsoluteErrorTol(1e-14)
    lm.setMaxIterations(100)
    optimum = gtsam.LevenbergMarquardtOptimizer(graph, start, lm).optimize()
    assert graph.error(start) > graph.error(optimum) + 1.0
    assert graph.error(optimum) == pytest.approx(graph.error(smoothed), rel=1e-9, abs=1e-9)
    keys = list(optimum.keys())
    assert len(keys) == 3 * 16 + est.estimate().landmark_ids().size
    worst = 0.0
    for key in keys:
        char = chr(gtsam.Symbol(key).chr())
        if char == "x":
            d = optimum.atPose3(key).localCoordinates(smoothed.atPose3(key))
        elif char == "b":
            d = optimum.atConstantBias(key).localCoordinates(smoothed.atConstantBias(key))
        elif char == "v":
            d = optimum.atVector(key) - smoothed.atVector(key)
        else:
            d = optimum.atPoint3(key) - smoothed.atPoint3(key)
        worst = max(worst, float(np.max(np.abs(d))))
    print(f"largest |iSAM2 − LM| over the {len(keys)} variables: {worst:.1e}")
    assert worst < 1e-6


def test_runs_as_lanes_of_the_vector_env_like_the_scalar_env() -> None:
    kwargs: dict[str, Any] = {
        "scenario": SCENARIO,
        "estimator_name": "isam2",
        "episode": {"duration_s": 1.0},
    }
    vec = gym.make_vec(SCENARIO_ENV, num_envs=2, vectorization_mode="vector_entry_point", **kwargs)
    policy = DFLQRPolicy.from_env(vec)
    obs, _ = vec.reset(seed=3)
    for _ in range(50):
        obs, _, terminated, _, info = vec.step(policy.predict(obs)[0])
        assert not terminated.any()
    scalar = _fly(gym.make(SCENARIO_ENV, **kwargs), seed=3, steps=50)
    assert info["est_pos_err_m"][0] == scalar[-1]["est_pos_err_m"]


def test_slow_imu_is_refused_with_a_config_error() -> None:
    """An IMU slower than the control makes the env copy its estimator (ImuReplay), which a
    GTSAM smoother cannot be: the scenario check reads ``copyable = False`` first."""
    with pytest.raises(ConfigError, match=r"imu\.rate_hz null or >= episode\.control_hz"):
        gym.make(SCENARIO_ENV, scenario=SCENARIO, estimator_name="isam2", imu={"rate_hz": 10.0})
