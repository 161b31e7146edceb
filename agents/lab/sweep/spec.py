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
              ``policy`` (a controller name, a run folder or a model ``.zip``) on ``env``
``train``     ``quadslam train --algo A --env E --seed S`` (the agent YAML entry, merged with
              ``hyperparams``; ``scenario``/``estimator``/``set`` go into its ``env_kwargs``),
              then ``episodes`` held-out evaluation episodes from seed ``eval_seed``
============  ===============================================================================

``seeds`` is a number N (seeds ``seed … seed + N − 1``, ``seed`` defaulting to 0, as
``--seed``/``--seeds``) or a list; ``cpus`` (default 1) is what Ray reserves for each job.
``seeds_per_job: K`` (run and evaluate; default 1) flies K consecutive seeds of a grid point in
one job, as K lanes of one vector env (``quadslam run --seed S --seeds K``: the same numbers,
less start-up per episode, fewer and longer jobs). ``trust_pickle: true`` (evaluate; default
false) is ``quadslam evaluate --trust-pickle``: a run folder without ``policy.npz`` or a bare
SB3 zip is read by unpickling it, which runs any code it holds. ``drag_feedforward: true`` and
``thrust_adaptation: true`` (evaluate; default false) are ``quadslam evaluate
--drag-feedforward`` / ``--thrust-adaptation``: only with a ``policy`` of the controllers that
take them (``lqi``, ``se3``), the drag feed-forward also only with
``observation.air_velocity: true``.

Everything is checked before any job starts (:func:`load_spec`): unknown keys or kinds,
empty grids, unknown scenarios, env ids, algorithms or estimators, bad ``set`` keys or values
and bad hyperparameters raise :class:`SweepSpecError`, one line naming the job block, the key,
the value and what is allowed. A spec of more than :data:`MAX_JOBS` jobs is refused from its
counts, before any seed list or grid point is made.
"""

from __future__ import annotations

import copy
import hashlib
import itertools
import json
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from agents.control.named import CONTROLLERS, OPTIONS
from agents.lab.sweep.resolve import Resolver, SweepSpecError, is_int

__all__ = ["KINDS", "Job", "SweepSpecError", "load_spec", "parse_spec", "shipped_specs"]

KINDS = ("run", "evaluate", "train")
#: The named controllers' options an evaluate block takes (``quadslam evaluate``'s flags).
CONTROLLER_KEYS = tuple(OPTIONS)
_COMMON = ("kind", "name", "scenario", "estimator", "seed", "seeds", "set", "cpus")
KIND_KEYS: dict[str, tuple[str, ...]] = {
    "run": (*_COMMON, "seeds_per_job", "plots"),
    "evaluate": (
        *_COMMON,
        "seeds_per_job",
        "policy",
        "env",
        "plots",
        "trust_pickle",
        *CONTROLLER_KEYS,
    ),
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
#: Keys of one value for the whole block (never an axis).
FIXED_KEYS = ("plots", "episodes", "eval_seed", "trust_pickle", *CONTROLLER_KEYS)
#: Keys whose list value is a grid axis (``set`` and ``hyperparams`` entries are too).
AXIS_KEYS = ("scenario", "estimator", "env", "algo", "policy", "config", "timesteps", "n_envs")
TOP_KEYS = ("description", "jobs")
#: Most jobs of one sweep (each is a Ray task, a folder and table rows; 10^8 seeds would
#: exhaust the memory while the grid is expanded).
MAX_JOBS = 100_000


@dataclass(frozen=True)
class Job:
    """One job of a sweep: a grid point of a job block and one seed.

    Attributes:
        job_id: Stable name from the job's content (its folder under ``OUT/jobs``).
        kind: ``run``, ``evaluate`` or ``train``.
        block: Index of the job block in the spec's ``jobs`` list.
        seeds: Episode seeds (run, evaluate: one lane each) or the one training seed (train).
        cpus: CPUs Ray reserves for the job.
        params: Plain-data arguments of :func:`agents.lab.sweep.jobs.execute_job`.
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
    """``configs/sweeps`` (the example specs; ``QUADSLAM_CONFIG_DIR`` overrides)."""
    from quadslam_env.config.files import config_dir

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
    from quadslam_env.config.files import (
        DuplicateKeyError,
        YamlLimitError,
        parse_yaml,
        read_text_file,
    )

    path = spec_path(spec)
    try:
        data = parse_yaml(read_text_file(path, "sweep spec"))
    except (DuplicateKeyError, YamlLimitError) as exc:
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
    validator = Resolver()
    for i, block in enumerate(blocks):
        budget = MAX_JOBS - len(jobs)
        for job in _expand_block(block, i, f"{where}: jobs[{i}]", validator, budget):
            if job.job_id in seen:
                raise SweepSpecError(
                    f"{where}: jobs[{i}] (seed {job.seed}): the same job as one of "
                    f"jobs[{seen[job.job_id]}]; allowed: each job once"
                )
            seen[job.job_id] = i
            jobs.append(job)
    return jobs


# ----------------------------------------------------------------------------- one block
def _expand_block(
    block: Any, index: int, where: str, validator: Resolver, budget: int = MAX_JOBS
) -> list[Job]:
    """Check one job block's keys and values and expand its grid (at most ``budget`` jobs:
    what :data:`MAX_JOBS` leaves after the blocks before)."""
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
            f"{where}.policy: missing; allowed: a controller ({', '.join(CONTROLLERS)}), a run "
            "folder or a model .zip"
        )
    if kind == "train" and "algo" not in block:
        raise SweepSpecError(f"{where}.algo: missing; allowed: ppo, sac, td3 or a2c")
    name = block.get("name", f"jobs[{index}]")
    if not isinstance(name, str) or not name.strip():
        raise SweepSpecError(f"{where}.name: got {name!r}; allowed: a non-empty string")
    per_job = block.get("seeds_per_job", 1)
    if not is_int(per_job) or per_job < 1:
        raise SweepSpecError(f"{where}.seeds_per_job: got {per_job!r}; allowed: a positive integer")
    n_seeds = _seed_count(block, where)
    cpus = block.get("cpus", 1)
    if isinstance(cpus, bool) or not isinstance(cpus, int | float) or not cpus > 0:
        raise SweepSpecError(f"{where}.cpus: got {cpus!r}; allowed: a positive number")
    fixed = {k: block[k] for k in FIXED_KEYS if k in block}
    _check_scalars(fixed, where)

    axes: list[tuple[str, list[Any]]] = []
    for key in AXIS_KEYS:
        if key in block:
            axes.append((key, _axis(block[key], f"{where}.{key}")))
    set_entries = _dotted(block.get("set", {}), f"{where}.set", min_parts=2)
    hp_entries = _dotted(block.get("hyperparams", {}), f"{where}.hyperparams", min_parts=1)
    axes += [(f"set:{k}", _axis(v, f"{where}.set.{k}")) for k, v in set_entries.items()]
    axes += [(f"hp:{k}", _axis(v, f"{where}.hyperparams.{k}")) for k, v in hp_entries.items()]
    points = math.prod(len(values) for _, values in axes)
    n_groups = -(-n_seeds // per_job)
    if points * n_groups > budget:
        before = MAX_JOBS - budget
        earlier = f" (after {before:,} in the blocks before)" if before else ""
        raise SweepSpecError(
            f"{where}: {points * n_groups:,} jobs ({points:,} grid point(s) × {n_groups:,} "
            f"seed group(s)){earlier}; allowed: at most {MAX_JOBS:,} jobs per sweep (fewer "
            "seeds or axis values, or more seeds_per_job)"
        )
    seeds = _seeds(block, where)
    groups = [seeds[i : i + per_job] for i in range(0, len(seeds), per_job)]

    jobs = []
    for values in itertools.product(*(vals for _, vals in axes)):
        point = dict(zip((key for key, _ in axes), values, strict=True))
        label = ", ".join(f"{k.split(':')[-1]}={v!r}" for k, v in point.items()) or "no axes"
        point_where = f"{where} ({label})"
        params, columns = validator.resolve(kind, point, fixed, point_where, min(per_job, n_seeds))
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


def _seed_count(block: dict[str, Any], where: str) -> int:
    """How many seeds :func:`_seeds` will list (a bad value is reported by it)."""
    seeds = block.get("seeds", 1)
    if isinstance(seeds, list):
        return len(seeds)
    return int(seeds) if is_int(seeds) and seeds >= 1 else 1


def _seeds(block: dict[str, Any], where: str) -> Sequence[int]:
    """``seeds`` (a count from ``seed``, or a list) as a sequence of seeds: a count as a
    ``range``, so that no list of them exists before the jobs' checks (their memory)."""
    seeds = block.get("seeds", 1)
    first = block.get("seed", 0)
    if not is_int(first) or first < 0:
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
            if not is_int(s) or s < 0:
                raise SweepSpecError(
                    f"{where}.seeds: got {s!r} in the list; allowed: integers >= 0"
                )
        if len(set(seeds)) != len(seeds):
            raise SweepSpecError(f"{where}.seeds: got {seeds!r}; allowed: each seed once")
        return [int(s) for s in seeds]
    if not is_int(seeds) or seeds < 1:
        raise SweepSpecError(
            f"{where}.seeds: got {seeds!r}; allowed: a positive number of seeds or a "
            "non-empty list of seeds"
        )
    return range(int(first), int(first) + int(seeds))


def _check_scalars(fixed: dict[str, Any], where: str) -> None:
    for key in ("plots", "trust_pickle", *CONTROLLER_KEYS):
        if key in fixed and not isinstance(fixed[key], bool):
            raise SweepSpecError(f"{where}.{key}: got {fixed[key]!r}; allowed: true or false")
    if "episodes" in fixed and (not is_int(fixed["episodes"]) or fixed["episodes"] < 0):
        raise SweepSpecError(
            f"{where}.episodes: got {fixed['episodes']!r}; allowed: an integer >= 0"
        )
    if "eval_seed" in fixed and (not is_int(fixed["eval_seed"]) or fixed["eval_seed"] < 0):
        raise SweepSpecError(
            f"{where}.eval_seed: got {fixed['eval_seed']!r}; allowed: an integer >= 0"
        )


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


def _job_id(kind: str, params: dict[str, Any], columns: dict[str, Any]) -> str:
    """``<kind>-<label>-s<seed>[+<n>]-<hash>``: readable, stable while the job is the same."""
    blob = json.dumps({"kind": kind, "params": params}, sort_keys=True, default=str)
    digest = hashlib.sha1(blob.encode()).hexdigest()[:10]
    label = str(columns.get("env") if kind == "train" else columns.get("scenario"))
    label = re.sub(r"[^A-Za-z0-9_.-]+", "_", label)[:40]
    seeds = params.get("seeds") or [params["seed"]]
    more = f"+{len(seeds) - 1}" if len(seeds) > 1 else ""
    return f"{kind}-{label}-s{seeds[0]}{more}-{digest}"
