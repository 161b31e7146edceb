"""``QuadSLAMVectorEnv``: B lanes of the simulation core as a native Gymnasium vector env.

Registered as the ``vector_entry_point`` of every id, so
``gymnasium.make_vec("QuadSLAM-EKF-v0", num_envs=B, vectorization_mode="vector_entry_point",
**kwargs)`` takes the same kwargs as ``gymnasium.make``. Lane i of ``reset(seed=s)`` is the
scalar env reset with seed ``s + i``, step for step and through autoresets, because both run
the same :class:`~quadslam_env.core.SimCore` code.

Gymnasium 1.x conventions: ``metadata["autoreset_mode"]`` is next-step (the step after a lane
ends resets it, ignoring its action, and returns its reset observation with reward 0); info is
a dict of (B,) arrays, each with a ``_key`` bool mask of the lanes where the term applies.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from quadslam_env.actions import validate_actions
from quadslam_env.config import ConfigError, ScenarioConfig, load_scenario
from quadslam_env.core import SimCore
from quadslam_env.env import step_rate
from quadslam_env.reset_options import parse_reset_options

if TYPE_CHECKING:
    from quadslam_env.render import LaneRenderer


class QuadSLAMVectorEnv(VectorEnv):
    """B quadcopter-with-estimator episodes stepped in lockstep in one process.

    Args:
        num_envs: Number of lanes B ≥ 1.
        scenario: Scenario name, YAML path, mapping or ``None`` (as for ``gymnasium.make``).
        render_mode: ``None`` or ``"rgb_array"`` (frames of lane 0).
        estimator_name: Estimator applied before ``overrides`` (used by the registered ids).
        max_episode_steps: Accepted for ``make_vec`` compatibility; must be ``None`` (the
            scenario's ``episode.duration_s`` sets the episode length).
        **overrides: Section mappings merged into the scenario, e.g. ``episode={...}``.
    """

    metadata = {
        "render_modes": ["rgb_array"],
        "render_fps": 100,  # an instance sets its control rate: one frame per step
        "autoreset_mode": AutoresetMode.NEXT_STEP,
    }

    def __init__(
        self,
        num_envs: int = 1,
        scenario: str | dict[str, Any] | None = None,
        render_mode: str | None = None,
        estimator_name: str | None = None,
        max_episode_steps: int | None = None,
        **overrides: Any,
    ) -> None:
        if isinstance(num_envs, bool) or not isinstance(num_envs, int | np.integer) or num_envs < 1:
            raise ConfigError(f"num_envs: got {num_envs!r}; allowed: an integer >= 1")
        if max_episode_steps is not None:
            raise ConfigError(
                f"max_episode_steps: got {max_episode_steps!r}; allowed: None (set the episode "
                "length with episode.duration_s)"
            )
        if render_mode not in (None, "rgb_array"):
            raise ConfigError(f"render_mode: got {render_mode!r}; allowed: None or 'rgb_array'")
        self.scenario: ScenarioConfig = load_scenario(scenario, overrides, estimator_name)
        self.num_envs = int(num_envs)
        self.render_mode = render_mode
        self._core = SimCore(self.scenario, self.num_envs)
        core = self._core
        self.dt = core.dt
        self.vehicle_params = core.vehicle_params
        self.hover_action = core.action_map.hover_action
        self.single_observation_space = core.observer.space
        self.single_action_space = spaces.Box(
            -1.0, 1.0, shape=(core.action_map.dim,), dtype=np.float32
        )
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._rngs: list[np.random.Generator | None] = [None] * self.num_envs
        self._autoreset = np.zeros(self.num_envs, dtype=bool)
        self.metadata = {**self.metadata, "render_fps": step_rate(self.scenario)}
        self._renderer: LaneRenderer | None = None
        if render_mode is not None:  # lane 0's history; nothing without render_mode
            from quadslam_env.render import LaneRenderer

            self._renderer = LaneRenderer(core, 0)

    @property
    def core(self) -> SimCore:
        """The simulation core (its arrays hold every lane's truth: for analysis only)."""
        return self._core

    def seed_lanes(self, seeds: Sequence[int | None]) -> None:
        """Give lane i a generator seeded ``seeds[i]`` (``None``: keep the lane's generator), as
        ``gymnasium.Env.reset(seed=...)`` does for the scalar env."""
        for lane, s in enumerate(seeds):
            if s is not None:
                self._rngs[lane] = seeding.np_random(int(s))[0]

    def lane_rngs(self, lanes: Iterable[int]) -> list[np.random.Generator]:
        """The generators of ``lanes`` (a lane never seeded gets one from fresh entropy)."""
        out = []
        for lane in lanes:
            if self._rngs[lane] is None:
                self._rngs[lane] = seeding.np_random(None)[0]
            out.append(self._rngs[lane])
        return out  # type: ignore[return-value]

    def reset(
        self,
        *,
        seed: int | list[int | None] | None = None,
        options: dict[str, Any] | None = None,
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Reset every lane; lane i is seeded with ``seed + i`` (or ``seed[i]`` for a list).

        Options (applied to every lane): ``initial_state`` (12,), ``landmarks`` (L, 3).
        """
        opts = parse_reset_options(options)
        b = self.num_envs
        if isinstance(seed, list):
            if len(seed) != b:
                raise ConfigError(f"seed: got a list of {len(seed)}; allowed: {b} seeds or an int")
            seeds = seed
        else:
            seeds = [None if seed is None else int(seed) + i for i in range(b)]
        self.seed_lanes(seeds)
        lanes = np.arange(b)
        obs, info = self._core.reset_lanes(lanes, self.lane_rngs(lanes), opts)
        self._autoreset[:] = False
        if self._renderer is not None:
            self._renderer.record(info)
        return obs, _vector_info(info)

    def step(
        self, actions: Any
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """Step every lane; lanes that ended on the previous step are reset instead.

        Raises:
            ActionError: ``actions`` is not a finite (B, 4) array (naming the lanes); no lane
                is changed.
        """
        act = validate_actions(actions, self.num_envs, self._core.action_map.dim)
        core = self._core
        resetting = self._autoreset.copy()
        obs, reward, terminated, truncated, info = core.step(act, ~resetting)
        info["termination_reason"] = np.array(info["termination_reason"], dtype=object)
        lanes = np.flatnonzero(resetting)
        if lanes.size:
            r_obs, r_info = core.reset_lanes(lanes, self.lane_rngs(lanes))
            obs[lanes] = r_obs
            reward[lanes] = 0.0
            terminated[lanes] = False
            truncated[lanes] = False
            for key, value in info.items():
                if key in r_info:
                    value[lanes] = r_info[key]
                elif key == "termination_reason":
                    value[lanes] = ""
                else:
                    value[lanes] = np.nan
        self._autoreset = terminated | truncated
        if self._renderer is not None:
            self._renderer.record(info)
        return obs, reward, terminated, truncated, _vector_info(info)

    # VectorEnv.render is typed as one frame per lane; this env draws lane 0 only (README).
    def render(self) -> np.ndarray | None:  # type: ignore[override]
        """Lane 0's frame (see :meth:`QuadSLAMEnv.render`), or ``None`` without ``render_mode``."""
        if self._renderer is None:
            return None
        return self._renderer.frame()


def _vector_info(info: dict[str, Any]) -> dict[str, Any]:
    """Gymnasium vector info: each (B,) array with a ``_key`` mask of the lanes it applies to."""
    out: dict[str, Any] = {}
    for key, value in info.items():
        if key == "termination_reason":
            arr = np.asarray(value, dtype=object)
            mask = arr != ""
        else:
            arr = np.asarray(value, dtype=float)
            mask = ~np.isnan(arr)
        if mask.any():
            out[key] = arr
            out[f"_{key}"] = mask
    return out
