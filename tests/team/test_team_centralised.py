"""One smoother of the whole team (``team.fusion: centralised``, estimators.isam2.team): a team
of one is the single iSAM2 env bit for bit; flown on the same true trajectories, every
landmark vehicle 0 maps is known better by the team's graph than by vehicle 0's own smoother
(the other vehicle's factors add information); and bad settings."""

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


def _team(fusion: str, n: int = 2) -> Any:
    return parallel_env(
        n_vehicles=n,
        scenario=SCENARIO,
        team={"fusion": fusion},
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
            {"estimator_name": "isam2", "n_vehicles": 100},
            "n_vehicles: got 100 with team.fusion 'centralised'; join: 100 vehicles; allowed: at "
            "most 99",
        ),
    ],
)
def test_bad_centralised_settings_name_the_key_the_value_and_what_is_allowed(
    kwargs: dict[str, Any], fragment: str
) -> None:
    kwargs = {"n_vehicles": 2, **kwargs}
    with pytest.raises(ConfigError) as err:
        parallel_env(scenario=SCENARIO, team={"fusion": "centralised"}, **kwargs)
    assert fragment in str(err.value)
