"""The named controllers' options (``drag_feedforward``, ``thrust_adaptation``) wherever a
controller is flown by name: ``quadslam run`` and ``quadslam evaluate`` (the same flags, parsed
and checked by one helper) and a sweep's evaluate blocks; each reaches the controller, and each
is refused, naming the flag or the key, with a policy that does not take it."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import gymnasium as gym
import pytest

import quadslam_env  # noqa: F401  (registers the ids)
from agents.lab.cli.fly import controller_options
from agents.lab.cli.main import build_parser, main
from agents.lab.sweep.jobs import execute_job
from agents.lab.sweep.spec import SweepSpecError, parse_spec
from agents.rl.policies import load_policy

WIND = ["--scenario", "ekf_figure8_wind_states", "--set", "observation.air_velocity=true"]
EVALUATE = ["evaluate", "--duration", "1.0", "--episodes", "1", *WIND]


@pytest.mark.parametrize("command", ["run", "evaluate"])
def test_run_and_evaluate_parse_the_same_flags(command: str) -> None:
    argv = [command, "--policy", "se3", "--drag-feedforward", "--thrust-adaptation"]
    args = build_parser().parse_args(argv)
    both = {"drag_feedforward": True, "thrust_adaptation": True}
    assert controller_options(args, command) == both
    plain = build_parser().parse_args([command, "--policy", "lqi"])
    assert controller_options(plain, command) == {}


@pytest.mark.parametrize("flag", ["--drag-feedforward", "--thrust-adaptation"])
def test_evaluate_refuses_them_with_a_policy_without_them(flag: str, tmp_path: Path) -> None:
    with pytest.raises(
        SystemExit,
        match=rf"^quadslam evaluate: error: {flag}: only with --policy lqi or se3 "
        r"\(got --policy dflqr\)$",
    ):
        main([*EVALUATE, "--policy", "dflqr", flag])
    run = tmp_path / "run"  # a trained model takes none either: refused before it is read
    run.mkdir()
    with pytest.raises(SystemExit, match=rf"{flag}: only with --policy lqi or se3 \(got --policy "):
        main([*EVALUATE, "--policy", str(run), flag])


def test_load_policy_gives_them_to_the_controller_and_refuses_them_for_a_model(
    tmp_path: Path,
) -> None:
    env = gym.make("QuadSLAM-v0", scenario="ekf_figure8_wind_states",
                   observation={"air_velocity": True})  # fmt: skip
    try:
        on, _ = load_policy("se3", env, options={"drag_feedforward": True,
                                                 "thrust_adaptation": True})  # fmt: skip
        off, _ = load_policy("se3", env)
        assert on.feedforward is not None and on.adaptation
        assert off.feedforward is None and not off.adaptation
        with pytest.raises(ValueError, match=r"thrust_adaptation: got True with --policy "):
            load_policy(str(tmp_path), env, options={"thrust_adaptation": True})
    finally:
        env.close()


def _evaluate(tmp_path: Path, *flags: str) -> dict[str, Any]:
    out = tmp_path / f"eval{len(flags)}.json"
    assert main([*EVALUATE, "--policy", "lqi", "--json", str(out), *flags]) == 0
    return json.loads(out.read_text())


def test_evaluate_flies_the_drag_feedforward(tmp_path: Path) -> None:
    off = _evaluate(tmp_path)["episodes"][0]
    on = _evaluate(tmp_path, "--drag-feedforward")["episodes"][0]
    assert on["track_pos_rmse_m"] != off["track_pos_rmse_m"]


# ----------------------------------------------------------------------------- sweeps
def _block(**keys: Any) -> dict[str, Any]:
    return {
        "kind": "evaluate",
        "policy": "lqi",
        "scenario": "ekf_figure8_wind_states",
        "set": {"episode.duration_s": 1.0, "observation.air_velocity": True},
        **keys,
    }


def test_a_sweep_evaluate_block_takes_them() -> None:
    (on,) = parse_spec({"jobs": [_block(drag_feedforward=True, thrust_adaptation=True)]})
    (off,) = parse_spec({"jobs": [_block(drag_feedforward=False)]})
    (plain,) = parse_spec({"jobs": [_block()]})
    assert on.params["drag_feedforward"] is True and on.params["thrust_adaptation"] is True
    assert on.columns["drag_feedforward"] is True
    assert off.params == plain.params and off.job_id == plain.job_id  # false: as before
    assert "drag_feedforward" not in plain.params and "drag_feedforward" not in plain.columns
    a = execute_job("evaluate", on.params)["result"]["episodes"][0]
    b = execute_job("evaluate", plain.params)["result"]["episodes"][0]
    assert a["track_pos_rmse_m"] != b["track_pos_rmse_m"]


@pytest.mark.parametrize(
    ("block", "match"),
    [
        (_block(policy="dflqr", drag_feedforward=True),
         r"jobs\[0\] \(scenario=.*policy='dflqr'.*\): drag_feedforward: got True with policy "
         r"dflqr; allowed: false, or a controller with the drag feed-forward \(lqi, se3\)"),
        (_block(policy="dflqr", thrust_adaptation=True),
         r"thrust_adaptation: got True with policy dflqr; allowed: false, or a controller with "
         r"the thrust adaptation"),
        (_block(thrust_adaptation="yes"),
         r"jobs\[0\]\.thrust_adaptation: got 'yes'; allowed: true or false"),
        ({**_block(drag_feedforward=True), "set": {"episode.duration_s": 1.0}},
         r"drag_feedforward: got true with observation.air_velocity false; allowed: false, or "
         r"set: \{observation.air_velocity: true\}"),
        ({"kind": "run", "drag_feedforward": True},
         r"jobs\[0\]\.drag_feedforward: unknown key for a run job"),
    ],
)  # fmt: skip
def test_a_sweep_refuses_them_naming_the_key(block: dict[str, Any], match: str) -> None:
    with pytest.raises(SweepSpecError, match=match):
        parse_spec({"jobs": [block]})
