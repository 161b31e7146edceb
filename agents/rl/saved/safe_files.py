"""A trained policy's files that load without running code: its weights and its
``VecNormalize`` statistics as plain arrays (docs/design.md §6).

SB3 saves a model as ``model.zip``, whose ``data`` member holds pickled objects (the spaces,
the schedules), and ``VecNormalize`` as a pickle (``vecnormalize.pkl``): reading either runs
whatever code the file names. ``quadslam train`` writes, beside each of them, a NumPy ``.npz``
archive that :func:`numpy.load` reads with ``allow_pickle=False`` (numbers, strings and a
JSON header; an object array is refused):

- the policy (``policy.npz``, :func:`write_policy`): every tensor of the policy's
  ``state_dict`` (``param/<name>``), the observation and action spaces it was built on (their
  bounds as arrays, ``space/<observation|action>[/<key>]/<low|high>``) and a header naming the
  algorithm, the policy class and the step count;
- the statistics (``vecnormalize.npz``, :func:`write_normalization`): the running mean,
  variance and count of the observations (per key of a dict observation) and of the returns,
  the clip values, ``gamma``, ``epsilon`` and the ``norm_obs``/``norm_reward`` flags.

:mod:`agents.rl.loading` rebuilds the SB3 model from the run's ``config.yaml`` and these files.
"""

from __future__ import annotations

import json
import math
import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from agents.rl import sbx_backend
from agents.rl.saved.run_folder import safe_paths, vecnormalize_path

POLICY_FORMAT = "quadslam-policy"
STATS_FORMAT = "quadslam-vecnormalize"
VERSION = 1
#: The most array data one file may hold once unpacked (a policy of this project is a few
#: hundred kB): a crafted archive that would unpack to more is refused before it is read.
MAX_ARRAY_BYTES = 256 * 2**20


class SafeFileError(ValueError):
    """A policy or statistics file that is not one :mod:`agents.rl.saved.safe_files` writes."""


# ---------------------------------------------------------------------------- reading and writing
def _write_arrays(path: Path, meta: dict[str, Any], arrays: dict[str, np.ndarray]) -> None:
    """``arrays`` and the JSON header ``meta`` as an uncompressed ``.npz`` at ``path`` (an
    object array, which NumPy would pickle, is refused)."""
    savez: Callable[..., None] = np.savez
    with open(path, "wb") as fh:
        savez(fh, allow_pickle=False, meta=np.array(json.dumps(meta)), **arrays)


def _read_arrays(path: Path, what: str, fmt: str) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """The header and arrays of a file :func:`_write_arrays` wrote, never unpickling.

    Raises:
        SafeFileError: Unreadable, too large, an object array, or another format.
    """
    try:
        with zipfile.ZipFile(path) as archive:
            size = sum(info.file_size for info in archive.infolist())
    except (OSError, zipfile.BadZipFile) as exc:
        raise SafeFileError(f"{path}: cannot read the {what} ({exc})") from None
    if size > MAX_ARRAY_BYTES:
        raise SafeFileError(
            f"{path}: unpacks to {size:,} bytes; allowed: at most {MAX_ARRAY_BYTES:,} for the "
            f"{what}"
        )
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {name: data[name] for name in data.files}
        meta = json.loads(str(arrays.pop("meta")[()]))
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
        reason = " ".join(str(exc).split()) or type(exc).__name__
        raise SafeFileError(f"{path}: cannot read the {what} ({reason})") from None
    if not isinstance(meta, dict) or meta.get("format") != fmt or meta.get("version") != VERSION:
        raise SafeFileError(
            f"{path}: not a {what} file written by quadslam (format {fmt!r}, version {VERSION})"
        )
    return meta, arrays


def _array(arrays: dict[str, np.ndarray], name: str, path: Path) -> np.ndarray:
    """``arrays[name]``, a real numeric array."""
    value = arrays.get(name)
    if value is None or value.dtype.kind not in "biuf":
        got = "missing" if value is None else f"of dtype {value.dtype}"
        raise SafeFileError(f"{path}: array {name!r} {got}; allowed: a numeric array")
    return value


# ---------------------------------------------------------------------------- spaces
def _space_entries(name: str, space: gym.Space) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """The header entry and bound arrays describing a ``Box`` or a ``Dict`` of them."""
    if isinstance(space, gym.spaces.Box):
        arrays = {f"space/{name}/low": space.low, f"space/{name}/high": space.high}
        return {"type": "box", "dtype": str(space.dtype)}, arrays
    if isinstance(space, gym.spaces.Dict):
        spec: dict[str, Any] = {"type": "dict", "spaces": {}}
        arrays = {}
        for key, sub in space.spaces.items():
            spec["spaces"][key], more = _space_entries(f"{name}/{key}", sub)
            arrays.update(more)
        return spec, arrays
    raise SafeFileError(f"{name} space {space}: allowed: a Box or a Dict of Box spaces")


def _space(name: str, spec: Any, arrays: dict[str, np.ndarray], path: Path) -> gym.Space:
    """The space :func:`_space_entries` described."""
    kind = spec.get("type") if isinstance(spec, dict) else None
    if kind == "box":
        low, high = (
            _array(arrays, f"space/{name}/low", path),
            _array(arrays, f"space/{name}/high", path),
        )
        try:
            return gym.spaces.Box(low, high, dtype=np.dtype(spec.get("dtype")))
        except (TypeError, ValueError, AssertionError) as exc:
            raise SafeFileError(f"{path}: the {name} space is not a valid Box ({exc})") from None
    if kind == "dict" and isinstance(spec.get("spaces"), dict):
        return gym.spaces.Dict(
            {
                str(key): _space(f"{name}/{key}", sub, arrays, path)
                for key, sub in spec["spaces"].items()
            }
        )
    raise SafeFileError(f"{path}: the {name} space: allowed: a Box or a Dict of Box spaces")


# ---------------------------------------------------------------------------- the policy
@dataclass(frozen=True)
class PolicyFile:
    """What a policy file holds.

    Attributes:
        algo: The algorithm (``ppo``, ``sac``, ``td3``, ``a2c``).
        policy_class: The class name of the SB3 policy (``ActorCriticPolicy``, ``SACPolicy``).
        num_timesteps: Environment steps the model had taken when it was saved.
        observation_space: The space the policy was built on (a ``Dict`` for the privileged
            critic).
        action_space: Its action space.
        tensors: The policy's ``state_dict`` as arrays, by parameter name.
    """

    algo: str
    policy_class: str
    num_timesteps: int
    observation_space: gym.Space
    action_space: gym.Space
    tensors: dict[str, np.ndarray]


def write_policy(path: Path, model: Any) -> None:
    """Write the weights and spaces of an SB3 ``model``'s policy to ``path`` (``.npz``).

    An sbx model's flax parameters are written in the layout of SB3's torch policy
    (:func:`agents.rl.sbx_backend.torch_layout`), so that the file reads as an SB3 run's.
    """
    obs_spec, obs_arrays = _space_entries("observation", model.observation_space)
    act_spec, act_arrays = _space_entries("action", model.action_space)
    if sbx_backend.is_sbx_model(model):
        policy_class, state = sbx_backend.TORCH_POLICY_CLASS, sbx_backend.torch_layout(model)
    else:
        policy_class = type(model.policy).__name__
        state = {k: v.detach().cpu().numpy() for k, v in model.policy.state_dict().items()}
    meta = {
        "format": POLICY_FORMAT,
        "version": VERSION,
        "algo": type(model).__name__.lower(),
        "policy_class": policy_class,
        "num_timesteps": int(model.num_timesteps),
        "observation_space": obs_spec,
        "action_space": act_spec,
    }
    tensors = {f"param/{name}": value for name, value in state.items()}
    _write_arrays(path, meta, {**obs_arrays, **act_arrays, **tensors})


def read_policy(path: Path) -> PolicyFile:
    """Read a policy file (:func:`write_policy`) without unpickling anything.

    Raises:
        SafeFileError: Unreadable, or not a policy file of this format (one line).
    """
    meta, arrays = _read_arrays(path, "policy weights", POLICY_FORMAT)
    tensors = {
        name[len("param/") :]: _array(arrays, name, path)
        for name in arrays
        if name.startswith("param/")
    }
    if not tensors:
        raise SafeFileError(f"{path}: no policy weights (param/<name> arrays) in the file")
    steps = meta.get("num_timesteps")
    names = (meta.get("algo"), meta.get("policy_class"))
    if not all(isinstance(n, str) for n in names) or not isinstance(steps, int):
        raise SafeFileError(f"{path}: its header lacks the algorithm, policy class or step count")
    return PolicyFile(
        algo=str(names[0]),
        policy_class=str(names[1]),
        num_timesteps=steps,
        observation_space=_space("observation", meta.get("observation_space"), arrays, path),
        action_space=_space("action", meta.get("action_space"), arrays, path),
        tensors=tensors,
    )


def save_files(
    model: Any, zip_path: Path, run_dir: Path, normalized: bool
) -> list[tuple[Path, Callable[[Path], Any]]]:
    """What a saved model of a run is made of, as ``(path, produce)`` pairs for
    :func:`agents.io.outputs.atomic_produce_all`: the statistics (``VecNormalize``'s pickle
    and the arrays) when ``normalized``, the policy's arrays, and SB3's zip last (a model whose
    zip exists is complete); the names are :func:`agents.rl.saved.run_folder.safe_paths`'."""
    weights, stats = safe_paths(zip_path, run_dir)
    items: list[tuple[Path, Callable[[Path], Any]]] = []
    vec = model.get_vec_normalize_env() if normalized else None
    if vec is not None:
        norm = Normalization.from_vec_normalize(vec)
        items.append((vecnormalize_path(zip_path, run_dir), lambda tmp: vec.save(str(tmp))))
        items.append((stats, lambda tmp: write_normalization(tmp, norm)))
    items.append((weights, lambda tmp: write_policy(tmp, model)))
    items.append((zip_path, lambda tmp: model.save(tmp)))
    return items


# ---------------------------------------------------------------------------- the statistics
@dataclass(frozen=True)
class RunningStats:
    """The running mean, variance and sample count of one stream (SB3's ``RunningMeanStd``)."""

    mean: np.ndarray
    var: np.ndarray
    count: float


@dataclass(frozen=True)
class Normalization:
    """A ``VecNormalize``'s statistics and settings, as plain arrays and numbers.

    Attributes:
        obs_rms: The observations' statistics: one :class:`RunningStats`, by key for a dict
            observation, ``None`` when observations are not normalised.
        ret_rms: The discounted returns' statistics.
        norm_obs: Observations are normalised.
        norm_reward: Rewards were normalised in training (never at evaluation).
        clip_obs: Normalised observations are clipped to ±this.
        clip_reward: Normalised rewards were clipped to ±this.
        gamma: The discount of the return statistics.
        epsilon: Added to the variance before its square root.
        norm_obs_keys: The normalised keys of a dict observation (``None`` otherwise).
    """

    obs_rms: RunningStats | dict[str, RunningStats] | None
    ret_rms: RunningStats
    norm_obs: bool
    norm_reward: bool
    clip_obs: float
    clip_reward: float
    gamma: float
    epsilon: float
    norm_obs_keys: tuple[str, ...] | None = None

    @classmethod
    def from_vec_normalize(cls, vec_normalize: Any) -> Normalization:
        """The statistics of an SB3 ``VecNormalize`` (copies of its arrays)."""

        def stats(rms: Any) -> RunningStats:
            return RunningStats(np.array(rms.mean), np.array(rms.var), float(rms.count))

        rms = getattr(vec_normalize, "obs_rms", None)  # SB3 makes none without norm_obs
        obs: RunningStats | dict[str, RunningStats] | None = None
        keys = None
        if isinstance(rms, dict):
            obs = {str(k): stats(v) for k, v in rms.items()}
            keys = tuple(str(k) for k in (vec_normalize.norm_obs_keys or rms))
        elif rms is not None:
            obs = stats(rms)
        return cls(
            obs_rms=obs,
            ret_rms=stats(vec_normalize.ret_rms),
            norm_obs=bool(vec_normalize.norm_obs),
            norm_reward=bool(vec_normalize.norm_reward),
            clip_obs=float(vec_normalize.clip_obs),
            clip_reward=float(vec_normalize.clip_reward),
            gamma=float(vec_normalize.gamma),
            epsilon=float(vec_normalize.epsilon),
            norm_obs_keys=keys,
        )

    def obs_stats(self, key: str | None = None) -> RunningStats | None:
        """The statistics applied to observations (to entry ``key`` of a dict observation);
        ``None`` when they are left as they are."""
        if not self.norm_obs or self.obs_rms is None:
            return None
        if isinstance(self.obs_rms, dict):
            keys = self.norm_obs_keys if self.norm_obs_keys is not None else tuple(self.obs_rms)
            return self.obs_rms[key] if key is not None and key in keys else None
        return self.obs_rms

    def normalize_obs(self, obs: np.ndarray, key: str | None = None) -> np.ndarray:
        """Observations (n, dim) normalised as ``VecNormalize.normalize_obs`` does (float32):
        ``clip((obs − mean) / sqrt(var + epsilon), ±clip_obs)``; entry ``key`` of a dict
        observation."""
        stats = self.obs_stats(key)
        if stats is None:
            return obs
        scaled = (obs - stats.mean) / np.sqrt(stats.var + self.epsilon)
        return np.clip(scaled, -self.clip_obs, self.clip_obs).astype(np.float32)


def write_normalization(path: Path, norm: Normalization) -> None:
    """Write a :class:`Normalization` to ``path`` (``.npz``)."""
    arrays: dict[str, np.ndarray] = {}

    def put(prefix: str, stats: RunningStats) -> None:
        arrays[f"{prefix}/mean"] = np.asarray(stats.mean, dtype=np.float64)
        arrays[f"{prefix}/var"] = np.asarray(stats.var, dtype=np.float64)
        arrays[f"{prefix}/count"] = np.asarray(stats.count, dtype=np.float64)

    obs_keys: list[str] | None = None
    if isinstance(norm.obs_rms, dict):
        obs_keys = list(norm.obs_rms)
        for key, stats in norm.obs_rms.items():
            put(f"obs/{key}", stats)
    elif norm.obs_rms is not None:
        put("obs", norm.obs_rms)
    put("ret", norm.ret_rms)
    meta = {
        "format": STATS_FORMAT,
        "version": VERSION,
        "obs": "none" if norm.obs_rms is None else ("dict" if obs_keys is not None else "box"),
        "obs_keys": obs_keys,
        "norm_obs_keys": None if norm.norm_obs_keys is None else list(norm.norm_obs_keys),
        **{k: getattr(norm, k) for k in ("norm_obs", "norm_reward")},
        **{k: getattr(norm, k) for k in ("clip_obs", "clip_reward", "gamma", "epsilon")},
    }
    _write_arrays(path, meta, arrays)


def _stats(arrays: dict[str, np.ndarray], prefix: str, path: Path) -> RunningStats:
    mean, var = _array(arrays, f"{prefix}/mean", path), _array(arrays, f"{prefix}/var", path)
    count = _array(arrays, f"{prefix}/count", path)
    ok = mean.shape == var.shape and count.shape == () and float(count) > 0
    if not ok or not (np.isfinite(mean).all() and np.isfinite(var).all() and (var >= 0).all()):
        raise SafeFileError(
            f"{path}: {prefix} statistics: allowed: finite mean and variance of one shape, "
            "the variance >= 0, a positive count"
        )
    return RunningStats(mean.astype(np.float64), var.astype(np.float64), float(count))


def read_normalization(path: Path) -> Normalization:
    """Read a statistics file (:func:`write_normalization`) without unpickling anything.

    Raises:
        SafeFileError: Unreadable, or not a statistics file of this format (one line).
    """
    meta, arrays = _read_arrays(path, "VecNormalize statistics", STATS_FORMAT)
    numbers = {}
    for key in ("clip_obs", "clip_reward", "gamma", "epsilon"):
        value = meta.get(key)
        if (
            isinstance(value, bool)
            or not isinstance(value, int | float)
            or not math.isfinite(value)
        ):
            raise SafeFileError(f"{path}: {key}: got {value!r}; allowed: a finite number")
        numbers[key] = float(value)
    flags = {key: meta.get(key) for key in ("norm_obs", "norm_reward")}
    if not all(isinstance(v, bool) for v in flags.values()):
        raise SafeFileError(f"{path}: norm_obs and norm_reward: allowed: true or false")
    keys, norm_keys = meta.get("obs_keys"), meta.get("norm_obs_keys")
    obs: RunningStats | dict[str, RunningStats] | None = None
    if meta.get("obs") == "box":
        obs = _stats(arrays, "obs", path)
    elif meta.get("obs") == "dict" and isinstance(keys, list):
        obs = {str(k): _stats(arrays, f"obs/{k}", path) for k in keys}
    elif meta.get("obs") != "none":
        raise SafeFileError(f"{path}: obs: allowed: 'box', 'dict' with obs_keys, or 'none'")
    if norm_keys is not None and not (
        isinstance(norm_keys, list) and isinstance(obs, dict) and set(norm_keys) <= set(obs)
    ):
        raise SafeFileError(f"{path}: norm_obs_keys: allowed: keys of the dict statistics")
    return Normalization(
        obs_rms=obs,
        ret_rms=_stats(arrays, "ret", path),
        norm_obs=bool(flags["norm_obs"]),
        norm_reward=bool(flags["norm_reward"]),
        norm_obs_keys=None if norm_keys is None else tuple(str(k) for k in norm_keys),
        **numbers,
    )
