"""``python -m estimators.ekf.compile_update``: compile and cache the EKF-SLAM update kernels.

The process that :mod:`estimators.ekf.warmup` starts on a cold numba cache.
"""

from __future__ import annotations

import numpy as np

from estimators.ekf.filter import EkfSlamBatch


def compile_update() -> None:
    """Run one labeled update of a one-lane filter: compiles and caches the update kernels
    with the argument types :meth:`EkfSlamBatch.update` always passes."""
    ekf = EkfSlamBatch(1, 1)
    lanes = np.zeros(1, dtype=np.int64)
    ekf.reset_lanes(lanes, np.zeros((1, 12)), np.eye(12)[None], [np.random.default_rng(0)])
    visible = np.ones((1, 1), dtype=bool)
    meas = np.array([[[0.1, 0.1, 5.0]]])
    ekf.update(np.zeros(1), lanes, visible, meas, np.full(3, 0.01))


if __name__ == "__main__":
    compile_update()
