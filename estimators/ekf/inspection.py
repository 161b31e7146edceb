"""Read and write one lane of :class:`~estimators.ekf.filter.EkfSlamBatch` whole: its total
state, covariance and stacked observation model (for tests, debugging and analyses)."""

from __future__ import annotations

import numpy as np

from estimators.ekf.state import EkfState
from estimators.ekf.update import stacked_model
from quadslam_env.types import FloatArray

_AR3 = np.arange(3)


class FilterInspection:
    """Mixin of :class:`~estimators.ekf.filter.EkfSlamBatch` (reads and writes its
    :class:`~estimators.ekf.state.EkfState`)."""

    state: EkfState
    nv: int

    def full_state(self, lane: int = 0) -> tuple[FloatArray, FloatArray, np.ndarray]:
        """Copies of one lane's total mean x (n,), covariance P (n, n) and the mapped ids in
        slot order (landmark slot j occupies ``x[nv + 3j : nv + 3j + 3]``)."""
        n = int(self.state.n[lane])
        self.state.sync(lane, self.nv)
        n_mapped = (n - self.nv) // 3
        return (
            self.state.x[lane, :n].copy(),
            self.state.P[lane, :n, :n].copy(),
            self.state.id_of_slot[lane, :n_mapped].copy(),
        )

    def set_full_state(self, x: FloatArray, P: FloatArray, lane: int = 0) -> None:
        """Overwrite one lane's total mean and covariance (same size n as the current state).

        Raises:
            ValueError: On a shape mismatch or non-finite values.
        """
        n = int(self.state.n[lane])
        x = np.asarray(x, dtype=float)
        P = np.asarray(P, dtype=float)
        if x.shape != (n,) or P.shape != (n, n):
            raise ValueError(f"set_full_state: expected x ({n},) and P ({n}, {n})")
        if not (np.isfinite(x).all() and np.isfinite(P).all()):
            raise ValueError("set_full_state: x and P must be finite")
        self.state.x[lane, :n] = x
        self.state.P[lane, :n, :n] = P
        self.state.stale[lane] = False

    def stacked_measurement(
        self, ids: np.ndarray, lane: int = 0
    ) -> tuple[np.ndarray, FloatArray, FloatArray]:
        """Stacked observation model of one lane's mapped/known landmarks ``ids`` (eq. 34, 40).

        Args:
            ids: (k,) landmark ids; all must be mapped (or in the known map).
            lane: Lane index.

        Returns:
            ``(cols, h, H)``: ``cols`` (d,) the columns of x the model depends on
            (``[s, m_κ]``, d = 9 + 3k; only s in known-map mode), ``h`` (3k,) the predicted
            measurements (α, β, δ per landmark) and ``H`` (3k, d) = ``∂h/∂x[cols]``.

        Raises:
            KeyError: If an id is not mapped (or known).
        """
        ids = np.asarray(ids, dtype=np.int64).reshape(-1)
        for i in ids.tolist():
            if not (0 <= i < self.state.landmark_capacity and self.state.mapped[lane, i]):
                raise KeyError(i)
        x = self.state.x[lane]
        if self.state.known[lane]:
            lms, lm_cols = self.state.known_pos[lane, ids], None
        else:
            lm_cols = (self.nv + 3 * self.state.slot_of_id[lane, ids][:, None] + _AR3).ravel()
            lms = x[lm_cols].reshape(-1, 3)
        return stacked_model(x, lms, lm_cols)
