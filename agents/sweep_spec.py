"""Sweep specs for ``quadslam sweep``: reading, validation and expansion into jobs.

A spec is a YAML file with a list of job blocks; each block expands into a grid of jobs::

    description: LiDAR range noise, EKF-SLAM          # optional, one line
    jobs:
      - kind: run                                     # run | train | evaluate
        scenario: [paper_ekf_figure8, paper_ekf_figure8_known]   # a list is a grid axis
        seeds: 4                                      # seeds 0..3 (or a list of seeds)
        set: {episode.duration_s: 5, lidar.sigma_range_m: [0.05, 0.1]}   # --set overrides

Every list value of an axis key (``scenario``, ``estimator``, ``env``, ``algo``, ``policy``,
``config``, ``timesteps``, ``n_envs``) and of a ``set`` or ``hyperparams`` entry is a grid
axis; a setting whose value is itself a list is written as a list of lists
(``estimator.initial_cov_diag: [[1e-3, ...]]``: one grid value). The grid is the Cartesian
product of the axes, with the seeds innermost: one job per grid point and seed.

============  ===============================================================================
kind          one job is
============  ===============================================================================
``run``       ``quadslam run --seed S --seeds 1``: one DF-LQR episode (``plots: true`` also
              writes the figures of its first episode)
``evaluate``  ``quadslam evaluate --policy P --seed S --episodes 1``: one episode of
              ``policy`` (``dflqr``, a run folder or a model ``.zip``) on ``env``
``train``     ``quadslam train --algo A --env E --seed S`` (the agent YAML entry, merged with
              ``hyperparams``; ``scenario``/``estimator``/``set`` go into its ``env_kwargs``),
              then ``episodes`` held-out evaluation episodes from seed ``eval_seed``
============  ===============================================================================

``seeds`` is a number N (seeds ``seed … seed + N − 1``, ``seed`` defaulting to 0, as
``--seed``/``--seeds``) or a list; ``cpus`` (default 1) is what Ray reserves for each job.
``seeds_per_job: K`` (run and evaluate; default 1) flies K consecutive seeds of a grid point in
one job, as K lanes of one vector env (``quadslam run --seed S --seeds K``: the same numbers,
less start-up per episode, fewer and longer jobs).

Everything is checked before any job starts (:func:`load_spec`): unknown keys or kinds,
empty grids, unknown scenarios, env ids, algorithms or estimators, bad ``set`` keys or values
and bad hyperparameters raise :class:`SweepSpecError`, one line naming the job block, the key,
the value and what is allowed.
"""

from __future__ import annotations

import copy
import hashlib
import itertools
import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

KINDS = ("run", "evaluate", "train")
_COMMON = ("kind", "name", "scenario", "estimator", "seed", "seeds", "set", "cpus")
KIND_KEYS: dict[str, tuple[str, ...]] = {
    "run": (*_COMMON, "seeds_per_job", "plots"),
    "evaluate": (*_COMMON, "seeds_per_job", "policy", "env", "plots"),
    "train": (
        *_COMMON,
        "algo",
        "env",
        "config",
        "hyperparams",
        "timesteps",
        "n_envs",
        "episodes",
        "eval_seed",
    ),
}
#: Keys whose list value is a grid axis (``set`` and ``hyperparams`` entries are too).
AXIS_KEYS = ("scenario", "estimator", "env", "algo", "policy", "config", "timesteps", "n_envs")
TOP_KEYS = ("description", "jobs")
DEFAULT_EVAL_SEED = 1000  # held-out seeds of train jobs start here (as in the study)
DEFAULT_EPISODES = 10  # held-out episodes per train job (quadslam evaluate's default)


class SweepSpecError(ValueError):
    """A malformed sweep spec (one line: where, the key, the value, what is allowed)."""


@dataclass(frozen=True)
class Job:
    """One job of a sweep: a grid point of a job block and one seed.

    Attributes:
        job_id: Stable name from the job's content (its folder under ``OUT/jobs``).
        kind: ``run``, ``evaluate`` or ``train``.
        block: Index of the job block in the spec's ``jobs`` list.
        seeds: Episode seeds (run, evaluate: one lane each) or the one training seed (train).
        cpus: CPUs Ray reserves for the job.
        params: Plain-data arguments of :func:`agents.sweep_jobs.execute_job`.
        columns: The job's settings as table columns (name, resolved scenario and estimator,
            env id, algorithm, policy, and one column per ``set``/``hyperparams`` key).
    """

    job_id: str
    kind: str
    block: int
    seeds: tuple[int, ...]
    cpus: float
    params: dict[str, Any]
    columns: dict[str, Any]

    @property
    def seed(self) -> int:
        """The first (for train jobs: the) seed."""
        return self.seeds[0]


# ----------------------------------------------------------------------------- reading
def shipped_specs_dir() -> Path:
    """``quadslam_env/configs/sweeps`` (the example specs; ``QUADSLAM_CONFIG_DIR`` overrides)."""
    from quadslam_env.config_files import config_dir

    return config_dir() / "sweeps"


def shipped_specs() -> list[str]:
    """Names of the example specs shipped with the package."""
    return sorted(p.stem for p in shipped_specs_dir().glob("*.yaml"))


def spec_path(spec: str | Path) -> Path:
    """A spec path, or the shipped spec of that name (``rauniyar2023_table``).

    Raises:
        SweepSpecError: Neither an existing file nor a shipped spec name.
    """
    path = Path(spec)
    if path.is_file():
        return path
    shipped = shipped_specs_dir() / f"{spec}.yaml"
    if path.suffix not in (".yaml", ".yml") and shipped.is_file():
        return shipped
    raise SweepSpecError(
        f"SPEC: got {str(spec)!r}; allowed: a YAML file or a shipped spec name "
        f"(one of {shipped_specs()})"
    )


def load_spec(spec: str | Path) -> list[Job]:
    """Read, validate and expand a spec file (or shipped spec name) into its jobs.

    Raises:
        SweepSpecError: Unreadable file, malformed YAML or any invalid entry (see the module
            docstring); nothing has run yet.
    """
    from quadslam_env.config_files import DuplicateKeyError, parse_yaml, read_text_file

    path = spec_path(spec)
    try:
        data = parse_yaml(read_text_file(path, "sweep spec"))
    except DuplicateKeyError as exc:
        raise SweepSpecError(f"{path}: {exc}") from None
    except yaml.YAMLError as exc:
        raise SweepSpecError(f"{path}: malformed YAML ({exc})") from None
    except ValueError as exc:
        raise SweepSpecError(str(exc)) from None
    return parse_spec(data, str(path))


def parse_spec(data: Any, where: str = "spec") -> list[Job]:
    """Validate and expand a spec mapping (as read from YAML) into its jobs.

    Args:
        data: The spec: ``{"jobs": [...], "description": ...}``.
        where: How error messages name the spec (its path).

    Raises:
        SweepSpecError: See :func:`load_spec`.
    """
    if not isinstance(data, dict):
        raise SweepSpecError(
            f"{where}: got {type(data).__name__}; allowed: a mapping with keys {list(TOP_KEYS)}"
        )
    for key in data:
        if key not in TOP_KEYS:
            raise SweepSpecError(f"{where}: {key!r}: unknown key; allowed: {list(TOP_KEYS)}")
    blocks = data.get("jobs")
    if not isinstance(blocks, list) or not blocks:
        raise SweepSpecError(
            f"{where}: jobs: got {blocks!r}; allowed: a non-empty list of job blocks"
        )
    jobs: list[Job] = []
    seen: dict[str, int] = {}
    validator = _Validator()
    for i, block in enumerate(blocks):
        for job in _expand_block(block, i, f"{where}: jobs[{i}]", validator):
            if job.job_id in seen:
                raise SweepSpecError(
                    f"{where}: jobs[{i}] (seed {job.seed}): the same job as one of "
                    f"jobs[{seen[job.job_id]}]; allowed: each job once"
                )
            seen[job.job_id] = i
            jobs.append(job)
    return jobs


# ----------------------------------------------------------------------------- one block
def _expand_block(block: Any, index: int, where: str, validator: _Validator) -> list[Job]:
    """Check one job block's keys and values and expand its grid."""
    if not isinstance(block, dict):
        raise SweepSpecError(f"{where}: got {block!r}; allowed: a mapping with a 'kind' key")
    kind = block.get("kind")
    if kind not in KINDS:
        raise SweepSpecError(f"{where}.kind: got {kind!r}; allowed: one of {list(KINDS)}")
    allowed = KIND_KEYS[kind]
    for key in block:
        if key not in allowed:
            raise SweepSpecError(
                f"{where}.{key}: unknown key for a {kind} job; allowed: {sorted(allowed)}"
            )
    if kind == "evaluate" and "policy" not in block:
        raise SweepSpecError(
            f"{where}.policy: missing; allowed: 'dflqr', a run folder or a model .zip"
        )
    if kind == "train" and "algo" not in block:
        raise SweepSpecError(f"{where}.algo: missing; allowed: ppo, sac, td3 or a2c")
    name = block.get("name", f"jobs[{index}]")
    if not isinstance(name, str) or not name.strip():
        raise SweepSpecError(f"{where}.name: got {name!r}; allowed: a non-empty string")
    seeds = _seeds(block, where)
    per_job = block.get("seeds_per_job", 1)
    if not _is_int(per_job) or per_job < 1:
        raise SweepSpecError(f"{where}.seeds_per_job: got {per_job!r}; allowed: a positive integer")
    groups = [seeds[i : i + per_job] for i in range(0, len(seeds), per_job)]
    cpus = block.get("cpus", 1)
    if isinstance(cpus, bool) or not isinstance(cpus, int | float) or not cpus > 0:
        raise SweepSpecError(f"{where}.cpus: got {cpus!r}; allowed: a positive number")
    fixed = {k: block[k] for k in ("plots", "episodes", "eval_seed") if k in block}
    _check_scalars(fixed, where)

    axes: list[tuple[str, list[Any]]] = []
    for key in AXIS_KEYS:
        if key in block:
            axes.append((key, _axis(block[key], f"{where}.{key}")))
    set_entries = _dotted(block.get("set", {}), f"{where}.set", min_parts=2)
    hp_entries = _dotted(block.get("hyperparams", {}), f"{where}.hyperparams", min_parts=1)
    axes += [(f"set:{k}", _axis(v, f"{where}.set.{k}")) for k, v in set_entries.items()]
    axes += [(f"hp:{k}", _axis(v, f"{where}.hyperparams.{k}")) for k, v in hp_entries.items()]

    jobs = []
    for values in itertools.product(*(vals for _, vals in axes)):
        point = dict(zip((key for key, _ in axes), values, strict=True))
        label = ", ".join(f"{k.split(':')[-1]}={v!r}" for k, v in point.items()) or "no axes"
        point_where = f"{where} ({label})"
        params, columns = validator.resolve(kind, point, fixed, point_where)
        columns = {"name": name, **columns}
        for group in groups:
            job_params = {**copy.deepcopy(params), "seeds": [int(s) for s in group]}
            if kind == "train":
                job_params = {**copy.deepcopy(params), "seed": int(group[0])}
            jobs.append(
                Job(
                    job_id=_job_id(kind, job_params, columns),
                    kind=kind,
                    block=index,
                    seeds=tuple(int(s) for s in group),
                    cpus=float(cpus),
                    params=job_params,
                    columns=columns,
                )
            )
    return jobs


def _seeds(block: dict[str, Any], where: str) -> list[int]:
    """``seeds`` (a count from ``seed``, or a list) as a list of seeds."""
    seeds = block.get("seeds", 1)
    first = block.get("seed", 0)
    if not _is_int(first) or first < 0:
        raise SweepSpecError(f"{where}.seed: got {first!r}; allowed: an integer >= 0")
    if isinstance(seeds, list):
        if "seed" in block:
            raise SweepSpecError(
                f"{where}.seed: given with a list of seeds; allowed: 'seed' only with a number "
                "of seeds"
            )
        if not seeds:
            raise SweepSpecError(f"{where}.seeds: empty list; allowed: a non-empty list of seeds")
        for s in seeds:
            if not _is_int(s) or s < 0:
                raise SweepSpecError(
                    f"{where}.seeds: got {s!r} in the list; allowed: integers >= 0"
                )
        if len(set(seeds)) != len(seeds):
            raise SweepSpecError(f"{where}.seeds: got {seeds!r}; allowed: each seed once")
        return [int(s) for s in seeds]
    if not _is_int(seeds) or seeds < 1:
        raise SweepSpecError(
            f"{where}.seeds: got {seeds!r}; allowed: a positive number of seeds or a "
            "non-empty list of seeds"
        )
    return list(range(int(first), int(first) + int(seeds)))


def _check_scalars(fixed: dict[str, Any], where: str) -> None:
    if "plots" in fixed and not isinstance(fixed["plots"], bool):
        raise SweepSpecError(f"{where}.plots: got {fixed['plots']!r}; allowed: true or false")
    if "episodes" in fixed and (not _is_int(fixed["episodes"]) or fixed["episodes"] < 0):
        raise SweepSpecError(
            f"{where}.episodes: got {fixed['episodes']!r}; allowed: an integer >= 0"
        )
    if "eval_seed" in fixed and (not _is_int(fixed["eval_seed"]) or fixed["eval_seed"] < 0):
        raise SweepSpecError(
            f"{where}.eval_seed: got {fixed['eval_seed']!r}; allowed: an integer >= 0"
        )


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _axis(value: Any, where: str) -> list[Any]:
    """A grid axis: a list's values, or the one value of a scalar."""
    if isinstance(value, list):
        if not value:
            raise SweepSpecError(
                f"{where}: empty list (an empty grid); allowed: a value or a non-empty list "
                "of values"
            )
        return list(value)
    return [value]


_KEY_PART = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


def _dotted(entries: Any, where: str, min_parts: int) -> dict[str, Any]:
    """A mapping of dotted keys (``section.key``) to values, checked for shape."""
    if not isinstance(entries, dict):
        raise SweepSpecError(
            f"{where}: got {entries!r}; allowed: a mapping of dotted keys to values, e.g. "
            "{episode.duration_s: 5}"
        )
    example = "section.key, e.g. episode.duration_s" if min_parts == 2 else "e.g. n_steps"
    keys = list(entries)
    for key in keys:
        parts = key.split(".") if isinstance(key, str) else []
        if len(parts) < min_parts or not all(_KEY_PART.match(p) for p in parts):
            raise SweepSpecError(f"{where}: key {key!r}; allowed: {example}")
        for other in keys:
            if other != key and str(other).startswith(f"{key}."):
                raise SweepSpecError(f"{where}: {key!r} conflicts with {other!r}")
    return dict(entries)


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


def _job_id(kind: str, params: dict[str, Any], columns: dict[str, Any]) -> str:
    """``<kind>-<label>-s<seed>[+<n>]-<hash>``: readable, stable while the job is the same."""
    blob = json.dumps({"kind": kind, "params": params}, sort_keys=True, default=str)
    digest = hashlib.sha1(blob.encode()).hexdigest()[:10]
    label = str(columns.get("env") if kind == "train" else columns.get("scenario"))
    label = re.sub(r"[^A-Za-z0-9_.-]+", "_", label)[:40]
    seeds = params.get("seeds") or [params["seed"]]
    more = f"+{len(seeds) - 1}" if len(seeds) > 1 else ""
    return f"{kind}-{label}-s{seeds[0]}{more}-{digest}"


# ----------------------------------------------------------------------------- validation
class _Validator:
    """Resolves each grid point against the scenarios, env ids and agent YAMLs (cached)."""

    def __init__(self) -> None:
        self._scenarios: dict[str, Any] = {}

    def resolve(
        self, kind: str, point: dict[str, Any], fixed: dict[str, Any], where: str
    ) -> tuple[dict[str, Any], dict[str, Any]]:
        """Job parameters and table columns of one grid point.

        Raises:
            SweepSpecError: The point names something that does not exist or is invalid.
        """
        try:
            return self._resolve(kind, point, fixed, where)
        except SweepSpecError:
            raise
        except (ValueError, TypeError, KeyError, FileNotFoundError) as exc:
            message = " ".join(str(exc).split()) or type(exc).__name__
            raise SweepSpecError(f"{where}: {message}") from None

    def _resolve(
        self, kind: str, point: dict[str, Any], fixed: dict[str, Any], where: str
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
            params, resolved = self._fly(kind, point, fixed, scenario, sets)
        columns.update(
            scenario=resolved.name,
            estimator=resolved.estimator.name,
            env=params["env"],
            algo=params.get("algo"),
            policy=params.get("policy", "dflqr") if kind != "train" else params["algo"],
        )
        columns.update({k: _cell(v) for k, v in sets.items()})
        columns.update({f"hyperparams.{k}": _cell(v) for k, v in hps.items()})
        return params, columns

    def _scenario_arg(self, scenario: str | None) -> str | dict[str, Any] | None:
        """A shipped name stays a name; a YAML path is read here (the workers get its content)."""
        from quadslam_env.config import available_scenarios, load_yaml

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
        if kind == "evaluate" and policy != "dflqr":
            from agents.run_folder import run_config

            path = Path(policy)
            if not path.exists():
                raise SweepSpecError(
                    f"policy: got {policy!r}; allowed: 'dflqr', a run folder or a model .zip"
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
        from agents.hyperparams import (
            algorithms,
            default_config_path,
            load_hyperparams,
            resolve_settings,
        )
        from quadslam_env.config import deep_merge

        algo = str(point["algo"]).lower()
        if algo not in algorithms():
            raise SweepSpecError(f"algo: got {point['algo']!r}; allowed: {sorted(algorithms())}")
        env_id = point.get("env", "QuadSLAM-EKF-v0")
        config = point.get("config")
        source = Path(config).resolve() if config is not None else default_config_path(algo)
        for key in ("timesteps", "n_envs"):
            value = point.get(key)
            if value is not None and (not _is_int(value) or value < 1):
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

    from quadslam_env.config import load_scenario

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
