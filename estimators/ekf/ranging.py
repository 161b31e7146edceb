"""A range to another vehicle fused into one lane's EKF-SLAM state (docs/team-fusion.md
"Ranges between vehicles").

Vehicle i measures its distance to vehicle j, ``r = ‖ρ_i − ρ_j‖ + n``, ``n ~ N(0, σ²)``, and
vehicle j broadcasts its position estimate ``b = ρ̂_j`` with its 3×3 covariance ``P_b``. To
vehicle i, j is a beacon at an uncertain position: the measurement model on its own state is

    h(x) = ‖ρ − b‖,   H = ∂h/∂x = uᵀ on the columns of ρ (zero elsewhere),   u = (ρ − b) / h,

with the beacon's error moved into the noise to first order: ``∂h/∂b = −uᵀ``, so the beacon
adds ``uᵀ P_b u`` to the sensor's variance, ``R = σ² + uᵀ P_b u`` (the linearised measurement
noise ``H_b P_b H_bᵀ + σ²`` of an EKF update, seed 001 eq. 38).

The error of ``b`` is correlated with vehicle i's state in a way nobody knows: the vehicles
exchange ranges (and maps), so after a few of them each one's estimate holds information of the
other's. The range is therefore fused by covariance intersection exactly as a landmark message
(:func:`estimators.ekf.fusion.ci_update`: the Kalman update of ``(x, P / ω)`` with noise
``R / (1 − ω)``, ω minimising the trace of the whole fused covariance; Julier & Uhlmann 1997),
on the linearisation at the lane's mean (one first-order step, as the filter's own update).
"""

from __future__ import annotations

import math

import numpy as np

from estimators.ekf.fusion import ci_update
from estimators.ekf.kernels import D_DIVERGED
from estimators.ekf.state import EkfState
from quadslam_env.types import POS, FloatArray

MIN_RANGE_M = 1e-6
"""A predicted range below this, m, has no direction (u undefined): the range is not fused."""

_POS_IDX = np.arange(POS.start, POS.stop)
"""The columns of ρ in x."""


def range_model(position: FloatArray, beacon: FloatArray) -> tuple[float, FloatArray]:
    """The predicted range and its Jacobian (module docstring).

    Args:
        position: (3,) ρ, the lane's position, m, N frame.
        beacon: (3,) b, the other vehicle's position, m, N frame.

    Returns:
        ``(h, u)``: ``h = ‖ρ − b‖`` m and ``u = ∂h/∂ρ = (ρ − b) / h`` (3,) (unit vector).
    """
    d = np.asarray(position, dtype=float) - np.asarray(beacon, dtype=float)
    h = float(math.sqrt(float(d @ d)))
    return h, d / h if h > 0.0 else np.zeros(3)


def range_noise(u: FloatArray, sigma_m: float, beacon_cov: FloatArray) -> float:
    """``R = σ² + uᵀ P_b u`` m², the sensor's variance plus the beacon's along the line of
    sight (module docstring).

    Args:
        u: (3,) unit vector from the beacon to the lane.
        sigma_m: σ, the range noise std, m.
        beacon_cov: (3, 3) P_b, the beacon's position covariance, m².
    """
    return float(sigma_m * sigma_m + u @ np.asarray(beacon_cov, dtype=float) @ u)


def fuse_range(
    xb: FloatArray,
    Pb: FloatArray,
    nb: int,
    beacon: FloatArray,
    beacon_cov: FloatArray,
    measured_m: float,
    sigma_m: float,
) -> tuple[float, float]:
    """Fuse one range to a beacon into one lane's state by CI, in place (module docstring).

    Args:
        xb: (≥ nb,) the lane's total mean (ρ first, m, N frame).
        Pb: (≥ nb, ≥ nb) the lane's total covariance, fully symmetric (synced).
        nb: Used size n of the lane's state.
        beacon: (3,) the other vehicle's position estimate, m, N frame.
        beacon_cov: (3, 3) its covariance, m².
        measured_m: The measured range r, m.
        sigma_m: The range noise std σ, m.

    Returns:
        ``(ω, ν)``: the CI weight (NaN when not fused: a predicted range below
        :data:`MIN_RANGE_M`, or a failed update, which changes nothing) and the innovation
        ``r − h(x)``, m, at the lane's mean before the update.
    """
    h, u = range_model(xb[POS], beacon)
    nu = float(measured_m) - h
    if h < MIN_RANGE_M:
        return float("nan"), nu
    R = np.array([[range_noise(u, sigma_m, beacon_cov)]])
    omega = ci_update(xb, Pb, nb, _POS_IDX, np.array([nu]), R, "ci", u[None, :])
    return omega, nu


class RangeFusion:
    """:class:`~quadslam_env.estimation.protocol.FusesRanges` for
    :class:`~estimators.ekf.filter.EkfSlamBatch` (a mixin over its
    :class:`~estimators.ekf.state.EkfState`)."""

    fuses_ranges = True
    state: EkfState
    nv: int

    def fuse_range(
        self,
        lane: int,
        beacon: FloatArray,
        beacon_cov: FloatArray,
        measured_m: float,
        sigma_m: float,
    ) -> tuple[float, float]:
        """Fuse a range to another vehicle into lane ``lane`` (:func:`fuse_range`).

        Args:
            lane: The measuring lane.
            beacon: (3,) the other vehicle's position estimate, m, N frame.
            beacon_cov: (3, 3) its covariance, m².
            measured_m: The measured range, m.
            sigma_m: The range noise std, m.

        Returns:
            ``(ω, ν)``: the CI weight (NaN when not fused; a failed update flags the lane
            ``diverged`` and changes nothing) and the innovation, m.

        Raises:
            ValueError: ``beacon`` not (3,) or ``beacon_cov`` not (3, 3).
        """
        beacon = np.asarray(beacon, dtype=float)
        beacon_cov = np.asarray(beacon_cov, dtype=float)
        if beacon.shape != (3,) or beacon_cov.shape != (3, 3):
            raise ValueError(
                f"fuse_range: beacon got shape {beacon.shape}, beacon_cov {beacon_cov.shape}; "
                "allowed: (3,) and (3, 3)"
            )
        st = self.state
        st.sync(lane, self.nv)
        xb, Pb = st.x[lane], st.P[lane]
        omega, nu = fuse_range(xb, Pb, int(st.n[lane]), beacon, beacon_cov, measured_m, sigma_m)
        if omega != omega and range_model(xb[POS], beacon)[0] >= MIN_RANGE_M:
            st.diag[D_DIVERGED, lane] = 1.0  # the update failed
        return omega, nu
