"""Lane bookkeeping shared by the simulated sensors (:mod:`quadslam_env.sim.imu`,
:mod:`quadslam_env.sim.lidar`): lane index arrays and each lane's generator."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

LANE0 = np.zeros(1, dtype=int)
"""The lane indices ``[0]`` of a one-lane sensor."""


def lane_indices(lanes: ArrayLike) -> np.ndarray:
    """(k,) int lane indices from any array-like."""
    return np.asarray(lanes, dtype=int).reshape(-1)


def lane_generators(
    current: list[np.random.Generator | None], lanes: np.ndarray, who: str
) -> list[np.random.Generator]:
    """The generators of ``lanes`` (k,) from ``current`` (B,).

    Raises:
        RuntimeError: A lane has no generator yet (used before its reset); ``who`` names the
            sensor in the message.
    """
    gens = [current[i] for i in lanes.tolist()]
    missing = [i for i, g in zip(lanes.tolist(), gens, strict=True) if g is None]
    if missing:
        raise RuntimeError(f"{who}: lanes {missing} were used before reset() gave them a generator")
    return gens
