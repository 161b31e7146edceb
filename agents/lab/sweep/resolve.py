"""Sweep jobs resolved against the package: scenarios, env ids, agent YAMLs (no env built).

:class:`Resolver` turns one grid point of a job block (:mod:`agents.lab.sweep.spec`) into the job's
parameters and table columns, checking on the way everything ``quadslam run``, ``evaluate`` or
``train`` would check when it starts: the scenario (name or YAML path) with the ``set``
overrides and the estimator, through :func:`quadslam_env.config.load_scenario` (the same
``ScenarioConfig`` that ``gymnasium.make`` would build, without building an env); env ids;
``evaluate`` policies; and for ``train`` the algorithm, the agent YAML entry merged with the
hyperparameters (:func:`agents.rl.hyperparams.resolve_settings`) and its ``env_kwargs``; and
the memory a job will hold (:func:`agents.evaluation.episodes.check_episodes_memory` for the
lanes of ``run`` and ``evaluate``, :func:`agents.rl.building.check_training_memory` for
``train``).
"""

from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any

from agents.control.named import CONTROLLERS, OPTIONS, controller_options

DEFAULT_EVAL_SEED = 1000  # held-out seeds of train jobs start here (as in the study)
DEFAULT_EPISODES = 10  # held-out episodes per train job (quadslam evaluate's default)


class SweepSpecError(ValueError):
    """A malformed sweep spec (one line: where, the key, the value, what is allowed)."""


def is_int(value: Any) -> bool:
    """An ``int`` that is not a ``bool``."""
    return isinstance(value, int) and not isinstance(value, bool)


def nest(flat: dict[str, Any]) -> dict[str, Any]:
    """``{"episode.duration_s": 5}`` → ``{"episode": {"duration_s": 5}}``."""
    out: dict[str, Any] = {}
    for key, value in flat.items():
        node = out
        *parents, leaf = key.split(".")
        for part in parents:
            node = node.setdefault(part, {})
        node[leaf] = copy.deepcopy(value)
    return out


class Resolver:
    """Resolves each grid point against the scenarios, env ids and agent YAMLs (cached)."""

    def __init__(self) -> None:
        self._scenarios: dict[str, Any] = {}

    def resolve(
        self,
        kind: str,
        point: dict[str, Any],
        fixed: dict[str, Any],
        where: str,
        lanes: int = 1,
    ) -> tuple[dict[str, Any], dict[str, Any]]:
        """Job parameters and table columns of one grid point.

        Args:
            kind: ``run``, ``evaluate`` or ``train``.
            point: The grid point: axis keys (``scenario``, ``env``, …) and ``set:<key>`` /
                ``hp:<key>`` entries, each with one value.
            fixed: The block's non-axis settings (``plots``, ``episodes``, ``eval_seed``,
                ``trust_pickle``, ``drag_feedforward``, ``thrust_adaptation``).
            where: How error messages name the point (spec, block, axis values).
            lanes: The seeds a ``run`` or ``evaluate`` job flies at once (``seeds_per_job``).

        Returns:
            ``(params, columns)``: :attr:`agents.lab.sweep.spec.Job.params` without the seeds, and
            the table columns (resolved scenario and estimator names, env id, algorithm,
            policy, the controller options turned on, one column per ``set``/``hyperparams``
            key).

        Raises:
            SweepSpecError: The point names something that does not exist or is invalid, or
                a job that would not fit in memory.
        """
        try:
            return self._resolve(kind, point, fixed, where, lanes)
        except SweepSpecError:
            raise
        except (ValueError, TypeError, KeyError, FileNotFoundError) as exc:
            message = " ".join(str(exc).split()) or type(exc).__name__
            raise SweepSpecError(f"{where}: {message}") from None

    def _resolve(
        self, kind: str, point: dict[str, Any], fixed: dict[str, Any], where: str, lanes: int
    ) -> tuple[dict[str, Any], dict[str, Any]]:
        for key in ("scenario", "estimator", "env", "algo", "policy", "config"):
            value = point.get(key)
            if value is not None and (not isinstance(value, str) or not value):
                raise SweepSpecError(
                    f"{where}: {key}: got {value!r}; allowed: a non-empty string (a list of "
                    "them is a grid axis)"
                )
        sets = {k[4:]: v for k, v in point.items() if k.startswith("set:")}
        hps = {k[3:]: v for k, v in point.items() if k.startswith("hp:")}
        scenario = self._scenario_arg(point.get("scenario"))
        columns: dict[str, Any] = {}
        if kind == "train":
            params, resolved = self._train(point, fixed, scenario, sets, hps)
        else:
            from agents.evaluation.episodes import check_episodes_memory

            params, resolved = self._fly(kind, point, fixed, scenario, sets)
            check_episodes_memory(resolved, lanes, "seeds_per_job")
        columns.update(
            scenario=resolved.name,
            estimator=resolved.estimator.name,
            env=params["env"],
            algo=params.get("algo"),
            policy=params.get("policy", "dflqr") if kind != "train" else params["algo"],
        )
        columns.update({key: True for key in OPTIONS if params.get(key)})
        columns.update({k: _cell(v) for k, v in sets.items()})
        columns.update({f"hyperparams.{k}": _cell(v) for k, v in hps.items()})
        return params, columns

    def _scenario_arg(self, scenario: str | None) -> str | dict[str, Any] | None:
        """A shipped name stays a name; a YAML path is read here (the workers get its content)."""
        from quadslam_env.config.files import available_scenarios, load_yaml

        if scenario is None or scenario in available_scenarios():
            return scenario
        path = Path(scenario)
        if path.suffix in (".yaml", ".yml") or path.exists():
            if scenario not in self._scenarios:
                data = load_yaml(path)
                self._scenarios[scenario] = {"name": path.stem, **data}
            return copy.deepcopy(self._scenarios[scenario])
        return scenario  # load_scenario names the allowed ones

    def _fly(
        self,
        kind: str,
        point: dict[str, Any],
        fixed: dict[str, Any],
        scenario: Any,
        sets: dict[str, Any],
    ) -> tuple[dict[str, Any], Any]:
        """run / evaluate: the env the job flies on, resolved as ``quadslam run`` would."""
        policy = point.get("policy", "dflqr")
        env_id = point.get("env")
        if kind == "evaluate" and policy not in CONTROLLERS:
            from agents.rl.saved.run_folder import run_config

            path = Path(policy)
            if not path.exists():
                raise SweepSpecError(
                    f"policy: got {policy!r}; allowed: a controller ({', '.join(CONTROLLERS)}), "
                    "a run folder or a model .zip"
                )
            policy = str(path.resolve())
            cfg = run_config(path)
            env_id = env_id or (cfg["env_id"] if cfg else None)
            if scenario is None and cfg is not None:
                scenario = cfg.get("scenario")
        env_id = env_id or "QuadSLAM-v0"
        resolved = _resolve_env(env_id, scenario, point.get("estimator"), nest(sets))
        params = {
            "env": env_id,
            "scenario": scenario,
            "estimator": point.get("estimator"),
            "overrides": nest(sets),
            "plots": bool(fixed.get("plots", False)),
        }
        if kind == "evaluate":
            params["policy"] = policy
            if fixed.get("trust_pickle"):  # only when set: the other jobs keep their ids
                params["trust_pickle"] = True
            params.update(_controller_options(policy, fixed, resolved))
        return params, resolved

    def _train(
        self,
        point: dict[str, Any],
        fixed: dict[str, Any],
        scenario: Any,
        sets: dict[str, Any],
        hps: dict[str, Any],
    ) -> tuple[dict[str, Any], Any]:
        """train: the agent YAML entry with the overrides, checked as ``quadslam train`` does."""
        from agents.rl.hyperparams import (
            algorithms,
            default_config_path,
            load_hyperparams,
            resolve_settings,
        )
        from quadslam_env.config.files import deep_merge

        algo = str(point["algo"]).lower()
        if algo not in algorithms():
            raise SweepSpecError(f"algo: got {point['algo']!r}; allowed: {sorted(algorithms())}")
        env_id = point.get("env", "QuadSLAM-EKF-v0")
        config = point.get("config")
        source = Path(config).resolve() if config is not None else default_config_path(algo)
        if config is not None:
            from quadslam_env.config.files import check_config_file

            check_config_file(source, "config")  # exists, a file, at most 1 MiB: before reading
        for key in ("timesteps", "n_envs"):
            value = point.get(key)
            if value is not None and (not is_int(value) or value < 1):
                raise SweepSpecError(f"{key}: got {value!r}; allowed: a positive integer")
        env_kwargs: dict[str, Any] = nest(sets)
        if scenario is not None:
            env_kwargs["scenario"] = scenario
        if point.get("estimator") is not None:
            env_kwargs["estimator_name"] = point["estimator"]
        hyperparams = deep_merge(nest(hps), {"env_kwargs": env_kwargs} if env_kwargs else {})
        _check_env_id(env_id)
        entry = deep_merge(load_hyperparams(algo, env_id, source), hyperparams)
        for key, name in (("timesteps", "n_timesteps"), ("n_envs", "n_envs")):
            if point.get(key) is not None:
                entry[name] = int(point[key])
        settings = resolve_settings(algo, entry)
        kwargs = dict(settings["env_kwargs"])
        resolved = _resolve_env(
            env_id, kwargs.pop("scenario", None), kwargs.pop("estimator_name", None), kwargs
        )
        from agents.rl.building import check_training_memory

        check_training_memory(algo, settings, env_id)
        params = {
            "algo": algo,
            "env": env_id,
            # The default file is found again where the job runs (package data).
            "config": None if config is None else str(source),
            "hyperparams": hyperparams,
            "timesteps": point.get("timesteps"),
            "n_envs": point.get("n_envs"),
            "episodes": int(fixed.get("episodes", DEFAULT_EPISODES)),
            "eval_seed": int(fixed.get("eval_seed", DEFAULT_EVAL_SEED)),
        }
        return params, resolved


def _controller_options(policy: str, fixed: dict[str, Any], resolved: Any) -> dict[str, bool]:
    """The controller options an evaluate block turns on (``drag_feedforward: true``, …), as
    the policy ``policy`` on the scenario ``resolved`` takes them.

    Raises:
        ValueError: An option on a policy without it, or the drag feed-forward on a scenario
            whose observation has no air velocity (naming the key).
    """
    given = {key: fixed[key] for key in OPTIONS if key in fixed}
    options = controller_options(policy, "policy", **given)
    if options.get("drag_feedforward") and not resolved.observation.air_velocity:
        raise ValueError(
            "drag_feedforward: got true with observation.air_velocity false; allowed: false, or "
            "set: {observation.air_velocity: true} (with an estimator that estimates the "
            "wind: ekf_slam with estimator.params.wind: estimate)"
        )
    return options


def _check_env_id(env_id: str) -> None:
    import gymnasium as gym

    import quadslam_env

    if env_id not in gym.registry:
        raise SweepSpecError(
            f"env: got {env_id!r}; allowed: one of {list(quadslam_env.ENV_IDS)} or another "
            "registered Gymnasium id"
        )


def _resolve_env(env_id: str, scenario: Any, estimator: str | None, overrides: dict) -> Any:
    """The ``ScenarioConfig`` that ``gymnasium.make(env_id, ...)`` would build (no env)."""
    import gymnasium as gym

    from quadslam_env.config.scenario import load_scenario

    _check_env_id(env_id)
    kwargs = {**gym.spec(env_id).kwargs, **overrides}
    if scenario is not None:
        kwargs["scenario"] = scenario
    if estimator is not None:
        kwargs["estimator_name"] = estimator
    kwargs.pop("render_mode", None)
    name = kwargs.pop("scenario", None)
    swap = kwargs.pop("estimator_name", None)
    return load_scenario(name, kwargs, swap)


def _cell(value: Any) -> Any:
    """A table cell: scalars as they are, lists and mappings as JSON text."""
    if value is None or isinstance(value, bool | int | float | str):
        return value
    return json.dumps(value, sort_keys=True)
