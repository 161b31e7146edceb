"""Optional dependencies: a clear one-line error naming the extra that brings a missing one.

``pip install quadslam`` gives every env id, the estimators and the DF-LQR baseline with numpy,
numba, scipy, gymnasium, PyYAML and tqdm only. Rendering and figures need ``quadslam[plots]``
(matplotlib); training and loading agents need ``quadslam[rl]`` (stable-baselines3, torch,
tensorboard, matplotlib for the learning curves); sweeps ``quadslam[ray]``.
"""

from __future__ import annotations

import importlib
from types import ModuleType


class MissingExtraError(ValueError):
    """An optional dependency is not installed; the message names the extra to install."""


def require(module: str, extra: str, what: str) -> ModuleType:
    """Import ``module`` or say in one line which extra brings it.

    Args:
        module: The module to import, e.g. ``"matplotlib"``.
        extra: The ``quadslam[...]`` extra that installs it, e.g. ``"plots"``.
        what: What needs it, e.g. ``"render_mode='rgb_array'"``.

    Raises:
        MissingExtraError: ``module`` cannot be imported.
    """
    try:
        return importlib.import_module(module)
    except ImportError:
        raise MissingExtraError(
            f"{what} needs {module.split('.')[0]}, which is not installed; install it with: "
            f"pip install 'quadslam[{extra}]'"
        ) from None
