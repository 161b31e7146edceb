"""Action wrappers for learning on top of the DF-LQR baseline (docs/design.md §6).

:class:`ResidualDFLQRWrapper` turns the env into a *residual* learning problem: the agent outputs
a correction ``δ ∈ [-1, 1]⁴`` and the env receives

.. code-block:: text

    a = clip(a_DFLQR(o) + scale ⊙ δ, -1, 1)

where ``a_DFLQR(o)`` is the normalised ``thrust_torque`` action the DF-LQR baseline
(:class:`agents.control.dflqr.DFLQRPolicy`) computes from the *same* observation ``o`` the agent
sees.
With ``δ = 0`` the wrapped env flies exactly the DF-LQR baseline, so a freshly initialised
agent (whose mean action is ≈ 0) starts from a working controller and only has to learn to
correct it (e.g. for IMU biases the estimator leaves in the estimate).

Observations, rewards, termination and ``info`` are passed through unchanged; the wrapper adds
``info["dflqr_action"]`` and ``info["residual"]`` for analysis.

Wrapper specifications (as written in ``configs/agents/*.yaml``) are parsed by
:func:`parse_wrapper_spec` and applied by :func:`apply_wrapper`:

- ``null`` / ``"none"``: no wrapper;
- ``"residual_dflqr"``: residual wrapper with the default scale;
- ``{"name": "residual_dflqr", "scale": 0.2}`` (``scale`` a number or 4 numbers, in units of
  the normalised action: thrust, roll/pitch/yaw torque).

The formula is applied in one place, :class:`ResidualDFLQR`, batch-first; it serves the scalar
wrapper, :class:`ResidualDFLQRVectorWrapper` (Gymnasium vector envs) and the SB3 adapter
:class:`agents.rl.vec_adapter.QuadSLAMVecEnv` (``wrapper="residual_dflqr"``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np

from agents.control.dflqr import DFLQRPolicy
from agents.control.lookat import LookAtPolicy
from agents.control.named import CONTROLLERS, OPTIONS, build_controller

RESIDUAL_DFLQR = "residual_dflqr"
WRAPPERS = (RESIDUAL_DFLQR,)
DEFAULT_RESIDUAL_SCALE = 0.2


def residual_action(base: np.ndarray, residual: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """Compose a DF-LQR action with a scaled residual.

    Args:
        base: (4,) or (n, 4) normalised DF-LQR actions in [-1, 1].
        residual: Residuals of the same shape; clipped to [-1, 1] first.
        scale: (4,) per-component residual scale.

    Returns:
        float32 ``clip(base + scale * clip(residual, -1, 1), -1, 1)``.
    """
    res = np.clip(np.asarray(residual, dtype=np.float32), -1.0, 1.0)
    out = np.asarray(base, dtype=np.float32) + np.asarray(scale, dtype=np.float32) * res
    return np.clip(out, -1.0, 1.0).astype(np.float32)


def as_residual_scale(scale: float | Sequence[float]) -> np.ndarray:
    """Validate a residual scale (a number or 4 numbers ≥ 0) → (4,) float32.

    Raises:
        ValueError: Wrong length, negative or non-finite values.
    """
    arr = np.asarray(scale, dtype=float)
    if arr.ndim == 0:
        arr = np.full(4, float(arr))
    if arr.shape != (4,) or not np.all(np.isfinite(arr)) or np.any(arr < 0.0):
        raise ValueError(
            f"residual_dflqr.scale: got {scale!r}; allowed: a non-negative number or 4 "
            "non-negative numbers (thrust, roll, pitch, yaw torque; normalised action units)"
        )
    return arr.astype(np.float32)


BASES = (*CONTROLLERS, "lookat")
"""Controllers a residual can sit on: the baselines by name (DF-LQR, the LQI of
:mod:`agents.control.lqi`), or DF-LQR with the look-at heading rule
(:mod:`agents.control.lookat`, for scenarios with the heading channel)."""


_OPTIONS = {option: names for option, (names, _) in OPTIONS.items()}
"""The base options a residual takes (``wrapper.<option>``), each with the bases that have it
(the controllers' options, :data:`agents.control.named.OPTIONS`)."""


def _check_options(base: str, given: dict[str, Any]) -> None:
    """Refuse a ``wrapper.<option>`` of :data:`_OPTIONS` that is not a bool, or true on a
    ``base`` without it.

    Raises:
        ValueError: Naming ``wrapper.<option>``, the value, the base and what is allowed.
    """
    for option, value in given.items():
        if not isinstance(value, bool) or (value and base not in _OPTIONS[option]):
            raise ValueError(
                f"wrapper.{option}: got {value!r} with wrapper.base {base!r}; allowed: false, "
                f"or true with a base that has it ({', '.join(_OPTIONS[option])})"
            )


def base_controller(
    env: Any, base: str, drag_feedforward: bool = False, thrust_adaptation: bool = False
) -> Any:
    """The controller named ``base`` (one of :data:`BASES`) for ``env``, with the drag
    feed-forward and the thrust adaptation if asked (``lqi`` and ``se3``,
    :func:`agents.control.named.build_controller`).

    Raises:
        ValueError: Unknown name, ``lookat`` on a scenario without the heading channel, or
            an option on a base without it or ``drag_feedforward`` on an env without the air
            velocity.
    """
    if base not in BASES:
        raise ValueError(f"wrapper.base: got {base!r}; allowed: {list(BASES)}")
    _check_options(base, {"drag_feedforward": drag_feedforward,
                          "thrust_adaptation": thrust_adaptation})  # fmt: skip
    if base == "lookat":
        return LookAtPolicy(env)
    return build_controller(base, env, "wrapper.base", drag_feedforward=drag_feedforward,
                            thrust_adaptation=thrust_adaptation)  # fmt: skip


class ResidualDFLQR:
    """The residual-on-DF-LQR action for one env or B lanes: the one place the formula is applied.

    Args:
        env: A (possibly wrapped) ``QuadSLAMEnv`` or ``QuadSLAMVectorEnv`` (``thrust_torque``).
        scale: Residual scale, a number or (4,) per component, in normalised action units.
        controller: Controller to use; default the one named by ``base``.
        base: ``"dflqr"`` or ``"lookat"`` (:data:`BASES`), when no ``controller`` is given.
        drag_feedforward: The base's drag feed-forward (``lqi``, ``se3``), when no
            ``controller`` is given.
        thrust_adaptation: The base's thrust adaptation (``lqi``, ``se3``), when no
            ``controller`` is given.

    Attributes:
        controller: The base policy (DF-LQR, LQI, or DF-LQR with the look-at heading).
        scale: (4,) float32 residual scale ((5,) with the heading channel, whose scale is 1).
        dim: Components of one action (4, or 5 with the heading channel).
        state: The base's ``predict`` state over the lanes (the LQI's integrals; ``None`` for
            a memoryless base), carried from call to call and reset per lane by
            ``episode_start``.

    Raises:
        ValueError: Bad ``scale`` or an env not in ``thrust_torque`` mode.
    """

    def __init__(
        self,
        env: Any,
        scale: float | Sequence[float] = DEFAULT_RESIDUAL_SCALE,
        controller: DFLQRPolicy | LookAtPolicy | None = None,
        base: str = "dflqr",
        drag_feedforward: bool = False,
        thrust_adaptation: bool = False,
    ) -> None:
        if controller is None:
            controller = base_controller(env, base, drag_feedforward, thrust_adaptation)
        self.controller = controller
        self.dim = self.controller.action_dim
        # A heading channel (fifth component) is the agent's own command, not a residual:
        # DF-LQR's is 0 and its scale 1, so the formula passes it through.
        self.scale = np.concatenate([as_residual_scale(scale), np.ones(self.dim - 4, np.float32)])
        self.state: Any = None

    def __call__(
        self, obs: np.ndarray, residual: Any, episode_start: Any = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Actions for residuals given the observations the agent acted on.

        Args:
            obs: (obs_dim,) or (B, obs_dim) observations.
            residual: Residuals of shape (4,) or (B, 4) matching ``obs``.
            episode_start: () or (B,) bool, the lanes whose ``obs`` starts an episode (their
                base state is reset); ``None``: none of them, unless no state exists yet.

        Returns:
            ``(action, dflqr_action)``, both float32 of the residual's shape.

        Raises:
            ValueError: ``residual`` does not have the shape of one action per observation.
        """
        res = np.asarray(residual, dtype=np.float32)
        want = (*np.shape(obs)[:-1], self.dim)
        if res.shape != want:
            raise ValueError(f"residual action: got shape {res.shape}; allowed: {want}")
        base, self.state = self.controller.predict(
            obs, state=self.state, episode_start=episode_start
        )
        return residual_action(base, res, self.scale), base


class _ResidualSteps:
    """``reset``/``step`` shared by the scalar and vector residual wrappers."""

    env: Any
    residual: ResidualDFLQR
    _obs: np.ndarray | None = None
    _start: np.ndarray | None = None

    def reset(self, *, seed: Any = None, options: dict[str, Any] | None = None) -> tuple[Any, Any]:
        """Reset the env and remember the observation(s) for the next base command."""
        obs, info = self.env.reset(seed=seed, options=options)
        self._obs = obs
        self._start = np.ones(np.shape(obs)[:-1], dtype=bool)
        return obs, info

    def _residual_step(self, action: Any) -> tuple[np.ndarray, np.ndarray, tuple]:
        """``(action sent, base action, env.step result)`` for residual ``action``; a lane
        that ends starts its next episode (the vector env's autoreset) with a fresh base
        state."""
        if self._obs is None:
            raise gym.error.ResetNeeded(f"{type(self).__name__}: call reset() before step()")
        act, base = self.residual(self._obs, action, self._start)
        out = self.env.step(act)
        self._obs = out[0]
        self._start = np.asarray(out[2]) | np.asarray(out[3])
        return act, base, out


class ResidualDFLQRWrapper(_ResidualSteps, gym.Wrapper):
    """Residual RL on DF-LQR: ``a = clip(a_DFLQR(o) + scale ⊙ δ, -1, 1)``.

    The action space stays ``Box(-1, 1, (4,), float32)`` (5 with the heading channel, whose
    component is the agent's heading-rate command, passed through) and is interpreted as the
    residual ``δ``; the DF-LQR part is computed from the latest observation returned by ``reset`` /
    ``step`` (i.e. the observation the agent acted on). The env must use the
    ``thrust_torque`` action mode.

    Args:
        env: A (possibly wrapped) ``QuadSLAMEnv``.
        scale: Residual scale, a number or (4,) per component, in normalised action units.
        controller: Base controller to use; default the one named by ``base``.
        base: ``"dflqr"`` or ``"lookat"`` (:data:`BASES`).
        drag_feedforward: The base's drag feed-forward (``lqi``, ``se3``).
        thrust_adaptation: The base's thrust adaptation (``lqi``, ``se3``).

    Attributes:
        residual: The :class:`ResidualDFLQR` composer (``controller``, ``scale``).
        last_action: (4,) float32 action sent to the env on the last ``step``.

    Raises:
        ValueError: Bad ``scale`` or an env not in ``thrust_torque`` mode.
    """

    def __init__(
        self,
        env: gym.Env,
        scale: float | Sequence[float] = DEFAULT_RESIDUAL_SCALE,
        controller: DFLQRPolicy | LookAtPolicy | None = None,
        base: str = "dflqr",
        drag_feedforward: bool = False,
        thrust_adaptation: bool = False,
    ) -> None:
        super().__init__(env)
        self.residual = ResidualDFLQR(
            env, scale, controller, base, drag_feedforward, thrust_adaptation
        )
        self.action_space = gym.spaces.Box(-1.0, 1.0, shape=(self.residual.dim,), dtype=np.float32)
        self._obs = None
        self.last_action: np.ndarray | None = None

    @property
    def controller(self) -> DFLQRPolicy | LookAtPolicy:
        """The DF-LQR policy."""
        return self.residual.controller

    @property
    def scale(self) -> np.ndarray:
        """(4,) float32 residual scale."""
        return self.residual.scale

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        """Apply DF-LQR(last observation) + ``scale`` × residual ``action``."""
        act, base, (obs, reward, terminated, truncated, info) = self._residual_step(action)
        self.last_action = act
        info["dflqr_action"] = base
        info["residual"] = np.asarray(action, dtype=np.float32)
        return obs, reward, terminated, truncated, info


class ResidualDFLQRVectorWrapper(_ResidualSteps, gym.vector.VectorWrapper):
    """:class:`ResidualDFLQRWrapper` for a Gymnasium vector env of B lanes.

    Lane i sees ``a_i = clip(a_DFLQR(o_i) + scale ⊙ δ_i, -1, 1)`` with ``o_i`` the lane's latest
    observation (after an autoreset: its reset observation), so with the native
    ``QuadSLAMVectorEnv`` lane i equals the scalar wrapper on the scalar env seeded ``s + i``.
    ``info`` gains ``dflqr_action`` and ``residual`` (B, 4) with their ``_key`` masks.

    Args:
        env: A ``QuadSLAMVectorEnv`` (possibly wrapped), ``thrust_torque`` mode.
        scale: Residual scale, a number or (4,) per component, in normalised action units.
        controller: Base controller to use; default the one named by ``base``.
        base: ``"dflqr"`` or ``"lookat"`` (:data:`BASES`).
        drag_feedforward: The base's drag feed-forward (``lqi``, ``se3``).
        thrust_adaptation: The base's thrust adaptation (``lqi``, ``se3``).

    Raises:
        ValueError: Bad ``scale`` or an env not in ``thrust_torque`` mode.
    """

    def __init__(
        self,
        env: gym.vector.VectorEnv,
        scale: float | Sequence[float] = DEFAULT_RESIDUAL_SCALE,
        controller: DFLQRPolicy | LookAtPolicy | None = None,
        base: str = "dflqr",
        drag_feedforward: bool = False,
        thrust_adaptation: bool = False,
    ) -> None:
        super().__init__(env)
        self.residual = ResidualDFLQR(
            env, scale, controller, base, drag_feedforward, thrust_adaptation
        )
        self.single_action_space = gym.spaces.Box(
            -1.0, 1.0, shape=(self.residual.dim,), dtype=np.float32
        )
        self.action_space = gym.vector.utils.batch_space(self.single_action_space, self.num_envs)
        self._obs = None

    def step(self, actions: Any) -> tuple[Any, Any, Any, Any, dict[str, Any]]:
        """Step with residuals ``actions`` (B, 4) on DF-LQR of the last observations."""
        _, base, (obs, reward, terminated, truncated, info) = self._residual_step(actions)
        every = np.ones(self.num_envs, dtype=bool)
        info = {**info, "dflqr_action": base, "_dflqr_action": every}
        info["residual"] = np.asarray(actions, dtype=np.float32)
        info["_residual"] = every
        return obs, reward, terminated, truncated, info


def parse_wrapper_spec(spec: Any) -> tuple[str, dict[str, Any]] | None:
    """Normalise a config ``wrapper`` entry to ``(name, kwargs)`` or ``None`` (no wrapper).

    Raises:
        ValueError: Unknown wrapper name or malformed entry.
    """
    if spec is None or spec is False or (isinstance(spec, str) and spec.lower() == "none"):
        return None
    if isinstance(spec, str):
        name, kwargs = spec, {}
    elif isinstance(spec, dict):
        kwargs = dict(spec)
        name = kwargs.pop("name", None)
        if name is None and len(kwargs) == 1:  # {residual_dflqr: {scale: 0.2}}
            ((name, inner),) = kwargs.items()
            kwargs = dict(inner or {})
        if not isinstance(name, str):
            raise ValueError(
                f"wrapper: got {spec!r}; allowed: null/'none', a name from {list(WRAPPERS)}, "
                "or a mapping with 'name' and keyword arguments"
            )
    else:
        raise ValueError(
            f"wrapper: got {spec!r}; allowed: null/'none', a name from {list(WRAPPERS)}, "
            "or a mapping with 'name' and keyword arguments"
        )
    if name.lower() == "none":
        return None
    if name not in WRAPPERS:
        raise ValueError(f"wrapper: got {name!r}; allowed: {['none', *WRAPPERS]}")
    unknown = set(kwargs) - {"scale", "base", *_OPTIONS}
    if unknown:
        raise ValueError(
            f"wrapper.{sorted(unknown)[0]}: unknown key for {name}; allowed: "
            f"{sorted(['base', 'scale', *_OPTIONS])}"
        )
    if "scale" in kwargs:
        as_residual_scale(kwargs["scale"])  # validate early, with the config's wording
    base = kwargs.get("base", "dflqr")
    if base not in BASES:
        raise ValueError(f"wrapper.base: got {kwargs['base']!r}; allowed: {list(BASES)}")
    _check_options(base, {option: kwargs.get(option, False) for option in _OPTIONS})
    return name, kwargs


def apply_wrapper(env: gym.Env, spec: Any) -> gym.Env:
    """Wrap ``env`` according to a config ``wrapper`` entry (see :func:`parse_wrapper_spec`)."""
    parsed = parse_wrapper_spec(spec)
    if parsed is None:
        return env
    _, kwargs = parsed
    return ResidualDFLQRWrapper(env, **kwargs)


def make_wrapped_env(
    env_id: str, env_kwargs: dict[str, Any] | None = None, wrapper: Any = None
) -> gym.Env:
    """``gymnasium.make(env_id, **env_kwargs)`` followed by :func:`apply_wrapper`.

    Args:
        env_id: A registered id, e.g. ``"QuadSLAM-EKF-v0"``.
        env_kwargs: Keyword arguments for ``gymnasium.make`` (``scenario=``, section overrides).
        wrapper: A config ``wrapper`` entry (``None``, ``"residual_dflqr"``, or a mapping).
    """
    import quadslam_env  # noqa: F401  (registers the ids)

    return apply_wrapper(gym.make(env_id, **(env_kwargs or {})), wrapper)
