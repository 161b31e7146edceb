"""``imu.rate_hz`` apart from the control rate (docs/design.md §3; docs/timing.md "IMU rate"):
the rule, the unchanged default, the noise at the IMU rate, what the estimator is fed, and
EKF-SLAM's consistency and flight on the paper's 10 Hz IMU."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
from scipy.stats import chi2

import quadslam_env  # noqa: F401  (registers the ids)
from agents.control.dflqr import ATTITUDE_NATURAL_FREQ, DFLQRPolicy, attitude_natural_freq
from agents.lab.estimator_studies.consistency import run_consistency
from quadslam_env.config.scenario import load_scenario
from quadslam_env.metrics.step import anees_bounds
from quadslam_env.schema import ConfigError
from quadslam_env.types import GRAVITY

P_FAIL = 1e-6  # two-sided false-alarm probability of each statistical bound


# ---------------------------------------------------------------------- the rule
@pytest.mark.parametrize(
    ("rate", "per_step", "per_imu"),
    [(None, 1, 1), (100.0, 1, 1), (10.0, 1, 10), (50.0, 1, 2), (1000.0, 10, 1), (200.0, 2, 1)],
)
def test_rate_is_a_multiple_or_a_fraction_of_the_control_rate(rate, per_step, per_imu) -> None:
    cfg = load_scenario("paper_ekf_figure8", {"imu": {"rate_hz": rate}})
    assert cfg.imu_rate_hz == (100.0 if rate is None else rate)
    assert (cfg.imu_per_step, cfg.steps_per_imu) == (per_step, per_imu)


@pytest.mark.parametrize("rate", [30.0, 150.0, 99.0, 0.0, -10.0])
def test_other_rates_are_rejected_naming_the_key(rate) -> None:
    with pytest.raises(ConfigError, match=r"imu\.rate_hz") as err:
        load_scenario("paper_ekf_figure8", {"imu": {"rate_hz": rate}})
    assert str(rate) in str(err.value) or repr(rate) in str(err.value)


def test_the_rule_follows_the_control_rate() -> None:
    cfg = load_scenario(None, {"imu": {"rate_hz": 25.0}, "episode": {"control_hz": 50.0}})
    assert cfg.steps_per_imu == 2
    with pytest.raises(ConfigError, match="integer multiple or an integer fraction"):
        load_scenario(None, {"imu": {"rate_hz": 15.0}, "episode": {"control_hz": 40.0}})


# ---------------------------------------------------------------------- the default
def _rollout(seconds: float, seed: int, **kwargs):
    env = gym.make("QuadSLAM-EKF-v0", episode={"duration_s": seconds}, **kwargs)
    policy = DFLQRPolicy.from_env(env)
    obs, _ = env.reset(seed=seed)
    while True:
        obs, _, term, trunc, info = env.step(policy.predict(obs)[0])
        if term or trunc:
            break
    base = env.unwrapped
    out = (obs, base.last_estimate.position[0], info, base.core.imu.total_bias[0].copy())
    env.close()
    return out


@pytest.mark.parametrize(
    ("kwargs", "position", "nees"),
    [
        ({}, [0.33560987354621336, 0.10064878670413702, -0.12995870768453988], 9.728498298986263),
        (
            {"scenario": "ekf_figure8_biased_imu"},
            [0.4076787493572357, 0.0036067103464214687, -0.018260876169879463],
            12.240270534800175,
        ),
    ],
)
def test_default_rate_reproduces_the_stored_rollout(kwargs, position, nees) -> None:
    # Values of the same 1 s rollout (seed 5) before imu.rate_hz existed.
    _, pos, info, _ = _rollout(1.0, 5, **kwargs)
    np.testing.assert_allclose(pos, position, rtol=1e-12, atol=0)
    assert info["est_nees_pose"] == pytest.approx(nees, rel=1e-10)


def test_rate_equal_to_the_control_rate_is_the_default_bit_for_bit() -> None:
    a = _rollout(0.5, 2, scenario="ekf_figure8_biased_imu")
    b = _rollout(0.5, 2, scenario="ekf_figure8_biased_imu", imu={"rate_hz": 100.0})
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[3], b[3])


def test_dflqr_attitude_loop_is_capped_by_the_imu_rate() -> None:
    np.testing.assert_array_equal(attitude_natural_freq(100.0), ATTITUDE_NATURAL_FREQ)
    np.testing.assert_allclose(attitude_natural_freq(10.0), [4.0, 4.0, 4.0])


# ---------------------------------------------------------------------- what the filter gets
class _Spy:
    """Records every ``predict`` call of the wrapped batch estimator."""

    def __init__(self, inner):
        self.inner, self.calls = inner, []
        self.num_lanes, self.uses_truth = inner.num_lanes, inner.uses_truth

    def __getattr__(self, name):
        return getattr(self.inner, name)

    def __deepcopy__(self, memo):  # the slow-IMU filter and its copies record into one list
        import copy

        twin = _Spy(copy.deepcopy(self.inner, memo))
        twin.calls = self.calls
        return twin

    def predict(self, t, accel, gyro, sa, sg, thrust, torque, dt, active):
        self.calls.append((accel[0].copy(), gyro[0].copy(), sa, sg, dt))
        self.inner.predict(t, accel, gyro, sa, sg, thrust, torque, dt, active)


def _hover_inputs(rate_hz: float, seconds: float):
    """Predict calls of an oracle env hovering at rest (the truth is exactly hover)."""
    env = gym.make(
        "QuadSLAM-Oracle-v0",
        scenario="hover",
        estimator={"name": "oracle", "params": {}},
        imu={"rate_hz": rate_hz},
        episode={"duration_s": seconds},
    )
    base = env.unwrapped
    spy = _Spy(base.estimator)
    base.estimator = spy
    env.reset(seed=4)
    for _ in range(base.core.max_steps):
        env.step(base.hover_action)
    env.close()
    return base.core, spy.calls


def _assert_chi2(x: np.ndarray, sigma: float) -> None:
    stat = float(np.sum(x * x)) / sigma**2
    lo, hi = chi2.ppf(P_FAIL / 2, x.size), chi2.ppf(1 - P_FAIL / 2, x.size)
    assert lo < stat < hi, (stat, lo, hi)


def test_slow_imu_noise_at_its_rate_held_and_replayed() -> None:
    core, calls = _hover_inputs(10.0, 30.0)
    cfg = core.scenario.imu
    m, steps = 10, core.max_steps
    # Output: one prediction per control period between IMU instants; filter: the m periods
    # a sample covers, replayed at its instant.
    assert len(calls) == (steps - steps // m) + steps
    assert {c[4] for c in calls} == {0.01}
    # The filter's input noise per period is ND √f_control; the output's is wider by the
    # held sample's error (here the change between two noisy samples of the same hover).
    nd_a, nd_g = cfg.accel_noise_density * 10.0, cfg.gyro_noise_density * 10.0
    assert min(c[2] for c in calls) == pytest.approx(nd_a, rel=1e-12)
    assert min(c[3] for c in calls) == pytest.approx(nd_g, rel=1e-12)
    replayed = [c for c in calls if (c[2], c[3]) == (nd_a, nd_g)]
    assert len(replayed) == steps
    # The IMU's own samples: σ = ND √f_IMU, each held over m periods (one at reset).
    assert core.imu.accel_sigma == pytest.approx(cfg.accel_noise_density * math.sqrt(10.0))
    accel = np.array([c[0] for c in calls])
    samples = np.unique(accel, axis=0)
    assert len(samples) == steps // m + 1
    _assert_chi2(samples - [0.0, 0.0, -GRAVITY], core.imu.accel_sigma)
    gyro = np.unique(np.array([c[1] for c in calls]), axis=0)
    _assert_chi2(gyro, core.imu.gyro_sigma)


def test_fast_imu_noise_at_its_rate_every_sample_predicted() -> None:
    core, calls = _hover_inputs(1000.0, 2.0)
    cfg = core.scenario.imu
    assert len(calls) == 10 * core.max_steps
    np.testing.assert_allclose([c[4] for c in calls], 0.001, rtol=1e-12)
    sigma_a = cfg.accel_noise_density * math.sqrt(1000.0)
    assert calls[0][2] == pytest.approx(sigma_a) and core.imu.accel_sigma == calls[0][2]
    accel = np.array([c[0] for c in calls]) - [0.0, 0.0, -GRAVITY]
    _assert_chi2(accel, sigma_a)
    _assert_chi2(np.array([c[1] for c in calls]), core.imu.gyro_sigma)
    # White: no correlation between consecutive samples.
    lag1 = np.sum(accel[1:] * accel[:-1]) / np.sum(accel * accel)
    assert abs(lag1) < 5.0 / math.sqrt(accel.size)


def test_slow_imu_drift_steps_at_the_imu_period() -> None:
    core, _ = _hover_inputs(10.0, 0.1)
    cfg = load_scenario("ekf_figure8_biased_imu", {"imu": {"rate_hz": 10.0}})
    from quadslam_env.sim.imu import ImuBatch

    imu = ImuBatch(cfg.imu, core.vehicle_params, cfg.imu_rate_hz, 1)
    assert imu.period == pytest.approx(0.1)
    assert imu._decay == pytest.approx(math.exp(-0.1 / cfg.imu.drift_tau_s))


# ---------------------------------------------------------------------- the filter
@pytest.mark.slow
def test_ekf_on_a_10hz_imu_hover_is_consistent() -> None:
    n = 6
    result = run_consistency(
        n_runs=n, scenario="hover", imu={"rate_hz": 10.0}, episode={"duration_s": 20.0}
    )
    assert result.terminated == 0
    lo, hi = anees_bounds(9, n)
    at_imu = (np.arange(result.nees.shape[1]) + 1) % 10 == 0
    pooled_at_imu = float(result.anees[at_imu].mean())
    pooled = float(result.anees.mean())
    assert lo <= pooled_at_imu <= hi, (pooled_at_imu, lo, hi)
    assert lo <= pooled <= hi, (pooled, lo, hi)
    pooled_pos, (lo3, hi3), _ = result.block_consistency("pos")
    assert lo3 <= pooled_pos <= hi3, (pooled_pos, lo3, hi3)


@pytest.mark.slow
def test_dflqr_flies_the_figure8_on_a_10hz_imu() -> None:
    _, _, info, _ = _rollout(20.0, 0, scenario="paper_ekf_figure8_known", imu={"rate_hz": 10.0})
    assert info["t"] == pytest.approx(20.0)
    assert not info.get("termination_reason")
    assert info["episode_est_pos_rmse_m"] < 0.05
