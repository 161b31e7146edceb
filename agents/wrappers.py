"""Action wrappers for learning on top of the DF-LQR baseline (DESIGN.md §6).

:class:`ResidualDFLQRWrapper` turns the env into a *residual* learning problem: the agent outputs
a correction ``δ ∈ [-1, 1]⁴`` and the env receives

.. code-block:: text

    a = clip(a_DFLQR(o) + scale ⊙ δ, -1, 1)

where ``a_DFLQR(o)`` is the normalised ``thrust_torque`` action the DF-LQR baseline
(:class:`agents.dflqr.DFLQRPolicy`) computes from the *same* observation ``o`` the agent sees.
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
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np

from agents.dflqr import DFLQRPolicy

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


class ResidualDFLQRWrapper(gym.Wrapper):
    """Residual RL on DF-LQR: ``a = clip(a_DFLQR(o) + scale ⊙ δ, -1, 1)``.

    The action space stays ``Box(-1, 1, (4,), float32)`` and is interpreted as the residual
    ``δ``; the DF-LQR part is computed from the latest observation returned by ``reset`` /
    ``step`` (i.e. the observation the agent acted on). The env must use the
    ``thrust_torque`` action mode.

    Args:
        env: A (possibly wrapped) ``QuadSLAMEnv``.
        scale: Residual scale, a number or (4,) per component, in normalised action units.
        controller: DF-LQR controller to use; default ``DFLQRPolicy.from_env(env)``.

    Attributes:
        controller: The DF-LQR policy.
        scale: (4,) float32 residual scale.
        last_action: (4,) float32 action sent to the env on the last ``step``.

    Raises:
        ValueError: Bad ``scale`` or an env not in ``thrust_torque`` mode.
    """

    def __init__(
        self,
        env: gym.Env,
        scale: float | Sequence[float] = DEFAULT_RESIDUAL_SCALE,
        controller: DFLQRPolicy | None = None,
    ) -> None:
        super().__init__(env)
        self.scale = as_residual_scale(scale)
        self.controller = controller if controller is not None else DFLQRPolicy.from_env(env)
        self.action_space = gym.spaces.Box(-1.0, 1.0, shape=(4,), dtype=np.float32)
        self._obs: np.ndarray | None = None
        self.last_action: np.ndarray | None = None

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[Any, dict[str, Any]]:
        """Reset the env and remember the observation for the next DF-LQR command."""
        obs, info = self.env.reset(seed=seed, options=options)
        self._obs = obs
        return obs, info

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        """Apply DF-LQR(last observation) + ``scale`` × residual ``action``."""
        if self._obs is None:
            raise gym.error.ResetNeeded("ResidualDFLQRWrapper: call reset() before step()")
        residual = np.asarray(action, dtype=np.float32)
        if residual.shape != (4,):
            raise ValueError(f"residual action: got shape {residual.shape}; allowed: (4,)")
        base, _ = self.controller.predict(self._obs)
        act = residual_action(base, residual, self.scale)
        self.last_action = act
        obs, reward, terminated, truncated, info = self.env.step(act)
        self._obs = obs
        info["dflqr_action"] = base
        info["residual"] = residual
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
    unknown = set(kwargs) - {"scale"}
    if unknown:
        raise ValueError(
            f"wrapper.{sorted(unknown)[0]}: unknown key for {name}; allowed: ['scale']"
        )
    if "scale" in kwargs:
        as_residual_scale(kwargs["scale"])  # validate early, with the config's wording
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
