"""Env sections of ``quadslam bench``: scalar env, native vector env, worker processes.

* ``env``: steps/s and real-time factor of each id through ``gymnasium.make`` (one env), with
  a zero action and with DF-LQR in the loop, and of the iSAM2 smoother (fixed lag, its 3 s
  default window) on the paper's figure-8 with the known map and in SLAM (skipped without
  GTSAM);
* ``vector``: env-steps/s (B × steps / wall time, autoresets included) of the native vector env
  ``gymnasium.make_vec(id, num_envs=B, vectorization_mode="vector_entry_point")`` vs B, with
  the batched DF-LQR (``DFLQRPolicy.predict`` on the (B, obs_dim) observations) in the loop;
* ``workers``: the same with the lanes split over worker processes by
  :class:`agents.rl.vec_adapter.QuadSLAMVecEnv` (``step_async``/``step_wait``; DF-LQR computes the
  actions in the parent).
"""

from __future__ import annotations

import importlib.util
import time
from collections.abc import Callable
from functools import partial
from typing import Any

import numpy as np

from agents.lab.bench.plan import Plan, Results

# (label, env id, make kwargs) of the vector-env scenarios.
VECTOR_SCENARIOS: tuple[tuple[str, str, dict[str, Any]], ...] = (
    ("oracle", "QuadSLAM-Oracle-v0", {}),
    ("ekf_known_map", "QuadSLAM-EKF-v0", {"scenario": "paper_ekf_figure8_known"}),
    ("ekf_unknown_map", "QuadSLAM-EKF-v0", {}),  # paper_ekf_figure8: 40 landmarks, 100/10 Hz
    # The same with EKF-SLAM's integrity monitor excluding, with the sequential test of the
    # integrity study's best row (docs/integrity.md): the cost of its costliest setting.
    (
        "ekf_unknown_map_integrity",
        "QuadSLAM-EKF-v0",
        {"integrity": {"monitor": "exclude", "sequential_window": 10}},
    ),
    # The same figure-8 and map with everything the simulator adds on: four rotors on the paper
    # vehicle (its 38.3 N of thrust at 1000 rad/s), drag, a steady wind with Dryden gusts, and
    # mass, inertia, thrust, lag and sensor noise drawn per episode.
    (
        "ekf_rotors_wind_randomized",
        "QuadSLAM-EKF-v0",
        {
            "scenario": "ekf_figure8_wind",
            "vehicle": {
                "rotor_layout": "x",
                "rotor_arm_m": 0.225,
                "rotor_k_f": 9.56e-6,
                "rotor_k_m": 1.5e-7,
                "rotor_motor_tau_s": 0.02,
                "rotor_omega_min_rad_s": 0.0,
                "rotor_omega_max_rad_s": 1000.0,
            },
            "randomize": {
                "mass_scale": [0.9, 1.1],
                "inertia_scale": [0.9, 1.1],
                "thrust_scale": [0.95, 1.05],
                "lag_scale": [0.8, 1.2],
                "imu_noise_scale": [0.8, 1.2],
                "lidar_noise_scale": [0.8, 1.2],
            },
        },
    ),
)


# ---------------------------------------------------------------- scalar env
def _env_rate(env: Any, policy: Any, steps: int, repeats: int) -> list[float]:
    """Steps per second over ``repeats`` blocks of ``steps`` steps (resets included)."""
    obs, _ = env.reset(seed=0)
    zero = np.zeros(env.action_space.shape, dtype=np.float32)
    samples = []
    for _ in range(repeats + 1):  # the first block is the warm-up
        tic = time.perf_counter()
        for _ in range(steps):
            action = zero if policy is None else policy.predict(obs)[0]
            obs, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                obs, _ = env.reset()
        samples.append(steps / (time.perf_counter() - tic))
    return samples[1:]


def bench_env(results: Results, plan: Plan) -> None:
    """Steps/s of each env id through ``gymnasium.make`` with a zero action and with DF-LQR."""
    import gymnasium as gym

    import quadslam_env  # noqa: F401
    from agents.control.dflqr import DFLQRPolicy

    cases: list[tuple[str, str, dict[str, Any]]] = [
        ("QuadSLAM-Oracle-v0", "oracle", {}),
        ("QuadSLAM-EKF-v0", "ekf_slam", {}),
    ]
    for n in plan.fast_env_particles:
        cases.append(
            (
                "QuadSLAM-FastSLAM-v0",
                f"fastslam_N{n}",
                {"estimator": {"params": {"n_particles": n}}},
            )
        )
    if importlib.util.find_spec("gtsam") is not None:  # the smoother's 3 s fixed lag
        isam2 = {"estimator": {"name": "isam2"}}
        cases.append(("QuadSLAM-v0", "isam2_known_map",
                      {"scenario": "paper_ekf_figure8_known", **isam2}))  # fmt: skip
        cases.append(("QuadSLAM-v0", "isam2", {"scenario": "paper_ekf_figure8", **isam2}))
        monitor = {"integrity": {"monitor": "exclude", "sequential_window": 10}}
        cases.append(("QuadSLAM-v0", "isam2_integrity",  # its monitor's cost (docs/integrity.md)
                      {"scenario": "paper_ekf_figure8", **isam2, **monitor}))  # fmt: skip
    for env_id, label, kwargs in cases:
        env = gym.make(env_id, **kwargs)
        base: Any = env.unwrapped  # a QuadSLAMEnv (gymnasium types it as Env)
        dt = base.dt
        landmarks = base.scenario.landmarks
        n_lm = int(landmarks.count if landmarks.layout == "rauniyar2023" else 4)
        steps = plan.env_steps if "fastslam" not in label else max(100, plan.env_steps // 10)
        for policy_name, policy in (("zero", None), ("dflqr", DFLQRPolicy.from_env(env))):
            rates = _env_rate(env, policy, steps, plan.repeats)
            results.add(
                "env",
                f"steps_per_s/{label}/{policy_name}",
                rates,
                "steps/s",
                env_id=env_id,
                estimator=label,
                policy=policy_name,
                landmarks=n_lm,
            )
            results.add(
                "env",
                f"real_time_factor/{label}/{policy_name}",
                [r * dt for r in rates],
                "x real time",
                env_id=env_id,
                estimator=label,
                policy=policy_name,
            )
        env.close()


# ---------------------------------------------------------------- vector envs
def make_vector(env_id: str, num_envs: int, **kwargs: Any) -> Any:
    """The native vector env of ``env_id`` with ``num_envs`` lanes."""
    import gymnasium as gym

    import quadslam_env  # noqa: F401  (registers the ids)

    return gym.make_vec(
        env_id, num_envs=num_envs, vectorization_mode="vector_entry_point", **kwargs
    )


def steps_per_sample(plan: Plan, num_envs: int) -> int:
    """Vector steps per sample: about ``plan.vec_lane_steps`` env-steps, at least the minimum."""
    return max(plan.vec_min_steps, plan.vec_lane_steps // num_envs)


def lane_rates(
    step: Callable[[np.ndarray], np.ndarray],
    obs: np.ndarray,
    policy: Any,
    num_envs: int,
    plan: Plan,
) -> list[float]:
    """Env-steps/s samples of a vector env driven by ``policy``.

    Args:
        step: Steps the env with (B, 4) actions and returns the next (B, obs_dim) observations.
        obs: Observations after the reset.
        policy: Batched policy with SB3's ``predict``.
        num_envs: B.
        plan: Warm-up steps, steps per sample and repeats.

    Returns:
        ``plan.repeats`` samples of B × steps / wall time (autoresets included).
    """
    for _ in range(plan.vec_warmup):
        obs = step(policy.predict(obs)[0])
    steps = steps_per_sample(plan, num_envs)
    samples = []
    for _ in range(plan.repeats):
        tic = time.perf_counter()
        for _ in range(steps):
            obs = step(policy.predict(obs)[0])
        samples.append(num_envs * steps / (time.perf_counter() - tic))
    return samples


def _note(plan: Plan, dt: float, extra: str = "") -> str:
    return (
        f"batched DF-LQR in the loop; timed after {plan.vec_warmup} warm-up steps "
        f"({plan.vec_warmup * dt:g} s of flight: the EKF maps its landmarks in the first "
        f"~10 s, so its cost grows until then); autoresets included{extra}"
    )


def vector_rates(
    env_id: str, num_envs: int, plan: Plan, **kwargs: Any
) -> tuple[list[float], float, str]:
    """Env-steps/s samples of the native vector env of ``env_id`` (``kwargs`` as for
    ``gymnasium.make``) with B = ``num_envs`` lanes and the batched DF-LQR in the loop.

    Returns:
        ``(samples, control period dt in s, scenario name)``.
    """
    from agents.control.dflqr import DFLQRPolicy

    vec = make_vector(env_id, num_envs, **kwargs)
    try:
        policy = DFLQRPolicy.from_env(vec)
        obs, _ = vec.reset(seed=0)
        rates = lane_rates(partial(_observations, vec), obs, policy, num_envs, plan)
        return rates, vec.dt, vec.scenario.name
    finally:
        vec.close()


def bench_vector(results: Results, plan: Plan) -> None:
    """Native vector env env-steps/s vs lanes B, one process, for each scenario."""
    for label, env_id, kwargs in VECTOR_SCENARIOS:
        for b in plan.vec_batches:
            rates, dt, scenario = vector_rates(env_id, b, plan, **kwargs)
            results.add(
                "vector",
                f"env_steps_per_s/{label}",
                rates,
                "env-steps/s",
                note=_note(plan, dt),
                env_id=env_id,
                scenario=scenario,
                num_envs=b,
                workers=1,
                steps=steps_per_sample(plan, b),
                warmup_steps=plan.vec_warmup,
            )


def _observations(vec: Any, actions: np.ndarray) -> np.ndarray:
    """Step a vector env and return only the observations."""
    return np.asarray(vec.step(actions)[0])


def bench_workers(results: Results, plan: Plan) -> None:
    """``QuadSLAMVecEnv`` env-steps/s with the lanes split over ``plan.n_workers`` processes.

    The infos are not copied (``info_keys=()``) except in one extra EKF unknown-map series
    (``.../all_info``): each lane's info dict is built and pickled back to the parent.
    """
    from agents.control.dflqr import DFLQRPolicy
    from agents.rl.vec_adapter import QuadSLAMVecEnv

    n = plan.n_workers
    cases: list[tuple[str, str, dict[str, Any], tuple[str, ...] | None]] = [
        (*scenario, ()) for scenario in VECTOR_SCENARIOS
    ]
    unknown_map = next(case for case in VECTOR_SCENARIOS if case[0] == "ekf_unknown_map")
    cases.append((*unknown_map, None))
    for label, env_id, kwargs, info_keys in cases:
        probe = make_vector(env_id, 1, **kwargs)
        policy, dt, scenario = DFLQRPolicy.from_env(probe), probe.dt, probe.scenario.name
        probe.close()
        suffix = f"/{n}_workers" + ("" if info_keys == () else "_all_info")
        for b in plan.worker_batches:
            venv = QuadSLAMVecEnv(env_id, b, seed=0, n_workers=n, info_keys=info_keys, **kwargs)

            def step(actions: np.ndarray, v: Any = venv) -> np.ndarray:
                v.step_async(actions)
                return v.step_wait()[0]

            try:
                rates = lane_rates(step, np.asarray(venv.reset()), policy, b, plan)
            finally:
                venv.close()
            results.add(
                "vector",
                f"env_steps_per_s/{label}{suffix}",
                rates,
                "env-steps/s",
                note=_note(plan, dt, f"; {n} worker processes (QuadSLAMVecEnv)"),
                env_id=env_id,
                scenario=scenario,
                num_envs=b,
                workers=n,
                info_keys="all" if info_keys is None else "none",
                steps=steps_per_sample(plan, b),
                warmup_steps=plan.vec_warmup,
            )
