"""The NIS loss-of-lock check of the FastSLAM filters (:class:`~.particles.FastSLAMBase`)."""

from __future__ import annotations

from typing import Any

import numpy as np

from quadslam_env.types import FloatArray


def check_lock(filt: Any, nis_per_dof: FloatArray) -> None:
    """NIS-based loss-of-lock flag of a FastSLAM filter ``filt`` (sticky until its ``reset``).

    ``nis_per_dof`` (N,) is each particle's LiDAR NIS per degree of freedom. The mean over
    the best 10 % of particles (lowest NIS) is ≈ 1 while the filter is locked; if it stays
    above ``nis_divergence`` for ``nis_divergence_s`` seconds of filter time no particle
    explains the scans any more (the weights are then only relative and the estimate is
    silently wrong), so ``diagnostics["diverged"]`` is set. ``nis_divergence = 0`` disables
    the check.
    """
    k = max(1, filt.n_particles // 10)
    best = float(np.mean(np.partition(nis_per_dof, k - 1)[:k]))
    filt._best_nis = best
    if filt.nis_divergence <= 0.0:
        return
    if not best > filt.nis_divergence:  # also catches NaN as "not high"
        filt._nis_high_since = None
        return
    if filt._nis_high_since is None:
        filt._nis_high_since = filt._time
    if filt._time - filt._nis_high_since >= filt.nis_divergence_s:
        if not filt._lost:
            filt.n_divergences += 1
        filt._lost = True
        filt._diverged = True
