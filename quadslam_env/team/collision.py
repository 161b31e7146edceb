"""Vehicle–vehicle collisions: the distances between the team's vehicles and the termination
of two that come closer than ``team.collision_radius_m`` (docs/team.md).

:class:`Collisions` is the core's check across lanes (:data:`quadslam_env.core.LaneCheck`): it
runs after the single env's termination checks, on the true positions after the step, so the
reward's termination penalty and the episode summaries of a vehicle it ends are the core's own.
"""

from __future__ import annotations

import math

import numpy as np

from quadslam_env.types import POS, FloatArray

COLLISION = "vehicle_collision: vehicle_{other}"
"""The termination reason of a vehicle that came within the radius of ``vehicle_{other}``
(the nearest one)."""


def pair_distances(pos: FloatArray, lanes: np.ndarray) -> FloatArray:
    """Distances between the vehicles of ``lanes``.

    Args:
        pos: (B, 3) true positions, N frame m.
        lanes: (B,) bool, the vehicles to compare.

    Returns:
        (B, B) distances in m; ``inf`` on the diagonal and in the rows and columns of the
        vehicles outside ``lanes`` (NaN where a position is not finite).
    """
    diff = pos[:, None, :] - pos[None, :, :]
    dist = np.sqrt(np.einsum("ijk,ijk->ij", diff, diff))
    outside = ~(lanes[:, None] & lanes[None, :])
    np.fill_diagonal(outside, True)
    dist[outside] = math.inf
    return dist


def min_separation(pos: FloatArray, lanes: np.ndarray) -> float:
    """The smallest distance between two vehicles of ``lanes`` (B,) bool at the positions
    ``pos`` (B, 3) N frame m, in m; NaN with fewer than two (or at a non-finite position)."""
    if np.count_nonzero(lanes) < 2:
        return math.nan
    return float(np.min(pair_distances(pos, lanes)))


class Collisions:
    """End the vehicles closer than ``radius_m`` to another one stepped now.

    Args:
        radius_m: ``team.collision_radius_m``, m (> 0).
    """

    def __init__(self, radius_m: float) -> None:
        self.radius_m = float(radius_m)

    def __call__(
        self,
        state: FloatArray,
        active: np.ndarray,
        terminated: np.ndarray,
        truncated: np.ndarray,
        reasons: list[str],
    ) -> bool:
        """Terminate each active vehicle within the radius of another active one.

        A vehicle that an earlier check ended keeps its reason (and still ends the others
        within its radius); one that reached the time limit now is terminated instead.

        Args:
            state: (B, 12) true states.
            active: (B,) bool, the vehicles stepped now.
            terminated, truncated: (B,) bool, updated in place.
            reasons: B termination reasons, updated in place (:data:`COLLISION`).

        Returns:
            Whether a vehicle that went on ends here.
        """
        dist = pair_distances(state[:, POS], active)
        hit = (dist < self.radius_m).any(axis=1)
        ended = False
        for lane in np.flatnonzero(hit & ~terminated).tolist():
            reasons[lane] = COLLISION.format(other=int(np.nanargmin(dist[lane])))
            terminated[lane] = True
            truncated[lane] = False
            ended = True
        return ended
