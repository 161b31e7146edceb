"""The examples run, with tiny budgets, and count what they claim to count.

``examples/cleanrl_loop.py`` runs in this process; ``examples/sb3_workers.py`` starts worker
processes, so it runs as a script (its ``if __name__ == "__main__":`` guard is the real one).
The counts are checked against facts the examples do not compute: the episode length fixed by
``episode.duration_s``, the scalar env flown lane by lane, the stagger's cut steps.
"""

from __future__ import annotations

import importlib.util
import logging
import math
import os
import re
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType

import gymnasium as gym
import pytest

import quadslam_env  # noqa: F401  (registers the ids)
from agents.control.dflqr import DFLQRPolicy

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "examples"


def _load(name: str) -> ModuleType:
    spec = importlib.util.spec_from_file_location(f"example_{name}", EXAMPLES / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def _scalar_episodes(
    env_id: str, seed: int, steps: int, duration_s: float
) -> list[tuple[float, int]]:
    """(return, length) of the episodes the scalar env seeded ``seed`` ends within ``steps``."""
    env = gym.make(env_id, episode={"duration_s": duration_s})
    policy = DFLQRPolicy.from_env(env)
    obs, _ = env.reset(seed=seed)
    out, ret, length = [], 0.0, 0
    for _ in range(steps):
        obs, reward, terminated, truncated, _ = env.step(policy.predict(obs)[0])
        ret, length = ret + float(reward), length + 1
        if terminated or truncated:
            out.append((ret, length))
            obs, _ = env.reset()
            ret, length = 0.0, 0
    env.close()
    return out


def test_cleanrl_same_step_loop_counts_every_episode_once() -> None:
    example = _load("cleanrl_loop")
    lanes, steps, duration_s, seed = 3, 250, 0.4, 7
    episodes = example.rollout(
        "QuadSLAM-EKF-v0", num_envs=lanes, steps=steps, duration_s=duration_s, seed=seed
    )
    # 0.4 s at 100 Hz: DF-LQR flies every episode to its time limit, 40 steps, so each lane
    # ends on steps 40, 80, ..., 240: 6 episodes per lane, none of them doubled by the reset.
    n_steps = round(duration_s * 100)
    per_lane = steps // n_steps
    assert len(episodes) == lanes * per_lane
    for lane in range(lanes):
        mine = [ep for ep in episodes if ep.lane == lane]
        assert [ep.length for ep in mine] == [n_steps] * per_lane
        assert [ep.reported_steps for ep in mine] == [n_steps] * per_lane
        assert all(ep.reason == "" for ep in mine)
        # Lane i is the scalar env seeded seed + i, through its resets.
        scalar = _scalar_episodes("QuadSLAM-EKF-v0", seed + lane, steps, duration_s)
        assert [ep.length for ep in mine] == [n for _, n in scalar]
        assert [ep.ret for ep in mine] == pytest.approx([r for r, _ in scalar], rel=1e-9)


def _readme_block(heading: str) -> str:
    """The first ```python block after ``heading`` in the README."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    section = text.split(heading, 1)[1]
    match = re.search(r"```python\n(.*?)```", section, re.S)
    assert match is not None
    return match.group(1)


def test_readme_first_episode_prints_the_steady_state(
    capsys: pytest.CaptureFixture[str],
) -> None:
    block = _readme_block("## A first episode")
    scope: dict[str, object] = {}
    exec(compile(block, "README.md", "exec"), scope)  # the README's own code
    info = scope["info"]
    assert isinstance(info, dict)
    line = capsys.readouterr().out.strip()
    match = re.fullmatch(r"tracking (\S+) m, estimate (\S+) m, ANEES (\S+)", line)
    assert match is not None, line
    tracking = float(match.group(1))
    # The steady state is t > 10 s of the 20 s flight at 100 Hz: 1,000 of its 2,000 steps,
    # and its tracking RMSE is the one without the take-off climb, below the whole flight's.
    assert info["episode_steps_steady"] == 1000 and info["episode_steps"] == 2000
    assert tracking == pytest.approx(info["episode_track_pos_rmse_steady_m"], abs=5e-4)
    assert tracking < info["episode_track_pos_rmse_m"]


def test_sb3_with_two_workers_trains_with_lanes_ending_on_different_steps(
    tmp_path: Path,
) -> None:
    lanes, n_steps, duration_s, timesteps = 4, 64, 0.5, 256
    done = subprocess.run(
        [
            sys.executable,
            str(EXAMPLES / "sb3_workers.py"),
            f"--timesteps={timesteps}",
            f"--lanes={lanes}",
            f"--n-steps={n_steps}",
            f"--duration={duration_s}",
        ],
        cwd=tmp_path,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    assert (tmp_path / "ppo_residual_ekf.zip").is_file()
    # One rollout of 64 steps per lane. Episodes last 50 steps (0.5 s at 100 Hz) and the
    # stagger cuts lane i's first one after ceil(50 (i + 1) / 4) = 13, 25, 38, 50 steps: lanes
    # 0-1 (worker 0) and 2-3 (worker 1) end on different steps. Within 64 steps lane i ends
    # 1 + (64 - cut_i) // 50 times (none of these short episodes is terminated early).
    max_steps, per_lane = round(duration_s * 100), (timesteps // (lanes * n_steps)) * n_steps
    cuts = [math.ceil(max_steps * (i + 1) / lanes) for i in range(lanes)]
    expected = sum(1 + (per_lane - cut) // max_steps for cut in cuts)
    assert expected == 5
    assert done.stdout.strip().splitlines()[-1] == f"finished episodes: {expected}"


def test_readme_sb3_example_is_the_scripts_core() -> None:
    block = _readme_block("## stable-baselines3 on the vector env")
    source = (EXAMPLES / "sb3_workers.py").read_text(encoding="utf-8")
    core = source.split("# --8<-- [start:train]\n", 1)[1].split("\n\n# --8<-- [end:train]", 1)[0]
    assert block.strip() == core.strip()


def test_reward_figure_terms_sum_to_the_reward(tmp_path: Path) -> None:
    pytest.importorskip("matplotlib")
    spec = importlib.util.spec_from_file_location(
        "reward_figure", ROOT / "tools" / "reward_figure.py"
    )
    assert spec is not None and spec.loader is not None
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    terms = tool.episode_terms(seed=0, duration_s=0.5)
    assert terms["t"].size == 50
    total = sum(terms[term] for term in tool.TERMS)
    assert total == pytest.approx(terms["reward"], abs=1e-9)
    assert terms["pos"][0] == pytest.approx(-2.0, abs=0.05)  # starts 2 m below the figure-8
    tool.plot(terms, tmp_path / "r.png")
    assert (tmp_path / "r.png").stat().st_size > 0


def _files_under(folder: Path) -> set[Path]:
    return {p for p in folder.rglob("*") if p.is_file()} if folder.is_dir() else set()


@pytest.fixture
def skrl_run(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    """skrl's run folder under ``tmp_path``, from a ``tmp_path`` working directory; at the end
    skrl's log handler is removed and closed (it holds the stream pytest captured, closed after
    the test: a later line from skrl would go to a closed file)."""
    pytest.importorskip("skrl")
    monkeypatch.chdir(tmp_path)
    yield tmp_path / "skrl_runs"
    log = logging.getLogger("skrl")
    for handler in list(log.handlers):
        log.removeHandler(handler)
        handler.close()


def test_skrl_ppo_stores_one_transition_per_step_and_no_reset_step(skrl_run: Path) -> None:
    import torch

    before = _files_under(ROOT / "runs")
    example = _load("skrl_ppo")
    agent = example.train(40, num_envs=2, duration_s=0.2, rollouts=40, directory=skrl_run)
    assert _files_under(ROOT / "runs") == before  # nothing written into the checkout
    assert any(p.suffix == ".pt" for p in _files_under(skrl_run))  # the checkpoints went here
    memory = agent.memory
    ended = memory.get_tensor_by_name("terminated") | memory.get_tensor_by_name("truncated")
    # 0.2 s at 100 Hz = 20 steps: with same-step autoreset every lane's episodes end on the
    # 20th and 40th stored transitions; a reset step stored as a transition would shift them.
    assert torch.nonzero(ended[:, :, 0]).tolist() == [[19, 0], [19, 1], [39, 0], [39, 1]]


def test_tianshou_ppo_held_out_episodes_equal_the_scalar_env_flown_by_hand() -> None:
    pytest.importorskip("tianshou")
    import numpy as np
    import torch

    example = _load("tianshou_ppo")
    duration_s, episodes, seed = 0.4, 3, 1000
    algorithm, _ = example.train(256, num_envs=2, duration_s=duration_s, seed=0)
    stats = example.evaluate(algorithm, episodes, duration_s, seed)
    # tianshou seeds lane i by resetting it with seed + i, then resets it again before it
    # collects: each held-out episode is the second of the scalar env seeded seed + i, flown
    # with the actor's mean clipped to the action box [-1, 1].
    expected = []
    for lane in range(episodes):
        env = gym.make("QuadSLAM-EKF-v0", episode={"duration_s": duration_s})
        env.reset(seed=seed + lane)
        obs, _ = env.reset()
        ret, length, done = 0.0, 0, False
        while not done:
            with torch.no_grad():
                (loc, _), _ = algorithm.policy.actor(obs[None].astype(np.float32))
            action = np.clip(loc.numpy()[0], -1.0, 1.0)
            obs, reward, terminated, truncated, _ = env.step(action)
            ret, length, done = ret + float(reward), length + 1, terminated or truncated
        expected.append((ret, length))
        env.close()
    got = sorted(zip(stats.returns.tolist(), stats.lens.tolist(), strict=True))
    assert [n for _, n in got] == [n for _, n in sorted(expected)]
    assert [r for r, _ in got] == pytest.approx([r for r, _ in sorted(expected)], rel=1e-5)


def _team_rows(values: dict[str, object], agents: list[str]) -> object:
    import numpy as np

    return np.stack([values[agent] for agent in agents])


def test_team_vec_env_steps_the_team_env_and_ends_the_team_with_its_first_vehicle() -> None:
    pytest.importorskip("pettingzoo")
    import numpy as np

    from quadslam_env.team.env import parallel_env

    example = _load("team_sb3")
    settings = {"n_vehicles": 3, "episode": {"duration_s": 2.0}}
    venv = example.TeamVecEnv(parallel_env(**settings), seed=5)
    team = parallel_env(**settings)  # flown by hand with the same actions
    agents = team.possible_agents
    obs = venv.reset()
    ref, _ = team.reset(seed=5)
    assert np.array_equal(obs, _team_rows(ref, agents))
    rng = np.random.default_rng(0)
    for _ in range(200):  # random thrust and torques: the vehicles tilt over within 2 s
        actions = rng.uniform(-1.0, 1.0, (3, 4)).astype(np.float32)
        venv.step_async(actions)
        obs, rewards, dones, infos = venv.step_wait()
        ref, ref_rewards, terms, truncs, _ = team.step(dict(zip(agents, actions, strict=True)))
        assert rewards.tolist() == pytest.approx([ref_rewards[a] for a in agents], rel=1e-6)
        if dones.any():
            break
        assert np.array_equal(obs, _team_rows(ref, agents))
    assert dones.all()  # the first vehicle to end ends the team's episode
    own = [a for a in agents if terms[a] or truncs[a]]
    assert 1 <= len(own) < 3 and team.agents  # some vehicles ended, the others were cut
    for i, agent in enumerate(agents):
        assert infos[i]["TimeLimit.truncated"] is (not terms[agent])  # cut: bootstrapped
        assert np.array_equal(infos[i]["terminal_observation"], ref[agent])
    assert (venv.episodes_ended, venv.episodes_cut) == (len(own), 3 - len(own))
    ref, _ = team.reset()  # the team was reset, its streams continued (no new seed)
    assert np.array_equal(obs, _team_rows(ref, agents))
    assert venv.samples.tolist() == [venv.samples[0]] * 3


def test_team_sb3_trains_one_policy_on_every_vehicle_and_evaluates_each(
    capsys: pytest.CaptureFixture[str],
) -> None:
    pytest.importorskip("pettingzoo")
    example = _load("team_sb3")
    vehicles, n_steps, timesteps, duration_s = 2, 128, 700, 2.0
    argv = [f"--timesteps={timesteps}", f"--vehicles={vehicles}", f"--n-steps={n_steps}",
            f"--duration={duration_s}", "--hidden", "16"]  # fmt: skip
    assert example.main(argv) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    # PPO collects whole rollouts of n_steps steps of every vehicle: ceil(700 / 256) = 3.
    per_vehicle = -(-timesteps // (n_steps * vehicles)) * n_steps
    samples = " ".join(f"vehicle_{i}={per_vehicle}" for i in range(vehicles))
    assert lines[0] == f"trained: {per_vehicle * vehicles} steps; samples per vehicle: {samples}"
    match = re.fullmatch(r"vehicle episodes: (\d+) ended, (\d+) cut by a teammate's", lines[1])
    assert match is not None, lines[1]
    ended, cut = int(match.group(1)), int(match.group(2))
    # Each team episode ends every vehicle's: at least one by itself, the others cut.
    assert ended >= 1 and (ended + cut) % vehicles == 0 and cut <= ended * (vehicles - 1)
    assert len(lines) == 2 + vehicles
    max_steps = round(duration_s * 100)
    for i, line in enumerate(lines[2:]):
        match = re.fullmatch(
            rf"vehicle_{i}: tracking RMSE (\S+) m, (\d+) steps, ended by (\S+(?: limit)?)", line
        )
        assert match is not None, line
        assert math.isfinite(float(match.group(1))) and float(match.group(1)) > 0.0
        assert 1 <= int(match.group(2)) <= max_steps
        assert (match.group(3) == "time limit") is (int(match.group(2)) == max_steps)
