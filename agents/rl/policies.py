"""Load a policy by name or path for evaluation: a baseline controller by name
(:data:`agents.control.named.CONTROLLERS`) or a saved stable-baselines3 model."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from agents.control.named import CONTROLLERS, build_controller, controller_options


def load_policy(
    spec: str,
    env: Any,
    *,
    trust_pickle: bool = False,
    options: Mapping[str, Any] | None = None,
) -> tuple[Any, str]:
    """Return ``(policy, name)`` for ``spec``.

    Args:
        spec: A controller name (``"dflqr"``, ``"lqi"``, ``"se3"``), a run folder written by
            ``quadslam train`` or a model ``.zip``.
        env: The evaluation env (its spaces must match the model's).
        trust_pickle: Let a model without its arrays be read from SB3's pickles
            (:func:`agents.rl.loading.load_model`).
        options: The controller's options (:func:`agents.control.named.build_controller`'s
            ``drag_feedforward``, ``thrust_adaptation``); a trained model takes none.

    Raises:
        FileNotFoundError: The path does not exist.
        ValueError: The file is not a model for this env, or an option the policy does not
            take (:func:`agents.control.named.controller_options`).
    """
    given = dict(options or {})
    if spec in CONTROLLERS:
        return build_controller(spec, env, **given), spec
    controller_options(spec, **given)  # a trained model takes none: refused here
    from agents.rl.loading import load_model

    path = Path(spec)
    if not path.exists():
        raise FileNotFoundError(
            f"--policy: {spec!r} is neither a controller name ({', '.join(sorted(CONTROLLERS))}) "
            "nor an existing path"
        )
    return load_model(path, env, trust_pickle=trust_pickle), str(path)
