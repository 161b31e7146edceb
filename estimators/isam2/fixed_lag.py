"""iSAM2 over a sliding window, with the elimination order a sliding-window filter uses and the
marginalisation batched with the relinearisation (docs/isam2.md, "Solver").

GTSAM's ``IncrementalFixedLagSmoother`` constrains only the variables it is about to marginalise
and orders the rest by CCOLAMD. In landmark SLAM every keyframe sees part of the map, so CCOLAMD
spreads the landmarks through the Bayes tree; a new keyframe's LiDAR factors then touch cliques
deep in it, and iSAM2 re-eliminates nearly the whole window at every keyframe (measured on the
paper's figure of eight with a 3 s window: ~100 of ~115 variables, 9 ms per keyframe). So does
the relinearisation of an old keyframe (the path from it to the root).

Here every update constrains the order by timestamp, in three groups: the variables about to
leave the window first, the newest keyframe with the landmarks (which the estimator re-stamps at
every keyframe, so they never leave) last, the rest between. A new keyframe's factors then touch
the root clique only. The relinearisation (of every variable whose linear step exceeds the
threshold, Kaess et al. 2012, Alg. 6) and the marginalisation happen together every
``every`` keyframes: that update re-eliminates the whole window with the variables older than
the lag first, which makes them leaves of the Bayes tree, and ``ISAM2.marginalizeLeaves`` then
keeps their linear marginal as a factor on their neighbours, as GTSAM's smoother does. The window
so holds between ``lag`` and ``lag`` plus ``every − 1`` keyframe periods of vehicle states.
"""

from __future__ import annotations

import math
from typing import Any


class FixedLagIsam2:
    """iSAM2 over a window of ``lag`` seconds (or the whole graph), ordered by timestamp.

    The interface is the part of ``gtsam.IncrementalFixedLagSmoother`` the estimator uses.

    Args:
        gtsam: The ``gtsam`` module.
        lag: Window length in s: every ``every`` updates, the variables whose timestamps are
            more than ``lag`` before the newest are marginalised. ``None``: never (full graph).
        params: ``gtsam.ISAM2Params``; its own relinearisation schedule is switched off
            (this class asks for relinearisation every ``every`` updates).
        every: Updates between two relinearisations (and marginalisations), ≥ 1.
    """

    def __init__(self, gtsam: Any, lag: float | None, params: Any, every: int) -> None:
        self._g = gtsam
        self.lag = lag
        self.every = every
        params.enableRelinearization = False  # relinearised on this class's schedule
        self.isam = gtsam.ISAM2(params)
        self._stamps: dict[int, float] = {}
        self._updates = 0

    def update(
        self, graph: Any = None, values: Any = None, stamps: dict[int, float] | None = None
    ) -> None:
        """One iSAM2 update with the new factors and values, relinearised and followed by the
        marginalisation every ``every`` calls; without factors, one more relinearised
        iteration (``iterations`` > 1).

        Args:
            graph: ``NonlinearFactorGraph`` of the new factors (``None``: an iteration).
            values: ``Values`` of the new variables.
            stamps: Each new or re-stamped key's time in s (the smoother's clock).

        Raises:
            RuntimeError: GTSAM's exceptions (an indeterminate system).
        """
        g = self._g
        if graph is None:
            self.isam.update(g.NonlinearFactorGraph(), g.Values(), force_relinearize=True)
            return
        # Every stamped key must be (or enter here as) a variable of iSAM2: a group names
        # only existing keys (GTSAM raises on an unknown one in a batch step). The estimator
        # stamps exactly the keys of its new values and its landmarks.
        self._stamps.update(stamps or {})
        self._updates += 1
        newest = max(self._stamps.values())
        if self._updates % self.every:
            # iSAM2 re-eliminates at least the new factors' variables.
            groups = self._groups(newest, -math.inf, graph.keys().size())
            self.isam.update(graph, values, [], groups)
            return
        cutoff = newest - self.lag if self.lag is not None else -math.inf
        old = [key for key, t in self._stamps.items() if t < cutoff]
        # Relinearised and, with variables to drop, re-eliminated whole (a batch step of
        # iSAM2) with the old ones first: they become leaves of the Bayes tree.
        window = g.KeyList()
        for key in self._stamps if old else ():
            if self.isam.valueExists(key):  # (the new ones enter with this update)
                window.push_back(key)
        groups = self._groups(newest, cutoff, len(self._stamps) if old else graph.keys().size())
        self.isam.update(graph, values, [], groups, None, window, True)
        if old:
            leaves = g.KeyList()
            for key in old:
                leaves.push_back(key)
                del self._stamps[key]
            self.isam.marginalizeLeaves(leaves)

    def _groups(self, newest: float, cutoff: float, eliminated: int) -> Any:
        """The order constraint: group 0 before ``cutoff``, 2 at ``newest``, 1 between.

        iSAM2 applies the groups to the variables it re-eliminates, and CCOLAMD needs every
        group number below their count (a larger one crashes it), so with fewer than three
        variables surely re-eliminated (``eliminated``) the groups merge: two (newest last),
        or none (iSAM2's own order)."""
        if eliminated < 2:
            return None
        groups = self._g.KeyGroupMap()
        for key, t in self._stamps.items():
            if eliminated == 2:
                groups.insert2(key, 1 if t >= newest else 0)
            else:
                groups.insert2(key, 0 if t < cutoff else 2 if t >= newest else 1)
        return groups

    def calculateEstimate(self) -> Any:  # noqa: N802  (GTSAM's name)
        """The current estimate of every variable in the window (``gtsam.Values``)."""
        return self.isam.calculateEstimate()

    def getISAM2(self) -> Any:  # noqa: N802  (GTSAM's name)
        """The ``gtsam.ISAM2`` holding the window."""
        return self.isam
