"""One smoother of the whole team (``team.fusion: centralised``, estimators.isam2.team): a team
of one is the single iSAM2 env bit for bit; flown on the same true trajectories, every
landmark vehicle 0 maps is known better by the team's graph than by vehicle 0's own smoother
(the other vehicle's factors add information); a range between the vehicles adds exactly its
information 1/σ² to their relative position along the line of sight; and bad settings."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import pytest

import quadslam_env  # noqa: F401  (registers the env ids)
from agents.control.dflqr import DFLQRPolicy
from quadslam_env.schema import ConfigError

pytest.importorskip("pettingzoo")
pytest.importorskip("gtsam")

from quadslam_env.team.env import parallel_env

SCENARIO = "paper_ekf_figure8"
EPISODE = {"duration_s": 4.0}
"""Short episodes of the paper's unknown map: 40 scans per vehicle."""


def _team(fusion: str, n: int = 2, **team: Any) -> Any:
    return parallel_env(
        n_vehicles=n,
        scenario=SCENARIO,
        team={"fusion": fusion, **team},
        estimator_name="isam2",
        episode=EPISODE,
    )


def _fly(env: Any, seed: int, actions: list[dict[str, np.ndarray]] | None = None) -> list[Any]:
    """Fly ``env`` from a reset with ``seed``: DF-LQR on each vehicle's estimate, or the
    ``actions`` given, step by step; returns the actions flown."""
    policy = DFLQRPolicy.from_env(gym.make("QuadSLAM-v0", scenario=SCENARIO, episode=EPISODE))
    obs, _ = env.reset(seed=seed)
    flown: list[dict[str, np.ndarray]] = []
    while env.agents:
        if actions is None:
            act = {agent: policy.predict(obs[agent], deterministic=True)[0] for agent in env.agents}
        else:
            act = {agent: actions[len(flown)][agent] for agent in env.agents}
        flown.append(act)
        obs, *_ = env.step(act)
    return flown


def test_a_team_of_one_is_the_single_isam2_env() -> None:
    team = _team("centralised", n=1)
    single = gym.make("QuadSLAM-v0", scenario=SCENARIO, estimator_name="isam2", episode=EPISODE)
    policy = DFLQRPolicy.from_env(single)
    obs, _ = single.reset(seed=3)
    team_obs, _ = team.reset(seed=3)
    for _ in range(150):
        np.testing.assert_array_equal(team_obs["vehicle_0"], obs)
        action = policy.predict(obs, deterministic=True)[0]
        obs, *_ = single.step(action)
        team_obs, *_ = team.step({"vehicle_0": action})


def test_the_teams_graph_knows_every_landmark_better_than_one_vehicle() -> None:
    """The same actions, so the same true flights and measurements (the truth does not depend
    on the estimates): each landmark of vehicle 0's own map has a smaller marginal covariance
    (trace) in the team's graph, which holds vehicle 0's factors and vehicle 1's."""
    alone = _team("independent")
    actions = _fly(alone, seed=11)
    team = _team("centralised")
    _fly(team, seed=11, actions=actions)
    np.testing.assert_array_equal(team.core.vehicle.state, alone.core.vehicle.state)
    ids, _, covs = alone.core.estimator.lane_estimate(0).mapped_landmarks(0)
    team_ids, _, team_covs = team.core.estimator.lane_estimate(0).mapped_landmarks(0)
    assert len(ids) >= 5 and set(ids.tolist()) <= set(team_ids.tolist())
    rows = np.searchsorted(team_ids, ids)
    ratio = np.trace(team_covs[rows], axis1=1, axis2=2) / np.trace(covs, axis1=1, axis2=2)
    assert (ratio < 1.0).all(), ratio
    # Both vehicles read the one map: vehicle 1's snapshot has the same landmarks and means.
    ids1, means1, _ = team.core.estimator.lane_estimate(1).mapped_landmarks(0)
    ids0, means0, _ = team.core.estimator.lane_estimate(0).mapped_landmarks(0)
    np.testing.assert_array_equal(ids1, ids0)
    np.testing.assert_array_equal(means1, means0)


def _range_variance(env: Any, u: np.ndarray) -> float:
    """Var(uᵀ(t_0 − t_1)) m² of the two vehicles' latest keyframes in the team's graph: their
    joint marginal over GTSAM's Pose3 tangents (δθ, δt in the body frame: t + R δt)."""
    lanes = env.core.estimator.lanes
    keys = [lane._key("x", lane._k) for lane in lanes]
    isam = lanes[0]._isam
    joint = np.asarray(isam.jointMarginalCovariance(keys).fullMatrix())
    H = np.zeros(12)
    H[3:6] = u @ lanes[0]._kf_dcm
    H[9:12] = -u @ lanes[1]._kf_dcm
    return float(H @ joint @ H)


def test_a_range_factor_adds_its_information_to_the_vehicles_relative_position() -> None:
    """A scalar measurement of a linear function: the information of uᵀ(t_0 − t_1) (u the line
    of sight) grows by exactly 1/σ², as a Kalman update of that function (linearised; the
    graph relinearises, hence the 1% tolerance), for a precise range and a coarse one. The
    vehicles a quarter period apart (the default offsets start two vehicles together, where a
    range is far from linear)."""
    env = _team("centralised", time_offsets_s=[0.0, 6.25])
    env.reset(seed=4)
    hold = {agent: np.zeros(4, dtype=np.float32) for agent in env.agents}
    for sigma in (0.01, 0.1):
        for _ in range(10):  # to the next scan: both keyframes at the present
            env.step(hold)
        lanes = env.core.estimator.lanes
        assert not lanes[0]._kept and not lanes[1]._kept
        t0, t1 = (lane._kf_pose.translation() for lane in lanes)
        u = (t0 - t1) / np.linalg.norm(t0 - t1)
        before = _range_variance(env, u)
        assert env.core.estimator.range_between(0, 1, float(np.linalg.norm(t0 - t1)), sigma)
        after = _range_variance(env, u)
        assert 1.0 / after == pytest.approx(1.0 / before + 1.0 / sigma**2, rel=0.01)
    env.step(hold)  # an IMU sample since the keyframes: a range now is not at their instant
    assert not env.core.estimator.range_between(0, 1, 1.0, 0.1)


def test_ranges_as_factors_are_fused_at_each_epoch() -> None:
    team = {"fusion": "centralised", "ranges": True, "range_fusion": "factor"}
    env = parallel_env(
        n_vehicles=2, scenario=SCENARIO, team=team, estimator_name="isam2", episode=EPISODE
    )
    env.reset(seed=2)
    hold = {agent: np.zeros(4, dtype=np.float32) for agent in env.agents}
    fused = []
    for _ in range(41):
        _, _, _, _, infos = env.step(hold)
        fused.append(infos["vehicle_0"]["team_ranges_fused"])
    assert fused[10::10] == [1.0] * 4  # the step after each 10 Hz epoch, at the scans
    assert sum(fused) == 4


def test_the_uplink_counts_every_sample_return_and_range_the_graph_takes() -> None:
    """``team_bytes_sent`` of a centralised team: 8 bytes per float of every IMU sample (7),
    every scan (1, its time) and return (4), and every range (3), recounted from the steps."""
    team = {"fusion": "centralised", "ranges": True, "range_fusion": "factor"}
    env = parallel_env(
        n_vehicles=2, scenario=SCENARIO, team=team, estimator_name="isam2", episode=EPISODE
    )
    obs, _ = env.reset(seed=2)
    policy = DFLQRPolicy.from_env(gym.make("QuadSLAM-v0", scenario=SCENARIO, episode=EPISODE))
    scenario, floats, steps = env.scenario, 0, 0
    while env.agents:
        live = list(env.agents)
        act = {agent: policy.predict(obs[agent], deterministic=True)[0] for agent in live}
        obs, _, _, _, infos = env.step(act)
        steps += 1
        floats += 7 * scenario.imu_per_step * len(live)
        if steps % scenario.lidar_every == 0:
            floats += sum(1 + 4 * int(infos[a]["est_n_visible"]) for a in live)
        floats += 3 * int(infos[live[0]]["team_ranges_measured"])  # both vehicles' one range
        last = infos[live[0]]
    assert steps == 400 and last["team_episode_bytes_sent"] == 8 * floats


@pytest.mark.parametrize(
    ("kwargs", "fragment"),
    [
        (
            {"estimator_name": "ekf_slam"},
            "team.fusion: got 'centralised' with estimator.name = 'ekf_slam', which cannot be one "
            "estimator of the team; allowed:",
        ),
        (
            {"estimator_name": "isam2", "lidar": {"association": "unknown"}},
            "team.fusion: got 'centralised' with lidar.association = 'unknown'; allowed:",
        ),
        (
            {"estimator_name": "isam2", "team": {"ranges": True, "range_fusion": "factor"}},
            "team.range_fusion: got 'factor' with team.fusion = 'independent'; allowed:",
        ),
        (
            {"estimator_name": "isam2", "n_vehicles": 100},
            "n_vehicles: got 100 with team.fusion 'centralised'; join: 100 vehicles; allowed: at "
            "most 99",
        ),
    ],
)
def test_bad_centralised_settings_name_the_key_the_value_and_what_is_allowed(
    kwargs: dict[str, Any], fragment: str
) -> None:
    kwargs = {"n_vehicles": 2, "team": {"fusion": "centralised"}, **kwargs}
    with pytest.raises(ConfigError) as err:
        parallel_env(scenario=SCENARIO, **kwargs)
    assert fragment in str(err.value)
