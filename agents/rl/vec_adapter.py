"""``QuadSLAMVecEnv``: a stable-baselines3 ``VecEnv`` over the batched simulation core.

SB3 has no adapter for Gymnasium vector envs, so (as RotorPy does) this class subclasses
:class:`stable_baselines3.common.vec_env.VecEnv` directly and drives the
:class:`~quadslam_env.core.SimCore` of a native ``QuadSLAMVectorEnv`` with SB3's conventions:

- **same-step autoreset**: when lane i ends, ``step`` returns its *reset* observation,
  ``infos[i]["terminal_observation"]`` holds the final one and ``reset_infos[i]`` the reset info;
- ``dones = terminated | truncated``, ``infos[i]["TimeLimit.truncated"] = truncated and not
  terminated`` (every step, as ``DummyVecEnv``); rewards float32;
- ``reset()`` returns the observations only and fills ``reset_infos``; seeds set by ``seed(s)``
  (or the constructor's ``seed``) apply at the next ``reset``: lane i gets ``s + i``.

Lane i's generator is ``gymnasium.utils.seeding.np_random(s + i)[0]`` as in the native vector
env, so lane i equals ``DummyVecEnv`` over the scalar env seeded ``s + i``, through autoresets.

**Info cost**: each lane's info dict is built from the core's (B,) arrays with
:func:`quadslam_env.env.lane_info` (the scalar env's keys). Measured at B = 64 with the Oracle:
13.0 µs per lane and step with every key, 10.7 µs with ``info_keys=()``, i.e. ~2.3 µs (≈ 20 %
of the Oracle's step; less for the filters). ``info_keys`` limits the keys copied (``()``
copies none) on the lanes that did not end; a lane that ends gets every key (its episode
summaries and ``termination_reason``). ``TimeLimit.truncated`` and ``terminal_observation`` are
always present, as are ``dflqr_action``/``residual`` with the residual wrapper unless excluded.
Every numeric term of every lane is also in ``step_info`` (the core's (B,) arrays, NaN where
a term does not apply), which costs nothing extra.

**Workers** (``n_workers > 1``): the lanes are split into contiguous shares, each simulated by a
worker process ("forkserver" where available, else "spawn") holding a core of its lanes and
talking over ``multiprocessing`` pipes; lanes keep their global seed offsets, so the results are
those of ``n_workers=1``. Each worker builds the info dicts of its own lanes, so a lane's dict
holds exactly the keys its core reported for it (episode summaries only when it ended). The
workers' ``step_info`` arrays are merged over the union of their keys: a key a worker lacked
(the ``episode_*`` summaries appear only in a core where some lane ended) is NaN on its lanes
(``""`` for string terms), as in one core of all lanes. Both start methods re-import the main
module in each worker, so a script creating the env with ``n_workers > 1`` must do so under an
``if __name__ == "__main__":`` guard; without it the workers die at startup and the
constructor raises a ``RuntimeError`` that says so.
"""

from __future__ import annotations

import multiprocessing as mp
from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.vec_env.base_vec_env import (
    VecEnv,
    VecEnvIndices,
    VecEnvObs,
    VecEnvStepReturn,
)

from agents.rl.lane_share import ACTOR_KEY, PRIVILEGED_KEY, InProcess, unwrap, worker
from agents.rl.wrappers import ResidualDFLQRWrapper, parse_wrapper_spec
from quadslam_env.episode.actions import validate_actions
from quadslam_env.schema import ConfigError


class QuadSLAMVecEnv(VecEnv):
    """stable-baselines3 ``VecEnv`` of B lanes of the batched QuadSLAM core (module docstring).

    Args:
        env_id: Registered id, e.g. ``"QuadSLAM-EKF-v0"``.
        num_envs: Number of lanes B ≥ 1.
        seed: Seed of the first ``reset`` (lane i gets ``seed + i``); ``None``: random.
        n_workers: Processes to split the lanes over (1: simulate in this process).
        wrapper: A config ``wrapper`` entry: ``None`` or ``"residual_dflqr"`` (or
            ``{"name": "residual_dflqr", "scale": ...}``): actions are residuals on DF-LQR, as
            :class:`agents.rl.wrappers.ResidualDFLQRWrapper` on each lane.
        info_keys: Keys of the scalar env's info to copy per lane (``None``: all; cost above).
        stagger: Cut the first episode of lane i after ``ceil(max_steps (i+1) / B)`` steps
            (``done`` with ``TimeLimit.truncated``), so the lanes' episodes are spread over the
            trajectory instead of running in lockstep (training: otherwise every rollout batch
            covers one short stretch of the reference). The last lane's first episode runs
            its full length; later episodes of every lane are not cut (nor is an episode
            that ended before its cut). The cut is applied after each ``reset()``. A cut
            ends the episode like the time limit: the lane's info has its ``episode_*``
            summaries (in ``step_info`` too), ``termination_reason: ""``,
            ``TimeLimit.truncated: True``, ``terminal_observation`` and ``stagger_cut:
            True``; ``VecMonitor`` records it as an episode (``info["episode"]``).
        privileged: Observations are dicts ``{"obs": (B, obs_dim) the env's observation,
            "privileged": (B, obs_dim) the same observation built from the true state}``
            (asymmetric actor-critic training, :mod:`agents.rl.asymmetric`), and so are
            ``terminal_observation`` entries (each (obs_dim,)); ``observation_space`` is the
            matching ``Dict``.
        **env_kwargs: Keyword arguments of ``gymnasium.make(env_id, ...)``.

    Raises:
        ConfigError: Bad ``num_envs``/``n_workers`` or env kwargs.
        RuntimeError: A worker process died during startup, typically because the calling
            script creates the env outside an ``if __name__ == "__main__":`` guard.
        ActionError: (from ``step``) actions not a finite (B, 4) array; names the lanes.
    """

    def __init__(
        self,
        env_id: str,
        num_envs: int,
        seed: int | None = None,
        n_workers: int = 1,
        wrapper: Any = None,
        info_keys: Sequence[str] | None = None,
        stagger: bool = False,
        privileged: bool = False,
        **env_kwargs: Any,
    ) -> None:
        for name, value in (("num_envs", num_envs), ("n_workers", n_workers)):
            if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
                raise ConfigError(f"{name}: got {value!r}; allowed: an integer >= 1")
        if n_workers > num_envs:
            raise ConfigError(f"n_workers: got {n_workers}; allowed: 1..num_envs ({num_envs})")
        keys = None if info_keys is None else tuple(info_keys)
        splits = np.array_split(np.arange(num_envs), n_workers)
        self._slices = [slice(int(s[0]), int(s[-1]) + 1) for s in splits]
        self._shares: list[Any] = []
        self._processes: list[Any] = []
        self._residual = parse_wrapper_spec(wrapper) is not None
        for sl in self._slices:
            cut = (sl.start, int(num_envs)) if stagger else None
            args = (env_id, sl.stop - sl.start, dict(env_kwargs), wrapper, keys, cut, privileged)
            self._shares.append(InProcess(*args) if n_workers == 1 else self._spawn(args))
        if n_workers > 1:
            try:
                for index in range(n_workers):
                    unwrap(self._startup_reply(index))
            except Exception:
                for share, process in zip(self._shares, self._processes, strict=True):
                    process.terminate()
                    process.join(timeout=5.0)
                    share.close()
                raise
        self.closed = False
        single_obs, single_act = (
            self._get_attr_one("observation_space"),
            self._get_attr_one("action_space"),
        )
        if privileged:
            single_obs = gym.spaces.Dict({ACTOR_KEY: single_obs, PRIVILEGED_KEY: single_obs})
        super().__init__(int(num_envs), single_obs, single_act)
        if seed is not None:
            self._seeds = [int(seed) + i for i in range(self.num_envs)]
        self._actions: np.ndarray | None = None
        # The core's info arrays of the last step, {key: (B,) float} (NaN: does not apply):
        # every numeric term of every lane without building per-lane dicts (the batched
        # EstimationMetricsCallback reads them).
        self.step_info: dict[str, np.ndarray] = {}

    def _spawn(self, args: tuple) -> Any:
        ctx: Any
        self._start_method = "spawn"
        if "forkserver" in mp.get_all_start_methods():
            self._start_method = "forkserver"
            ctx = mp.get_context("forkserver")
            ctx.set_forkserver_preload(["agents.rl.lane_share"])  # workers fork with it imported
        else:
            ctx = mp.get_context("spawn")
        remote, work_remote = ctx.Pipe()
        process = ctx.Process(target=worker, args=(work_remote, remote, args), daemon=True)
        process.start()
        work_remote.close()
        self._processes.append(process)
        return remote

    def _startup_reply(self, index: int) -> tuple[str, Any]:
        """Worker ``index``'s first message (its share built, or the error it raised).

        Raises:
            RuntimeError: The worker's pipe broke before it replied (the process died during
                startup); chains the pipe's error.
        """
        try:
            return self._shares[index].recv()
        except (EOFError, OSError) as exc:
            process = self._processes[index]
            process.join(timeout=5.0)
            raise RuntimeError(
                f"QuadSLAMVecEnv: worker process {index} died during startup (exit code "
                f"{process.exitcode}) before building its lanes. The workers are started "
                f"with the {self._start_method!r} start method, "
                "which re-imports your main module in each worker: put the code that creates "
                'QuadSLAMVecEnv(..., n_workers > 1) under an `if __name__ == "__main__":` '
                "guard (or use n_workers=1). The worker's own traceback, if any, is on "
                "stderr above."
            ) from exc

    def _ask(self, messages: Sequence[tuple[str, Any] | None]) -> list[Any]:
        """Send one message per share (``None``: skip it) and gather the replies."""
        for share, msg in zip(self._shares, messages, strict=True):
            if msg is not None:
                share.send(msg)
        replies = [
            share.recv() if msg is not None else ("ok", None)
            for share, msg in zip(self._shares, messages, strict=True)
        ]
        return [unwrap(r) for r in replies]

    def _get_attr_one(self, name: str) -> Any:
        return self._ask([("get_attr", (name, [0]))] + [None] * (len(self._shares) - 1))[0][0]

    def _local(self, indices: VecEnvIndices) -> list[list[int]]:
        """Global lane indices → local lane indices of each share."""
        wanted = list(self._get_indices(indices))
        for i in wanted:
            if not 0 <= i < self.num_envs:
                raise IndexError(f"lane index {i} out of range 0..{self.num_envs - 1}")
        return [[i - sl.start for i in wanted if sl.start <= i < sl.stop] for sl in self._slices]

    # ------------------------------------------------------------------ VecEnv API
    def reset(self) -> VecEnvObs:
        """Reset every lane with the pending seeds/options; fills ``reset_infos``.

        Returns:
            (B, obs_dim) float32 observations.
        """
        replies = self._ask(
            [("reset", (self._seeds[sl], self._options[sl])) for sl in self._slices]
        )
        self.reset_infos = [info for _, infos in replies for info in infos]
        self._reset_seeds()
        self._reset_options()
        return _concat([obs for obs, _ in replies])

    def step_async(self, actions: np.ndarray) -> None:
        """Check ``actions`` (B, 4) and send each share its rows.

        Raises:
            ActionError: Not a finite (B, 4) array (naming the lanes); no lane is stepped.
        """
        dim = int(np.prod(self.action_space.shape or (4,)))
        checked = validate_actions(actions, self.num_envs, dim)
        act = np.asarray(actions, dtype=np.float32) if self._residual else checked
        for share, sl in zip(self._shares, self._slices, strict=True):
            share.send(("step", act[sl]))
        self._actions = act

    def step_wait(self) -> VecEnvStepReturn:
        """Gather the step results: ``(obs (B, obs_dim), rewards (B,), dones (B,), infos)``."""
        replies = [unwrap(share.recv()) for share in self._shares]
        infos: list[dict[str, Any]] = []
        for sl, reply in zip(self._slices, replies, strict=True):
            infos.extend(reply[3])
            for lane, info in reply[4].items():
                self.reset_infos[sl.start + lane] = info
        obs = _concat([r[0] for r in replies])
        rewards, dones = (np.concatenate([r[k] for r in replies]) for k in (1, 2))
        self.step_info = _merge_arrays([r[5] for r in replies], self._slices)
        return obs, rewards, dones, infos

    def close(self) -> None:
        """Close every share and join the workers."""
        if self.closed:
            return
        self._ask([("close", None)] * len(self._shares))
        for process in self._processes:
            process.join()
        self.closed = True

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        """Per-lane values (``t``, ``steps``, ``true_state``, ``landmarks``, ``landmark_ids``,
        ``last_estimate``), the single-env ``observation_space``/``action_space``/``spec``, or
        the attribute every lane shares (``render_mode``, ``scenario``, ``dt``, ...)."""
        local = self._local(indices)
        replies = self._ask([("get_attr", (attr_name, ls)) if ls else None for ls in local])
        return [v for r, ls in zip(replies, local, strict=True) if ls for v in r]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        """Set an attribute of the env every lane shares (so ``indices`` must be all lanes).

        Raises:
            ValueError: ``indices`` names only some lanes.
        """
        if sorted(self._get_indices(indices)) != list(range(self.num_envs)):
            raise ValueError(
                f"set_attr({attr_name!r}): the lanes share one env, so the attribute is set for "
                "all of them; pass indices=None"
            )
        self._ask([("set_attr", (attr_name, value))] * len(self._shares))

    def env_method(
        self,
        method_name: str,
        *method_args: Any,
        indices: VecEnvIndices = None,
        **method_kwargs: Any,
    ) -> list[Any]:
        """Call ``method_name`` once on the vector env of each share holding some of
        ``indices``; its result is repeated for each of those lanes."""
        local = self._local(indices)
        msg = ("call", (method_name, method_args, method_kwargs))
        replies = self._ask([msg if ls else None for ls in local])
        return [r for r, ls in zip(replies, local, strict=True) for _ in ls]

    def env_is_wrapped(
        self, wrapper_class: type[gym.Wrapper], indices: VecEnvIndices = None
    ) -> list[bool]:
        """True for the residual wrapper's classes when ``wrapper`` is set, else False."""
        wrapped = self._residual and issubclass(ResidualDFLQRWrapper, wrapper_class)
        return [wrapped for _ in self._get_indices(indices)]

    def get_images(self) -> Sequence[np.ndarray | None]:
        """Lane 0's RGB frame (H, W, 3), then ``None`` for the other lanes."""
        frame = self._ask([("call", ("render", (), {}))] + [None] * (len(self._shares) - 1))[0]
        return [frame] + [None] * (self.num_envs - 1)

    def render(self, mode: str | None = None) -> np.ndarray | None:
        """Lane 0's RGB frame (H, W, 3), or ``None`` without ``render_mode="rgb_array"``."""
        if (mode or self.render_mode) != "rgb_array" or self.render_mode != "rgb_array":
            return None
        return self.get_images()[0]


def _merge_arrays(parts: list[dict[str, Any]], slices: list[slice]) -> dict[str, np.ndarray]:
    """Merge the shares' per-lane info arrays over the union of their keys.

    A share that lacks a key (the ``episode_*`` summaries exist only in a core where some lane
    ended this step) contributes "missing" on its lanes: NaN for numeric terms (the result is
    then floating point: integer/bool terms become float64), ``""`` for string terms (an object
    array). This is what one core of all the lanes would report.

    Args:
        parts: Each share's ``{key: (k_w,) array or list of k_w values}``.
        slices: Each share's global lanes (contiguous, in order, covering 0..B-1).

    Returns:
        ``{key: (B,) array}`` in first-seen key order; a single share's dict unchanged.
    """
    if len(parts) == 1:
        return parts[0]
    num_lanes = slices[-1].stop
    merged: dict[str, np.ndarray] = {}
    for key in dict.fromkeys(key for part in parts for key in part):
        values = [None if key not in part else np.asarray(part[key]) for part in parts]
        present = [v for v in values if v is not None]
        if len(present) == len(parts):
            merged[key] = np.concatenate(present)
            continue
        if any(v.dtype.kind in "OUS" for v in present):  # strings, e.g. termination_reason
            out = np.full(num_lanes, "", dtype=object)
        else:
            dtype = np.result_type(*present)
            if not np.issubdtype(dtype, np.inexact):
                dtype = np.dtype(np.float64)
            out = np.full(num_lanes, np.nan, dtype=dtype)
        for sl, value in zip(slices, values, strict=True):
            if value is not None:
                out[sl] = value
        merged[key] = out
    return merged


def _concat(parts: list[Any]) -> Any:
    """Concatenate the shares' observations (arrays, or dicts of arrays) along the lanes."""
    if len(parts) == 1:
        return parts[0]
    if isinstance(parts[0], dict):
        return {key: np.concatenate([p[key] for p in parts]) for key in parts[0]}
    return np.concatenate(parts)
