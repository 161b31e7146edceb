"""The NIS loss-of-lock check of the FastSLAM filters (:class:`~.particles.FastSLAMBase`)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from quadslam_env.types import FloatArray


@dataclass
class LockMonitor:
    """NIS-based loss-of-lock flag of one FastSLAM filter (sticky until the filter's reset).

    The mean NIS per degree of freedom over the best 10 % of particles (lowest NIS) is ≈ 1
    while the filter is locked; if it stays above ``threshold`` for ``hold_s`` seconds of filter
    time no particle explains the scans any more (the weights are then only relative and the
    estimate is silently wrong), so the filter reports ``diagnostics["diverged"]``.
    ``threshold = 0`` disables the check. The two settings stay the filter's
    (``nis_divergence``, ``nis_divergence_s``) and come with each call.

    Attributes:
        n_particles: N.
        best_nis: The last best-10 % mean NIS per degree of freedom (NaN before a scan).
        high_since: Filter time (s) since which it has stayed above ``threshold``, or ``None``.
        lost: Whether the lock is lost.
    """

    n_particles: int
    best_nis: float = math.nan
    high_since: float | None = None
    lost: bool = False

    def check(self, nis_per_dof: FloatArray, t: float, threshold: float, hold_s: float) -> bool:
        """Take one scan's NIS per degree of freedom (N,) at filter time ``t`` (s).

        Args:
            nis_per_dof: (N,) each particle's LiDAR NIS per degree of freedom.
            t: Filter time in s.
            threshold: ``nis_divergence``, NIS per degree of freedom (0: no check).
            hold_s: ``nis_divergence_s``, s.

        Returns:
            Whether the lock was lost at this call (``lost`` turned true now).
        """
        k = max(1, self.n_particles // 10)
        self.best_nis = float(np.mean(np.partition(nis_per_dof, k - 1)[:k]))
        if threshold <= 0.0:
            return False
        if not self.best_nis > threshold:  # also catches NaN as "not high"
            self.high_since = None
            return False
        if self.high_since is None:
            self.high_since = t
        if t - self.high_since < hold_s or self.lost:
            return False
        self.lost = True
        return True
