"""RLlib's PPO (new API stack) trains on the env ids through ``gymnasium.make``.

Needs the ``rllib`` extra (``ray[rllib]`` pins gymnasium 1.2.2, so CI runs this file in its
own venv: ``make test-rllib``); skipped without it.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

pytest.importorskip("ray.rllib.algorithms.ppo", exc_type=ImportError)
import ray

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "rllib_ppo.py"


def _example() -> object:
    spec = importlib.util.spec_from_file_location("rllib_ppo_example", EXAMPLE)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def local_ray():
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield
    ray.shutdown()


@pytest.mark.parametrize(
    ("env_id", "runners", "vectorize"),
    [
        # RLlib's default: gymnasium.make per env, in a remote env runner (a fresh process,
        # where only the "quadslam_env:" prefix of the id registers the envs).
        ("QuadSLAM-EKF-v0", 1, "sync"),
        # The native vector env as RLlib's vector env, sampled in this process.
        ("QuadSLAM-Oracle-v0", 0, "vector_entry_point"),
    ],
)
def test_ppo_one_iteration(local_ray, env_id, runners, vectorize):
    example: object = _example()
    config = example.build_config(  # type: ignore[attr-defined]
        env_id,
        {"episode": {"duration_s": 1.0}},
        env_runners=runners,
        envs_per_runner=2,
        vectorize=vectorize,
        rollout_length=100,
        minibatch_size=100,
        epochs=1,
        hidden=(16,),
    )
    algo = config.build_algo()
    try:
        result = algo.train()
    finally:
        algo.stop()
    assert result["training_iteration"] == 1
    runners_res = result["env_runners"]
    assert runners_res["num_env_steps_sampled_lifetime"] >= 200
    assert runners_res["num_episodes"] >= 1  # 1 s episodes: 100 steps at most
    assert runners_res["episode_len_mean"] <= 100
    learner = result["learners"]["default_policy"]
    assert all(v == v for v in (learner["total_loss"], learner["policy_loss"]))  # not NaN


def test_readme_rllib_block_trains_one_iteration(local_ray):
    text = (Path(__file__).resolve().parents[1] / "README.md").read_text(encoding="utf-8")
    section = text.split("## Other RL libraries", 1)[1]
    block = section.split("```python\n", 1)[1].split("```", 1)[0]
    scope: dict[str, object] = {}
    exec(compile(block, "README.md", "exec"), scope)  # the README's own code
    result = scope["result"]
    assert isinstance(result, dict)
    assert result["training_iteration"] == 1
    # 2 envs x 100-step fragments: 200 steps, and the 1 s episodes (100 steps) end within them.
    runners = result["env_runners"]
    assert runners["num_env_steps_sampled_lifetime"] >= 200
    assert runners["episode_len_mean"] <= 100
