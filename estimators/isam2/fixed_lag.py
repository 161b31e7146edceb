"""iSAM2 over a sliding window kept in the order of a sliding-window filter, so that the states
leaving it are leaves of the Bayes tree without a batch step (docs/isam2.md, "A sliding window
ordered by time").

GTSAM's ``IncrementalFixedLagSmoother`` constrains only the variables it is about to marginalise
and orders the rest by CCOLAMD. In landmark SLAM every keyframe sees part of the map, so CCOLAMD
spreads the landmarks through the Bayes tree; a new keyframe's LiDAR factors then touch cliques
deep in it, and iSAM2 re-eliminates nearly the whole window at every keyframe (measured on the
paper's figure of eight with a 3 s window: ~100 of ~115 variables, 9 ms per keyframe).

Here the variables are ordered by time: one CCOLAMD group per timestamp, oldest first, and the
variables without a stamp, which never leave the window (the landmarks), in a last group.

* Every ``every`` updates (and for an iteration without new factors) the update relinearises
  (every variable whose linear step exceeds the threshold, Kaess et al. 2012, Alg. 6) and
  re-eliminates the whole window in that order (a batch step of iSAM2): every variable's
  ancestors in the Bayes tree are then later ones or landmarks.
* The other updates re-eliminate only the cliques their new factors reach, the root clique
  and the newest keyframe's. They keep that property: the re-eliminated top is ordered by time
  (the groups of the newest timestamps, as many as CCOLAMD accepts for the variables of the new
  factors), and a subtree left in place hangs below the first-eliminated variable of its
  separator, whose ancestors it already had.
* So the states older than the lag are normally leaves, and every :data:`MARGINALIZE_EVERY`
  updates ``ISAM2.marginalizeLeaves`` replaces them by their linear marginal on their
  neighbours, as GTSAM's smoother does. GTSAM checks that they are leaves in its debug builds
  only (a release build corrupts its memory), so this class checks it on the Bayes tree
  (``ISAM2.dot``, the only view of the tree the bindings give) and, if a deeper update broke
  the order, first re-eliminates the window in time order.

The window so holds ``lag`` seconds of states plus up to ``MARGINALIZE_EVERY − 1`` updates'
worth.
"""

from __future__ import annotations

import re
from typing import Any

# A clique of ISAM2.dot(): 'id[label="frontal, ... : separator, ..."];' (no ':' at the root).
_CLIQUE = re.compile(r'^(\d+)\[label="([^":]*)', re.MULTILINE)
_EDGE = re.compile(r"^(\d+)->(\d+)$", re.MULTILINE)

MARGINALIZE_EVERY = 5
"""Updates between two marginalisations: each checks the Bayes tree (~0.35 ms on the paper's
figure of eight), so the window holds ``lag`` to ``lag`` plus four keyframe periods."""


class FixedLagIsam2:
    """iSAM2 over a window of ``lag`` seconds (or the whole graph), ordered by time.

    The interface is the part of ``gtsam.IncrementalFixedLagSmoother`` the estimator uses; only
    the states have timestamps (the variables without one are kept).

    Args:
        gtsam: The ``gtsam`` module.
        lag: Window length in s: every :data:`MARGINALIZE_EVERY` updates, the stamped
            variables more than ``lag`` before the newest are marginalised. ``None``: never
            (full graph).
        params: ``gtsam.ISAM2Params``; its own relinearisation schedule is switched off
            (this class asks for relinearisation every ``every`` updates).
        every: Updates between two relinearisations, ≥ 1.
    """

    def __init__(self, gtsam: Any, lag: float | None, params: Any, every: int) -> None:
        self._g = gtsam
        self.lag = lag
        self.every = every
        params.enableRelinearization = False  # relinearised on this class's schedule
        # A marginalisation removes factors; without this their slots stay, empty, for ever
        # (GTSAM's own fixed-lag smoother sets it too).
        params.findUnusedFactorSlots = lag is not None
        self.isam = gtsam.ISAM2(params)
        self._stamps: dict[int, float] = {}
        self._kept: set[int] = set()  # the variables without a stamp
        self._updates = 0
        self.repairs = 0
        """Whole-window re-eliminations made because the states to marginalise were not
        leaves."""

    def update(
        self, graph: Any = None, values: Any = None, stamps: dict[int, float] | None = None
    ) -> None:
        """One iSAM2 update with the new factors and values (relinearised every ``every``
        calls), then, every :data:`MARGINALIZE_EVERY` calls, the marginalisation of the states
        older than the lag; without factors, one more relinearised iteration (``iterations``
        > 1).

        Args:
            graph: ``NonlinearFactorGraph`` of the new factors (``None``: an iteration).
            values: ``Values`` of the new variables.
            stamps: Each new state's time in s (the smoother's clock). A new variable
                without a stamp (a landmark) never leaves the window and is eliminated after
                every state.

        Raises:
            RuntimeError: GTSAM's exceptions (an indeterminate system).
            ValueError: A stamp for a variable that has one.
        """
        g = self._g
        if graph is None:
            self._update(g.NonlinearFactorGraph(), g.Values(), {}, True)
        else:
            stamps = stamps or {}
            for key in stamps:
                if key in self._stamps:  # a later stamp could put the state below newer ones
                    raise ValueError(
                        f"FixedLagIsam2.update: key {key} already has a stamp; a state's stamp "
                        "is fixed (leave the variables that stay, the landmarks, unstamped)"
                    )
            self._updates += 1
            self._update(graph, values, stamps, self._updates % self.every == 0)
            if self._updates % MARGINALIZE_EVERY == 0:
                self._marginalize()

    def _update(self, graph: Any, values: Any, stamps: dict[int, float], relinearize: bool) -> None:
        """One iSAM2 update ordered by time; relinearised, it re-eliminates the whole window
        (with a lag: the order the marginalisation needs is then restored)."""
        window = None
        if relinearize and self.lag is not None:
            window = self._g.KeyList()
            for key in [*self._stamps, *self._kept]:
                window.push_back(key)
        new = list(values.keys())
        self._add(new, stamps)
        # CCOLAMD needs every group number below the count of the variables it orders (a
        # larger one crashes it): all of them in a batch step, else at least the variables of
        # the new factors.
        top = None if window is not None else len({*graph.keys(), *new}) - 2
        self.isam.update(graph, values, [], self._groups(top), None, window, relinearize)

    def _add(self, new: list[int], stamps: dict[int, float]) -> None:
        self._stamps.update(stamps)
        self._kept.update(key for key in new if key not in stamps)

    def _groups(self, top: int | None) -> Any:
        """The order constraint: group ``r`` for the ``r``-th oldest timestamp, the kept
        variables after all. With ``top``, only the newest timestamps get groups of their own
        (the newest ``top``, the older ones down to 0 and then all 0) and the kept ones
        ``top + 1``; ``top`` below zero gives ``None`` (iSAM2's own order)."""
        times = sorted(set(self._stamps.values()))
        if top is None:
            top = len(times) - 1
        elif top < 0:
            return None
        shift = len(times) - 1 - top
        rank = {t: max(r - shift, 0) for r, t in enumerate(times)}
        groups = self._g.KeyGroupMap()
        for key, t in self._stamps.items():
            if rank[t]:  # CCOLAMD puts a variable without a group in group 0
                groups.insert2(key, rank[t])
        for key in self._kept:
            groups.insert2(key, top + 1)
        return groups

    def _marginalize(self) -> None:
        """Marginalise the states older than the lag, leaves of the Bayes tree (re-eliminating
        the window in time order first if they are not)."""
        if self.lag is None or not self._stamps:
            return
        cutoff = max(self._stamps.values()) - self.lag
        old = [key for key, t in self._stamps.items() if t < cutoff]
        if not old:
            return
        if not self._are_leaves(old):
            self.repairs += 1
            self._update(self._g.NonlinearFactorGraph(), self._g.Values(), {}, True)
            if not self._are_leaves(old):
                raise RuntimeError(
                    "FixedLagIsam2: the states older than the lag are not leaves of the Bayes "
                    "tree after re-eliminating the window in time order"
                )
        leaves = self._g.KeyList()
        for key in old:
            leaves.push_back(key)
            del self._stamps[key]
        self.isam.marginalizeLeaves(leaves)

    def _are_leaves(self, keys: list[int]) -> bool:
        """Whether ``keys`` can leave by ``marginalizeLeaves``: below a clique with one of them
        every clique holds only such keys (checked edge by edge: a child of such a clique holds
        one, so its own children are checked too), and in a clique with others they are its
        first frontals (eliminated first: what GTSAM splits off)."""
        fmt = self._g.DefaultKeyFormatter
        leaving = {fmt(key) for key in keys}
        text = self.isam.dot()
        holds: dict[str, bool] = {}  # clique → holds a leaving key
        whole: set[str] = set()  # the cliques of leaving keys only
        for clique, label in _CLIQUE.findall(text):
            flags = [name in leaving for name in label.strip().split(", ")]
            n = sum(flags)
            if not all(flags[:n]):
                return False  # a leaving key after one that stays
            holds[clique] = n > 0
            if n == len(flags):
                whole.add(clique)
        for parent, child in _EDGE.findall(text):
            if holds[parent] and child not in whole:
                return False
        return True

    def calculateEstimate(self) -> Any:  # noqa: N802  (GTSAM's name)
        """The current estimate of every variable in the window (``gtsam.Values``)."""
        return self.isam.calculateEstimate()

    def getISAM2(self) -> Any:  # noqa: N802  (GTSAM's name)
        """The ``gtsam.ISAM2`` holding the window."""
        return self.isam
