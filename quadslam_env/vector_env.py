"""``QuadSLAMVectorEnv``: B lanes of the simulation core as a native Gymnasium vector env.

Registered as the ``vector_entry_point`` of every id, so
``gymnasium.make_vec("QuadSLAM-EKF-v0", num_envs=B, vectorization_mode="vector_entry_point",
**kwargs)`` takes the same kwargs as ``gymnasium.make`` (plus ``autoreset_mode``). Lane i of
``reset(seed=s)`` is the scalar env reset with seed ``s + i``, step for step and through every
reset of the lane, because both run the same :class:`~quadslam_env.core.SimCore` code.

Gymnasium 1.x conventions: ``metadata["autoreset_mode"]`` is the ``autoreset_mode`` the env was
made with (what :class:`gymnasium.vector.SyncVectorEnv` does in that mode):

* ``NEXT_STEP`` (default): the step after a lane ends resets it, ignoring its action, and
  returns its reset observation with reward 0.
* ``SAME_STEP``: a lane that ends is reset in the same step; the step returns its reset
  observation and reset info with the ending step's reward, ``terminated`` and ``truncated``,
  and ``info["final_obs"]`` (object (B,), the lane's last observation) and
  ``info["final_info"]`` (the ending step's info) with their ``_final_obs``/``_final_info``
  masks.
* ``DISABLED``: nothing is reset by ``step``; ``reset(options={"reset_mask": mask})`` resets
  the masked lanes, and stepping while a lane that ended was not reset raises.

Info is a dict of (B,) arrays, each with a ``_key`` bool mask of the lanes where the term
applies.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
from gymnasium import error, spaces
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from quadslam_env.config.scenario import ScenarioConfig, load_scenario
from quadslam_env.core import SimCore
from quadslam_env.env import step_rate
from quadslam_env.episode.actions import validate_actions
from quadslam_env.episode.reset_options import (
    parse_lane_seeds,
    parse_reset_options,
    parse_seed,
    split_reset_mask,
)
from quadslam_env.memory import check_env_memory
from quadslam_env.schema import ConfigError
from quadslam_env.types import TEXT_INFO_KEYS

if TYPE_CHECKING:
    from quadslam_env.render.renderer import LaneRenderer


class QuadSLAMVectorEnv(VectorEnv):
    """B quadcopter-with-estimator episodes stepped in lockstep in one process.

    Args:
        num_envs: Number of lanes B ≥ 1.
        scenario: Scenario name, YAML path, mapping or ``None`` (as for ``gymnasium.make``).
        render_mode: ``None`` or ``"rgb_array"`` (frames of lane 0).
        estimator_name: Estimator applied before ``overrides`` (used by the registered ids).
        max_episode_steps: Accepted for ``make_vec`` compatibility; must be ``None`` (the
            scenario's ``episode.duration_s`` sets the episode length).
        autoreset_mode: A :class:`gymnasium.vector.AutoresetMode` or its value
            (``"NextStep"``, ``"SameStep"``, ``"Disabled"``); see the module docstring.
        **overrides: Section mappings merged into the scenario, e.g. ``episode={...}``.

    Raises:
        ConfigError: A bad ``num_envs``, ``render_mode``, ``autoreset_mode`` or scenario.
        MemoryLimitError: Lanes whose buffers would not fit in memory (a ``ConfigError``
            naming the setting that dominates and what fits, :mod:`quadslam_env.memory`).
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
        autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
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
        self.autoreset_mode = parse_autoreset_mode(autoreset_mode)
        self.scenario: ScenarioConfig = load_scenario(scenario, overrides, estimator_name)
        self.num_envs = int(num_envs)
        self.render_mode = render_mode
        check_env_memory(self.scenario, self.num_envs)  # before anything is allocated
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
        # Lanes whose last step ended their episode and that were not reset since (NEXT_STEP:
        # reset by the next step; DISABLED: stepping them raises; SAME_STEP: never left set).
        self._ended = np.zeros(self.num_envs, dtype=bool)
        self._obs: np.ndarray | None = None  # (B, n) last observations; None before a reset
        self.metadata = {
            **self.metadata,
            "render_fps": step_rate(self.scenario),
            "autoreset_mode": self.autoreset_mode,
        }
        self._renderer: LaneRenderer | None = None
        if render_mode is not None:  # lane 0's history; nothing without render_mode
            from quadslam_env.render.renderer import LaneRenderer

            self._renderer = LaneRenderer(core, 0)

    @property
    def core(self) -> SimCore:
        """The simulation core (its arrays hold every lane's truth: for analysis only)."""
        return self._core

    def seed_lanes(self, seeds: Sequence[int | None]) -> None:
        """Give lane i a generator seeded ``seeds[i]`` (``None``: keep the lane's generator), as
        ``gymnasium.Env.reset(seed=...)`` does for the scalar env."""
        for lane, s in enumerate(seeds):
            s = parse_seed(s, f"seed[{lane}]")
            if s is not None:
                self._rngs[lane] = seeding.np_random(s)[0]

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
        """Reset every lane, or the lanes of ``options["reset_mask"]``.

        Lane i is seeded with ``seed + i`` (or ``seed[i]`` for a list); with a mask only the
        masked lanes are reseeded and reset, and the other lanes' rows of the returned
        observation are their last observations (as in Gymnasium's vector envs).

        Args:
            seed: ``None``, an integer >= 0 or a list of B entries, each ``None`` or an
                integer >= 0 (NumPy integers are accepted, bools are not).
            options: ``initial_state`` (12,), ``landmarks`` (L, 3), ``randomized`` (scales
                to pin) (applied to every lane reset) and ``reset_mask`` (B,) bool, the lanes
                to reset (at least one).

        Returns:
            ``(obs (B, n) float32, info)``: info as in :meth:`step`, for the lanes reset.

        Raises:
            ConfigError: A bad seed, seed list length, option or ``reset_mask``.
        """
        b = self.num_envs
        seeds = parse_lane_seeds(seed, b)
        mask, rest = split_reset_mask(options, b)
        opts = parse_reset_options(rest)
        if mask is None:
            mask = np.ones(b, dtype=bool)
        elif self._obs is None:
            raise error.ResetNeeded(
                "QuadSLAMVectorEnv.reset: reset_mask before the first reset; call reset() "
                "without it first"
            )
        lanes = np.flatnonzero(mask)
        self.seed_lanes([s if m else None for s, m in zip(seeds, mask, strict=True)])
        obs_k, info_k = self._core.reset_lanes(lanes, self.lane_rngs(lanes), opts)
        if self._obs is None or lanes.size == b:
            obs, info = obs_k, info_k
        else:
            obs = self._obs.copy()
            obs[lanes] = obs_k
            info = _lane_rows(info_k, lanes, b)
        self._ended[lanes] = False
        self._obs = obs.copy()  # a caller may write into what it is given
        if self._renderer is not None and mask[self._renderer.lane]:
            self._renderer.record(info)
        return obs, _vector_info(info)

    def step(
        self, actions: Any
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """Step every lane; what happens to lanes that end depends on ``autoreset_mode``.

        NEXT_STEP: lanes that ended on the previous step are reset instead of stepped.
        SAME_STEP: lanes that end now are reset now, their last observation and info in
        ``info["final_obs"]``/``info["final_info"]``. DISABLED: no lane is reset.

        Args:
            actions: (B, 4) actions in [-1, 1] ((B, 5) with ``action.heading``).

        Returns:
            ``(obs (B, n) float32, reward (B,), terminated (B,), truncated (B,), info)``.

        Raises:
            gymnasium.error.ResetNeeded: Before the first ``reset()``, or (DISABLED) while a
                lane that ended was not reset; no lane is changed.
            ActionError: ``actions`` is not a finite (B, 4) array (naming the lanes); no lane
                is changed.
        """
        if self._obs is None:
            raise error.ResetNeeded("QuadSLAMVectorEnv.step: call reset() before step()")
        mode = self.autoreset_mode
        if mode == AutoresetMode.DISABLED and self._ended.any():
            raise error.ResetNeeded(
                f"QuadSLAMVectorEnv.step: lane(s) {np.flatnonzero(self._ended).tolist()} ended "
                "(terminated or truncated) and autoreset_mode is DISABLED; call "
                "reset(options={'reset_mask': mask}) with those lanes before step()"
            )
        act = validate_actions(actions, self.num_envs, self._core.action_map.dim)
        if mode == AutoresetMode.NEXT_STEP:
            out = self._step_next(act)
        else:
            out = self._step_all(act, reset=mode == AutoresetMode.SAME_STEP)
        self._obs = out[0].copy()  # a caller may write into what it is given
        return out

    def _step_next(
        self, act: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """NEXT_STEP: step the lanes, reset the ones that ended on the previous step."""
        core = self._core
        resetting = self._ended.copy()
        obs, reward, terminated, truncated, info = core.step(act, ~resetting)
        _text_arrays(info)
        lanes = np.flatnonzero(resetting)
        if lanes.size:
            r_obs, r_info = core.reset_lanes(lanes, self.lane_rngs(lanes))
            obs[lanes] = r_obs
            reward[lanes] = 0.0
            terminated[lanes] = False
            truncated[lanes] = False
            _put_lane_rows(info, lanes, r_info)
        self._ended = terminated | truncated
        if self._renderer is not None:
            self._renderer.record(info)
        return obs, reward, terminated, truncated, _vector_info(info)

    def _step_all(
        self, act: np.ndarray, reset: bool
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """SAME_STEP (``reset``) or DISABLED: step every lane; with ``reset`` the lanes that
        end now are reset now, as :class:`gymnasium.vector.SyncVectorEnv` does."""
        core = self._core
        obs, reward, terminated, truncated, info = core.step(act)
        _text_arrays(info)
        ended = terminated | truncated
        lanes = np.flatnonzero(ended)
        extra: dict[str, Any] = {}
        if reset and lanes.size:
            final_obs = np.full(self.num_envs, None, dtype=object)
            for lane in lanes.tolist():
                final_obs[lane] = obs[lane].copy()
            final = {key: _only(value, ended) for key, value in info.items()}
            extra = {
                "final_obs": final_obs,
                "_final_obs": ended.copy(),
                "final_info": _vector_info(final),
                "_final_info": ended.copy(),
            }
            r_obs, r_info = core.reset_lanes(lanes, self.lane_rngs(lanes))
            obs[lanes] = r_obs
            _put_lane_rows(info, lanes, r_info)  # as SyncVectorEnv: the reset's info
            ended[:] = False
        self._ended = ended
        if self._renderer is not None:
            self._renderer.record(info)
        return obs, reward, terminated, truncated, {**_vector_info(info), **extra}

    # VectorEnv.render is typed as one frame per lane; this env draws lane 0 only
    # (docs/rendering.md).
    def render(self) -> np.ndarray | None:  # type: ignore[override]
        """Lane 0's frame (see :meth:`QuadSLAMEnv.render`), or ``None`` without ``render_mode``."""
        if self._renderer is None:
            return None
        return self._renderer.frame()


def parse_autoreset_mode(value: Any) -> AutoresetMode:
    """The :class:`gymnasium.vector.AutoresetMode` of ``value`` (the enum or its value).

    Raises:
        ConfigError: Anything else, naming the allowed values.
    """
    if isinstance(value, AutoresetMode):
        return value
    for mode in AutoresetMode:
        if isinstance(value, str) and value == mode.value:
            return mode
    allowed = [mode.value for mode in AutoresetMode]
    raise ConfigError(
        f"autoreset_mode: got {value!r}; allowed: a gymnasium.vector.AutoresetMode or one of "
        f"{allowed}"
    )


def _only(value: np.ndarray, lanes: np.ndarray) -> np.ndarray:
    """A copy of the (B,) info term ``value`` that applies only in the (B,) bool ``lanes``."""
    if value.dtype == object:  # text: termination_reason, fault_kind
        return np.where(lanes, value, "")
    return np.where(lanes, value, np.nan)


def _put_lane_rows(info: dict[str, Any], lanes: np.ndarray, lane_info: dict[str, Any]) -> None:
    """Write ``lane_info`` ((k,) terms of a reset of ``lanes`` (k,)) into the (B,) ``info`` in
    place; terms the reset does not report do not apply there (NaN, or ``""``)."""
    for key, value in info.items():
        if key in lane_info:
            value[lanes] = lane_info[key]
        elif key in TEXT_INFO_KEYS:
            value[lanes] = ""
        else:
            value[lanes] = np.nan


def _lane_rows(lane_info: dict[str, Any], lanes: np.ndarray, b: int) -> dict[str, Any]:
    """(B,) terms from the (k,) terms of ``lanes`` (k,): NaN in the other lanes."""
    out: dict[str, Any] = {}
    for key, value in lane_info.items():
        row = np.full(b, "", dtype=object) if key in TEXT_INFO_KEYS else np.full(b, np.nan)
        row[lanes] = value
        out[key] = row
    return out


def _text_arrays(info: dict[str, Any]) -> None:
    """The core's text terms (lists of B strings) as object arrays, in place."""
    for key in TEXT_INFO_KEYS:
        if key in info:
            info[key] = np.array(info[key], dtype=object)


def _vector_info(info: dict[str, Any]) -> dict[str, Any]:
    """Gymnasium vector info: each (B,) array with a ``_key`` mask of the lanes it applies to.

    The numeric terms are stacked into one (K, B) float array and masked at once (False exactly
    at NaN): a term costs a row view instead of three NumPy calls, which at a few lanes were
    half of a step. Each term is a row of that fresh array, so no core buffer is handed out.
    """
    text = [key for key in info if key in TEXT_INFO_KEYS]
    keys = [key for key in info if key not in TEXT_INFO_KEYS]
    out: dict[str, Any] = {}
    if keys:
        values = np.array([info[key] for key in keys], dtype=float)
        masks = values == values
        for row in np.flatnonzero(masks.any(axis=1)).tolist():
            key = keys[row]
            out[key] = values[row]
            out[f"_{key}"] = masks[row]
    for key in text:
        arr = np.asarray(info[key], dtype=object)
        mask = arr != ""
        if mask.any():
            out[key] = arr
            out[f"_{key}"] = mask
    return out
