"""The worker side of :class:`agents.rl.vec_adapter.QuadSLAMVecEnv`: a share of the lanes.

:class:`LaneShare` drives the :class:`~quadslam_env.core.SimCore` of a native
``QuadSLAMVectorEnv`` with stable-baselines3's same-step autoreset and builds the per-lane info
dicts. It runs in the caller's process (``n_workers=1``) or in a worker process answering
messages over a ``multiprocessing`` pipe (:func:`worker`). This module does not import
stable-baselines3 (nor torch), so workers start quickly.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import replace
from typing import Any

import gymnasium as gym
import numpy as np

from agents.rl.wrappers import ResidualDFLQR, parse_wrapper_spec
from quadslam_env.env import lane_info
from quadslam_env.episode.reset_options import parse_reset_options
from quadslam_env.types import TEXT_INFO_KEYS
from quadslam_env.vector_env import QuadSLAMVectorEnv

# Keys of the dict observation with privileged=True (agents.rl.asymmetric reads them).
ACTOR_KEY = "obs"
PRIVILEGED_KEY = "privileged"

STAGGER_CUT_KEY = "stagger_cut"
"""Info key set (``True``) on the step where a staggered first episode was cut short."""
NO_CUT = np.iinfo(np.int64).max
"""The step count of a lane whose episode is not cut."""

# Attributes that differ per lane, read from the core instead of the shared vector env.
_LANE_ATTRS = {
    "t": lambda core, i: float(core.t[i]),
    "steps": lambda core, i: int(core.steps[i]),
    "true_state": lambda core, i: core.vehicle.state[i].copy(),
    "landmarks": lambda core, i: core.landmarks[i, : core.n_landmarks[i]].copy(),
    "landmark_ids": lambda core, i: np.arange(core.n_landmarks[i]),
    "last_estimate": lambda core, i: core.estimator.lane_estimate(i),
}


class LaneShare:
    """A contiguous share of the lanes: one core driven with SB3's same-step autoreset.

    Args:
        env_id: Registered id.
        num_lanes: k, lanes in this share.
        env_kwargs: Keyword arguments of ``gymnasium.make(env_id, ...)``.
        wrapper: A config ``wrapper`` entry (``None`` or ``"residual_dflqr"``/a mapping).
        info_keys: Info keys to copy per lane (``None``: all); lanes that end get every key.
        stagger: ``(g0, n)``: this share's lanes are lanes ``g0, g0+1, …`` of ``n``, and the
            first episode of lane g is cut (truncated) after ``ceil(max_steps (g+1) / n)``
            steps, so the lanes' episodes are spread over the trajectory instead of running
            in lockstep (``None``: no cut). A cut ends the episode like the time limit: its
            info has the ``episode_*`` summaries, ``TimeLimit.truncated`` and
            ``terminal_observation``, and ``stagger_cut: True``.
        privileged: Observations are dicts ``{"obs": estimate-based, "privileged": the same
            observation built from the true state}`` (for asymmetric actor-critic training).
    """

    def __init__(
        self,
        env_id: str,
        num_lanes: int,
        env_kwargs: dict[str, Any],
        wrapper: Any,
        info_keys: tuple[str, ...] | None,
        stagger: tuple[int, int] | None = None,
        privileged: bool = False,
    ) -> None:
        import quadslam_env  # noqa: F401  (registers the ids)

        self.vec = gym.make_vec(
            env_id, num_envs=num_lanes, vectorization_mode="vector_entry_point", **env_kwargs
        )
        base = self.vec.unwrapped
        assert isinstance(base, QuadSLAMVectorEnv)  # the id's vector entry point
        self.base = base
        self.core = base.core
        self.info_keys = info_keys
        spec = gym.spec(env_id)
        self.spec = replace(spec, kwargs={**spec.kwargs, **env_kwargs})
        parsed = parse_wrapper_spec(wrapper)
        self.residual = None if parsed is None else ResidualDFLQR(self.vec, **parsed[1])
        self._obs: np.ndarray | None = None
        self._start = np.ones(num_lanes, dtype=bool)  # lanes whose next step starts an episode
        self.stagger = stagger
        self.privileged = privileged
        self._cut = np.full(num_lanes, NO_CUT)

    def _infos(
        self, info: dict[str, Any], lanes: Iterable[int], ended: np.ndarray | None = None
    ) -> list[dict[str, Any]]:
        """Per-lane info dicts; a lane that ``ended`` gets every key (its summaries, reason)."""
        kept = info
        if self.info_keys is not None:
            kept = {key: info[key] for key in self.info_keys if key in info}
        return [lane_info(info if ended is not None and ended[j] else kept, j) for j in lanes]

    def reset(
        self, seeds: Sequence[int | None], options: Sequence[dict[str, Any] | None]
    ) -> tuple[np.ndarray, list[dict[str, Any]]]:
        """Reset every lane: seeds (k,) (``None``: continue the lane's generator), options (k,).

        Returns:
            ``(obs (k, obs_dim) float32, infos (k,))``.
        """
        self.base.seed_lanes(seeds)  # the lane generators of the vector env
        groups: dict[int, list[int]] = {}  # lanes sharing one options object reset together
        for lane, opts in enumerate(options):
            groups.setdefault(id(opts) if opts else 0, []).append(lane)
        obs = np.empty((len(seeds), self.core.observer.size), dtype=np.float32)
        infos: list[dict[str, Any]] = [{} for _ in seeds]
        for lanes in groups.values():
            opts = parse_reset_options(options[lanes[0]] or None)
            g_obs, g_info = self.core.reset_lanes(lanes, self.base.lane_rngs(lanes), opts)
            obs[lanes] = g_obs
            for j, info in zip(lanes, self._infos(g_info, range(len(lanes))), strict=True):
                infos[j] = info
        self._obs = obs
        self._start = np.ones(len(seeds), dtype=bool)
        if self.stagger is not None:
            g0, n = self.stagger
            lanes_global = g0 + np.arange(len(seeds)) + 1
            cut = np.ceil(self.core.max_steps * lanes_global / n).astype(np.int64)
            self._cut = np.where(cut < self.core.max_steps, cut, NO_CUT)
        return self._observation(obs.copy()), infos

    def _observation(self, obs: np.ndarray, lanes: Any = slice(None)) -> Any:
        """``obs`` (k, n), or with ``privileged`` the dict with the truth-based twin."""
        if not self.privileged:
            return obs
        return {ACTOR_KEY: obs, PRIVILEGED_KEY: self.core.true_observation()[lanes]}

    def step(
        self, actions: np.ndarray
    ) -> tuple[
        np.ndarray, np.ndarray, np.ndarray, list[dict[str, Any]], dict[int, Any], dict[str, Any]
    ]:
        """Step every lane with ``actions`` (k, 4), resetting the lanes that end.

        Returns:
            ``(obs (k, obs_dim) float32, rewards (k,) float32, dones (k,) bool, infos (k,),
            reset infos {lane: info} of the lanes that were reset, the core's info arrays
            {key: (k,) float} of this step)``. The arrays hold every numeric term (NaN where
            it does not apply), whatever ``info_keys`` says.
        """
        if self._obs is None:
            raise gym.error.ResetNeeded("QuadSLAMVecEnv: call reset() before step()")
        act = actions
        if self.residual is not None:
            act, base = self.residual(self._obs, actions, self._start)
        core = self.core
        obs, reward, terminated, truncated, info = core.step(np.asarray(act, dtype=float))
        cut = core.steps >= self._cut  # staggered first episodes end here (truncated)
        if cut.any():
            cut &= ~(terminated | truncated)  # an episode that ended anyway was not cut
            truncated = truncated | cut
            add_summaries(info, core.episode.summary(), cut)
        dones = terminated | truncated
        self._start = dones
        self._cut[dones] = NO_CUT  # later episodes run their full length
        infos = self._infos(info, range(core.num_lanes), dones)
        for j, lane_dict in enumerate(infos):
            lane_dict["TimeLimit.truncated"] = bool(truncated[j] and not terminated[j])
            if cut[j]:
                lane_dict[STAGGER_CUT_KEY] = True
            if self.residual is not None:
                self._add_residual_info(lane_dict, base[j], actions[j])
        lanes = np.flatnonzero(dones).tolist()
        reset_infos: dict[int, Any] = {}
        if lanes:
            final = self._observation(obs, lanes)
            for i, j in enumerate(lanes):
                infos[j]["terminal_observation"] = (
                    {key: value[i].copy() for key, value in final.items()}
                    if self.privileged
                    else obs[j].copy()
                )
            r_obs, r_info = core.reset_lanes(lanes, self.base.lane_rngs(lanes))
            obs[lanes] = r_obs
            reset_infos = dict(zip(lanes, self._infos(r_info, range(len(lanes))), strict=True))
        self._obs = obs
        arrays = {key: value for key, value in info.items() if key not in TEXT_INFO_KEYS}
        out = self._observation(obs.copy())
        return out, reward.astype(np.float32), dones, infos, reset_infos, arrays

    def _add_residual_info(self, info: dict[str, Any], base: np.ndarray, res: np.ndarray) -> None:
        for key, value in (("dflqr_action", base), ("residual", res)):
            if self.info_keys is None or key in self.info_keys:
                info[key] = np.asarray(value, dtype=np.float32)

    def get_attr(self, name: str, lanes: Sequence[int]) -> list[Any]:
        """``name`` for local ``lanes``: per-lane values, the single-env spaces and spec, or the
        shared vector env's (then its core's) attribute.

        Raises:
            AttributeError: No such attribute.
        """
        if name in _LANE_ATTRS:
            return [_LANE_ATTRS[name](self.core, i) for i in lanes]
        shared = {
            "observation_space": self.base.single_observation_space,
            "action_space": self.base.single_action_space,
            "spec": self.spec,
        }
        if name in shared:
            value = shared[name]
        elif hasattr(self.base, name):
            value = getattr(self.base, name)
        else:
            value = getattr(self.core, name)
        return [value] * len(lanes)

    def set_attr(self, name: str, value: Any) -> None:
        """Set ``name`` on the vector env shared by this share's lanes."""
        setattr(self.base, name, value)

    def call(self, name: str, args: tuple, kwargs: dict[str, Any]) -> Any:
        """Call the shared vector env's method ``name`` once."""
        return getattr(self.base, name)(*args, **kwargs)

    def close(self) -> None:
        """Close the vector env."""
        self.vec.close()


def add_summaries(info: dict[str, Any], summary: dict[str, np.ndarray], lanes: np.ndarray) -> None:
    """Put the episode summaries of ``lanes`` (k,) bool into a step's ``info`` arrays.

    The core adds the ``episode_*`` summaries for the lanes whose episode it ended; an episode
    cut short here (stagger) ends like any other, so its lanes get them too. A key the core
    already reported keeps its values on the other lanes (NaN where it was absent).

    Args:
        info: The core's info of this step, ``{key: (k,) array}`` (entries are replaced).
        summary: ``EpisodeMetrics.summary()``, ``{key: (k,) array}`` for every lane.
        lanes: (k,) the lanes whose episode ends here without the core knowing.
    """
    for key, value in summary.items():
        before = info.get(key)
        info[key] = np.where(lanes, value, math.nan if before is None else before)


class InProcess:
    """A :class:`LaneShare` in this process behind the pipe protocol of the workers.

    Args:
        *args: Arguments of :class:`LaneShare`.
    """

    def __init__(self, *args: Any) -> None:
        self.share = LaneShare(*args)
        self._reply: tuple[str, Any] = ("ok", None)

    def send(self, message: tuple[str, Any]) -> None:
        """Run ``(command, data)`` now; :meth:`recv` returns the reply."""
        self._reply = handle(self.share, *message)

    def recv(self) -> tuple[str, Any]:
        """The reply to the last message."""
        return self._reply


def handle(share: LaneShare, cmd: str, data: Any) -> tuple[str, Any]:
    """Run one command on ``share``: ``("ok", result)`` or ``("error", exception)``."""
    try:
        if cmd == "step":
            return "ok", share.step(data)
        if cmd == "reset":
            return "ok", share.reset(*data)
        if cmd == "get_attr":
            return "ok", share.get_attr(*data)
        if cmd == "set_attr":
            share.set_attr(*data)
            return "ok", None
        if cmd == "call":
            return "ok", share.call(*data)
        if cmd == "close":
            share.close()
            return "ok", None
        return "error", ValueError(f"unknown command {cmd!r}")
    except Exception as exc:  # handed to the caller, which raises it
        return "error", exc


def worker(remote: Any, parent_remote: Any, args: tuple) -> None:
    """Worker process: build ``LaneShare(*args)``, then answer commands until ``close``."""
    parent_remote.close()
    try:
        share = LaneShare(*args)
    except Exception as exc:
        remote.send(("error", exc))
        return
    remote.send(("ok", None))
    while True:
        try:
            cmd, data = remote.recv()
        except (EOFError, KeyboardInterrupt):
            return
        reply = handle(share, cmd, data)
        try:
            remote.send(reply)
        except Exception as exc:  # an unpicklable result or exception
            remote.send(("error", RuntimeError(f"{cmd}: cannot send the result back: {exc}")))
        if cmd == "close":
            remote.close()
            return


def unwrap(reply: tuple[str, Any]) -> Any:
    """The result of a reply, raising the exception a failed command sent back."""
    status, value = reply
    if status == "error":
        raise value
    return value
