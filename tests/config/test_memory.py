"""The memory check before allocation (docs/reliability.md "Memory", ``quadslam_env.memory``):
settings whose buffers cannot fit are refused in one line, before the env, the learner or the
episodes allocate anything, naming the setting that dominates, its size and what fits; the
estimate is close to the arrays a small env really holds; the shipped scenarios pass.

The available memory is pinned with ``QUADSLAM_MEMORY_LIMIT_BYTES`` so that the messages do not
depend on the machine.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

import quadslam_env
from agents.lab.cli.main import main
from quadslam_env.config.files import available_scenarios
from quadslam_env.config.scenario import load_scenario
from quadslam_env.estimation.memory import ENV_MEMORY_SHARE, LIMIT_VARIABLE, MemoryLimitError
from quadslam_env.memory import check_env_memory, env_memory_terms
from quadslam_env.schema import ConfigError

GIB = 1 << 30
VECTOR: dict[str, Any] = {"vectorization_mode": "vector_entry_point"}
LONG: dict[str, Any] = {"episode": {"duration_s": 1e6}}  # 10^8 steps: every delay below is valid


@pytest.fixture
def limit(monkeypatch: pytest.MonkeyPatch) -> Any:
    """Pin the available memory: ``limit(bytes)``."""

    def pin(nbytes: int) -> int:
        monkeypatch.setenv(LIMIT_VARIABLE, str(nbytes))
        return int(ENV_MEMORY_SHARE * nbytes)

    return pin


@pytest.fixture
def no_core(monkeypatch: pytest.MonkeyPatch) -> None:
    """Fail the test if an env gets as far as building its core (the big allocations)."""

    def refuse(*args: Any, **kwargs: Any) -> None:
        raise AssertionError("the core was built: the check came too late")

    monkeypatch.setattr("quadslam_env.env.SimCore", refuse)
    monkeypatch.setattr("quadslam_env.vector_env.SimCore", refuse)


def _number(pattern: str, text: str) -> int:
    """The integer ``pattern``'s group matches in ``text`` (which must match)."""
    found = re.search(pattern, text)
    assert found is not None, text
    return int(found.group(1))


def _refused(make: Any) -> str:
    with pytest.raises(MemoryLimitError) as info:
        make()
    message = str(info.value)
    assert "\n" not in message
    return message


# ----------------------------------------------------------------------------- the probes


def test_delayed_actions_are_refused_with_the_ring_size(limit: Any, no_core: None) -> None:
    budget = limit(2 * GIB)
    message = _refused(
        lambda: gym.make("QuadSLAM-EKF-v0", action={"delay_steps": 99_999_999}, **LONG)
    )
    ring = 8 * 99_999_999 * 4  # float64 × d × B × 4 action entries
    assert message.startswith(f"action.delay_steps: 99999999 would need {ring / GIB:.1f} GiB")
    assert "99999999 × 1 × 4 × 8" in message and "on one lane" in message
    most = _number(r"allowed: action\.delay_steps at most (\d+)", message)
    assert 0 < 8 * 4 * most <= budget
    limit(16 * GIB)
    message = _refused(
        lambda: gym.make_vec(
            "QuadSLAM-EKF-v0", num_envs=64, action={"delay_steps": 99_999_999}, **LONG, **VECTOR
        )
    )
    assert f"would need {64 * ring / GIB:.1f} GiB" in message and "on 64 lanes" in message
    assert re.search(r"at most \d+ lane\(s\) \(num_envs\)", message)


def test_a_delayed_lidar_is_refused_with_its_period_log(limit: Any, no_core: None) -> None:
    limit(16 * GIB)
    message = _refused(
        lambda: gym.make("QuadSLAM-EKF-v0", lidar={"delay_steps": 99_999_999}, **LONG)
    )
    # 100 Hz control, 10 Hz scans: the log holds a scan period (10 steps) and the delay.
    assert message.startswith("lidar.delay_steps: 99999999 would need")
    assert "the period log of 100000009 control periods" in message
    assert re.search(r"allowed: lidar\.delay_steps at most \d+", message)


def test_a_slow_imu_is_refused_with_its_replay_log(limit: Any, no_core: None) -> None:
    limit(GIB)
    message = _refused(lambda: gym.make("QuadSLAM-EKF-v0", imu={"rate_hz": 1e-5}, **LONG))
    assert message.startswith("imu.rate_hz: 1e-05 Hz would need")
    assert "the period log of 10000000 control periods" in message
    assert re.search(r"allowed: imu\.rate_hz at least [\d.e+-]+ Hz", message)


def test_ekf_lanes_count_more_than_the_covariance(limit: Any, no_core: None) -> None:
    limit(16 * GIB)
    message = _refused(lambda: gym.make_vec("QuadSLAM-EKF-v0", num_envs=10**7, **VECTOR))
    assert "a map of 40 landmarks with EKF-SLAM on 10000000 lane(s)" in message
    # With a known map the covariance is 13 states per lane: the lanes' other buffers refuse.
    known: dict[str, Any] = {"estimator": {"known_map": True}}
    message = _refused(lambda: gym.make_vec("QuadSLAM-EKF-v0", num_envs=10**7, **known, **VECTOR))
    assert message.startswith("num_envs: 10000000 lane(s) would need")
    assert "the simulator's lanes" in message and "allowed: num_envs at most" in message


def test_oracle_lanes_are_refused_with_the_lanes_that_fit(limit: Any, no_core: None) -> None:
    limit(16 * GIB)
    message = _refused(lambda: gym.make_vec("QuadSLAM-Oracle-v0", num_envs=10**8, **VECTOR))
    assert message.startswith("num_envs: 100000000 lane(s) would need")
    most = _number(r"allowed: num_envs at most (\d+)$", message)
    scenario = load_scenario(None, {}, "oracle")
    check_env_memory(scenario, most)  # what the message allows fits
    with pytest.raises(MemoryLimitError):
        check_env_memory(scenario, 2 * most)


def test_isam2_lanes_are_refused_with_their_window(limit: Any, no_core: None) -> None:
    limit(16 * GIB)
    message = _refused(
        lambda: gym.make_vec("QuadSLAM-v0", estimator_name="isam2", num_envs=10**5, **VECTOR)
    )
    # 3 s at 10 Hz and the five keyframes before the next marginalisation; 40 landmarks.
    assert message.startswith("estimator.params.window_s: 3 s would need")
    assert "iSAM2's window of 35 keyframes per lane" in message and "16 × 150²" in message
    assert re.search(r"allowed: at most \d+ lane\(s\) \(num_envs\)", message)
    # Full iSAM2 keeps every keyframe of the episode.
    full: dict[str, Any] = {"estimator": {"name": "isam2", "params": {"window_s": None}}, **LONG}
    message = _refused(lambda: gym.make("QuadSLAM-v0", **full))
    assert message.startswith("episode.duration_s: 1e+06 s (window_s null) would need")
    assert "10000001 keyframes" in message and "or a window_s" in message


def test_a_long_lookahead_is_a_config_error() -> None:
    with pytest.raises(ConfigError, match=r"^observation\.lookahead_s: got 100000 entries; "):
        gym.make("QuadSLAM-EKF-v0", observation={"lookahead_s": [0.1] * 100_000})
    env = gym.make("QuadSLAM-Oracle-v0", observation={"lookahead_s": [0.1] * 64})
    assert env.observation_space.shape == (16 + 3 * 64,)


def test_train_with_a_million_lanes_is_one_line(
    capsys: pytest.CaptureFixture[str], limit: Any, tmp_path: Path
) -> None:
    limit(16 * GIB)
    argv = ["train", "--algo", "ppo", "--n-envs", "1000000", "--timesteps", "10"]
    code = main([*argv, "--no-progress", "--out", str(tmp_path)])
    lines = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(lines) == 1
    assert lines[0].startswith("quadslam train: error: landmarks: a map of 40 landmarks")
    assert "on 1000000 lane(s)" in lines[0]
    assert not any(tmp_path.iterdir())  # no run folder


def test_training_counts_the_learners_buffers(limit: Any) -> None:
    from agents.rl.building import check_training_memory
    from agents.rl.hyperparams import resolve_settings

    budget = limit(4 * GIB)
    ppo = resolve_settings("ppo", {"n_timesteps": 10, "n_envs": 1000, "n_steps": 10**6})
    with pytest.raises(MemoryLimitError) as info:
        check_training_memory("ppo", ppo, "QuadSLAM-Oracle-v0")
    # 16 observations, 4 actions and 6 scalars per transition, 8 bytes each, 1000 lanes.
    need = 10**6 * 1000 * 8 * (16 + 4 + 6)
    assert str(info.value).startswith(f"n_steps: 1000000 would need {need / GIB:.1f} GiB")
    most = _number(r"allowed: n_steps at most (\d+)", str(info.value))
    assert 0 < most * 1000 * 8 * 26 <= budget
    sac = resolve_settings("sac", {"n_timesteps": 10, "buffer_size": 10**9})
    with pytest.raises(MemoryLimitError, match=r"^buffer_size: 1000000000 would need"):
        check_training_memory("sac", sac, "QuadSLAM-Oracle-v0")


def test_run_with_a_hundred_million_seeds_is_one_line(
    capsys: pytest.CaptureFixture[str], limit: Any
) -> None:
    budget = limit(16 * GIB)
    code = main(["run", "--seeds", "100000000", "--no-plots"])
    lines = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(lines) == 1
    records = 100_000_000 * 8 * 1024
    assert lines[0].startswith(
        f"quadslam run: error: --seeds: 100000000 would need {records / GIB:.1f} GiB"
    )
    most = _number(r"allowed: --seeds at most (\d+)$", lines[0])
    assert 0 < most * 8 * 1024 <= budget


def test_the_sweep_refuses_a_job_that_cannot_fit(limit: Any) -> None:
    from agents.lab.sweep.spec import SweepSpecError, parse_spec

    limit(16 * GIB)
    job = {"kind": "run", "seeds": 10**8, "seeds_per_job": 10**8}
    with pytest.raises(SweepSpecError, match=r"seeds_per_job: 100000000 would need 762\.9 GiB"):
        parse_spec({"jobs": [job]})
    train = {"kind": "train", "algo": "ppo", "n_envs": 10**6}
    with pytest.raises(SweepSpecError, match=r"on 1000000 lane\(s\)"):
        parse_spec({"jobs": [train]})


# ------------------------------------------------------------------ the estimate itself


def _array_bytes(root: object) -> int:
    """The bytes of every distinct NumPy buffer reachable from ``root``'s attributes."""
    seen: set[int] = set()
    buffers: dict[int, int] = {}
    stack = [root]
    while stack:
        obj = stack.pop()
        if id(obj) in seen or isinstance(obj, str | bytes | int | float | type | gym.Space):
            continue
        seen.add(id(obj))
        if isinstance(obj, np.ndarray):
            base = obj
            while isinstance(base.base, np.ndarray):
                base = base.base
            buffers[id(base)] = base.nbytes
        elif isinstance(obj, dict):
            stack.extend(obj.values())
        elif isinstance(obj, list | tuple | set):
            stack.extend(obj)
        elif hasattr(obj, "__dict__") and not type(obj).__module__.startswith("numba"):
            stack.extend(vars(obj).values())
    return sum(buffers.values())


@pytest.mark.parametrize(
    "overrides",
    [
        {},
        {"action": {"delay_steps": 200}, "lidar": {"delay_steps": 20}},
        {"imu": {"rate_hz": 10.0}},
    ],
    ids=["ekf", "delays", "slow_imu"],
)
def test_the_estimate_is_within_a_factor_of_two_of_the_arrays(overrides: dict[str, Any]) -> None:
    """The estimate counts the arrays and, on top, the lanes' Python objects: between the
    arrays' bytes and twice them, for a small EKF-SLAM vector env after a few steps."""
    vec = gym.make_vec("QuadSLAM-EKF-v0", num_envs=6, **overrides, **VECTOR)
    base: Any = vec.unwrapped
    vec.reset(seed=0)
    for _ in range(25):  # the delayed scans arrive and the slow IMU replays
        vec.step(np.tile(base.hover_action, (6, 1)).astype(np.float32))
    real = _array_bytes(base)
    estimate = sum(t.nbytes for t in env_memory_terms(base.scenario, 6))
    assert real <= estimate <= 2 * real, (real, estimate)


def test_the_big_terms_are_the_real_buffers() -> None:
    vec = gym.make_vec("QuadSLAM-EKF-v0", num_envs=3, action={"delay_steps": 50}, **VECTOR)
    base: Any = vec.unwrapped
    core = base.core
    terms = {t.setting: t for t in env_memory_terms(base.scenario, 3)}
    covariance = next(t for t in env_memory_terms(core.scenario, 3) if "P (" in t.what)
    assert covariance.nbytes == core.estimator.state.P.nbytes
    assert terms["action.delay_steps"].nbytes == core._actions._ring.nbytes


# ------------------------------------------------------------ what is accepted stays as it was


@pytest.mark.parametrize("name", sorted(available_scenarios()))
def test_every_shipped_scenario_fits_an_evaluation_chunk(name: str, limit: Any) -> None:
    """64 lanes (``quadslam run``'s chunk) of every shipped scenario fit in 4 GiB."""
    budget = limit(4 * GIB)
    assert check_env_memory(load_scenario(name), 64) < budget


def test_the_check_changes_nothing_it_accepts(limit: Any) -> None:
    obs_free, _ = gym.make("QuadSLAM-EKF-v0").reset(seed=3)
    limit(GIB)  # ample for one lane
    env = gym.make("QuadSLAM-EKF-v0")
    obs, _ = env.reset(seed=3)
    np.testing.assert_array_equal(obs, obs_free)
    assert quadslam_env.ENV_IDS  # the ids are registered by the import above
