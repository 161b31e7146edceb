"""``quadslam bench --only team``: the team env against the vector env of as many lanes.

A team of N = 4 vehicles (``quadslam_env.team.parallel_env``, EKF-SLAM on the paper's
figure-8, each vehicle flown by DF-LQR on its estimate) is N lanes of the batched core plus the
team's coordination: the action and observation dicts, each vehicle's ``info``, the team's map
terms and, with fusion, the messages. Its target is a per-vehicle speed of at least half the
single-vehicle EKF-SLAM vector env's with N lanes (docs/team.md "Speed"). Both are timed in
alternation in one process (:func:`agents.lab.bench.paired.alternate`), so that each round's ratio
compares them on the same machine state: the team with ``independent`` fusion, with ``ci``
(the default messages: 0.2 per second, every mapped landmark with the joint covariance) and
with ``ci`` after every scan, and the vector env.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from agents.lab.bench.envs import make_vector, steps_per_sample
from agents.lab.bench.paired import alternate, vector_flight
from agents.lab.bench.plan import Plan, Results

N_VEHICLES = 4
SCENARIO = "paper_ekf_figure8"
TEAMS: dict[str, dict[str, Any]] = {
    "team_independent": {"fusion": "independent"},
    "team_ci": {"fusion": "ci"},
    "team_ci_every_scan": {"fusion": "ci", "message_rate_hz": None},
}
"""The teams timed: label → ``team`` settings."""
VECTOR = "vector"
TARGET = 0.5
"""A team's per-vehicle speed over the vector env's, at least (docs/team.md)."""
MAX_STEPS = 1000
"""Steps per round at most (a team of 4 steps ~1,000 times/s: a round of ~1 s)."""


def team_flight(env: Any, policy: Any) -> Callable[[int], None]:
    """A function that steps the team ``env`` that many times, every live vehicle flown by the
    batched ``policy``; a new episode (the next seed) when every vehicle has ended."""
    seed = [0]
    obs = [env.reset(seed=0)[0]]

    def fly(steps: int) -> None:
        for _ in range(steps):
            if not env.agents:
                seed[0] += 1
                obs[0] = env.reset(seed=seed[0])[0]
            agents = env.agents
            actions = policy.predict(np.stack([obs[0][a] for a in agents]))[0]
            obs[0] = env.step(dict(zip(agents, actions, strict=True)))[0]

    return fly


def bench_team(results: Results, plan: Plan) -> None:
    """Vehicle-steps/s of each team of :data:`TEAMS` and env-steps/s of the vector env with
    N lanes, in alternation, and each team's ratio to the vector env per round."""
    import gymnasium as gym

    from agents.control.dflqr import DFLQRPolicy
    from quadslam_env.team.env import parallel_env

    steps = min(MAX_STEPS, steps_per_sample(plan, N_VEHICLES))
    vec = make_vector("QuadSLAM-EKF-v0", N_VEHICLES, scenario=SCENARIO)
    try:
        policy = DFLQRPolicy.from_env(gym.make("QuadSLAM-EKF-v0", scenario=SCENARIO))
        runs = {VECTOR: vector_flight(vec, policy)}
        for label, team in TEAMS.items():
            env = parallel_env(n_vehicles=N_VEHICLES, scenario=SCENARIO, team=team)
            runs[label] = team_flight(env, policy)
        for fly in runs.values():
            fly(plan.vec_warmup)  # the EKF maps its landmarks first
        times = alternate(runs, steps, 2 * plan.repeats)
    finally:
        vec.close()
    rates = {label: [N_VEHICLES * steps / t for t in samples] for label, samples in times.items()}
    note = (
        f"{N_VEHICLES} vehicles / lanes, EKF-SLAM on {SCENARIO}, batched DF-LQR; "
        f"{len(rates[VECTOR])} alternating rounds of {steps} steps after {plan.vec_warmup} "
        "warm-up steps; resets included"
    )
    for label, samples in rates.items():
        results.add("team", f"vehicle_steps_per_s/{label}", samples, "env-steps/s", note=note,
                    num_envs=N_VEHICLES, steps=steps)  # fmt: skip
    for label in TEAMS:
        ratio = [t / v for t, v in zip(rates[label], rates[VECTOR], strict=True)]
        results.add("team", f"{label}_over_vector", ratio, "ratio", note=note,
                    num_envs=N_VEHICLES, steps=steps, target_min=TARGET)  # fmt: skip
