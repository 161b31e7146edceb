"""The IMU samples since the smoother's latest keyframe, kept so that a scan measured in the past
(a delayed LiDAR, ``lidar.delay_steps``) gets its keyframe at its own time (docs/isam2.md,
"A delayed LiDAR").

Every sample is preintegrated into the IMU factor from the latest keyframe (Forster et al.
2017, eq. 24–26) and kept with its time. When a scan of time ``t_s`` arrives after samples
measured later than ``t_s``, the samples up to ``t_s`` are preintegrated afresh, in the same
order and from the same bias, into the factor of the scan's keyframe, and those after
``t_s`` start the next interval at the new keyframe's smoothed bias once that keyframe is
solved. The smoother so sees the same factors, in the same order, as when each scan arrives at
its own time, and the estimate is the new keyframe propagated to the present. A scan at the
time of the latest sample (no delay) takes the running preintegration as it is.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from estimators.isam2.graph import preintegration_params
from estimators.isam2.settings import Isam2Settings
from quadslam_env.types import FloatArray


@dataclass(frozen=True)
class KeptSample:
    """One IMU sample as the smoother preintegrated it.

    Attributes:
        t: The sample's time in s (``ImuSample.t``: the end of its period).
        accel: (3,) specific force in m/s², B.
        gyro: (3,) rates in rad/s, B.
        accel_sigma: White-noise std of ``accel`` per step ``dt`` (m/s²).
        gyro_sigma: White-noise std of ``gyro`` per step ``dt`` (rad/s).
        dt: The period the sample is held over, s.
        clock: The smoother's clock after the sample (the sum of the periods since reset),
            s: the time stamp of a keyframe placed right after it.
    """

    t: float
    accel: FloatArray
    gyro: FloatArray
    accel_sigma: float
    gyro_sigma: float
    dt: float
    clock: float


class ImuHistory:
    """Mixin of :class:`~estimators.isam2.estimator.Isam2Slam`: its preintegration and the
    samples kept since the latest keyframe (module docstring)."""

    settings: Isam2Settings
    _g: Any
    _pim: Any
    _kf_bias: Any
    _kf_t: float
    _t: float
    _kept: list[KeptSample]
    _params: Any
    _pim_noise: tuple[float, float] | None

    def _preintegration_params(self, accel_sigma: float, gyro_sigma: float, dt: float) -> Any:
        """GTSAM preintegration settings for samples with the white-noise stds
        ``accel_sigma`` (m/s²) and ``gyro_sigma`` (rad/s) per step ``dt`` (cached;
        :func:`~estimators.isam2.graph.preintegration_params`)."""
        noise = (float(accel_sigma) ** 2 * dt, float(gyro_sigma) ** 2 * dt)
        if self._params is not None and self._pim_noise == noise:
            return self._params
        p = preintegration_params(self._g, self.settings, *noise)
        self._params, self._pim_noise = p, noise
        return p

    def _preintegrate(self, pim: Any, sample: KeptSample) -> Any:
        """``pim`` (``None``: a new one at the latest keyframe's bias) with ``sample`` added."""
        if pim is None:
            params = self._preintegration_params(sample.accel_sigma, sample.gyro_sigma, sample.dt)
            pim = self._g.PreintegratedCombinedMeasurements(params, self._kf_bias)
        accel = sample.accel
        if self.settings.thrust_axis_accel:  # EKF-SLAM's model: the thrust axis only
            accel = np.array([0.0, 0.0, accel[2]])
        # The sample is a specific force held in B over its period while B turns at the rate
        # ω; its velocity increment is ΔR ∫₀^dt Exp(ωτ) dτ a = ΔR J_l(ω dt) a dt (exact for
        # constant ω and a; J_l the left Jacobian of SO(3), GTSAM's ExpmapDerivative(−φ)).
        # GTSAM's rule takes ΔR a dt, the orientation at the period's start: a velocity error
        # of |a| |ω| dt²/2 per sample, about 6 mm/s after the take-off's first 0.1 rad of pitch.
        # Both at the preintegration's bias (GTSAM subtracts b_a after the turn). GTSAM's
        # first-order bias correction misses the turn's own dependence on b_g: about a tenth
        # of its ∂Δv/∂b_g over a 0.1 s interval, applied to the bias change only.
        bias = pim.biasHat()
        b_a = np.asarray(bias.accelerometer(), dtype=float)
        turn = self._g.Rot3.ExpmapDerivative(-sample.dt * (sample.gyro - bias.gyroscope()))
        pim.integrateMeasurement(b_a + turn @ (accel - b_a), sample.gyro, sample.dt)
        return pim

    def _until(self, t_scan: float) -> tuple[Any, float, int]:
        """The preintegration from the latest keyframe to a scan of time ``t_scan`` s.

        A sample belongs before the scan when it was measured no later than half its period
        after ``t_scan`` (the scan's and the sample's clocks are the same instants computed
        two ways, which may differ by rounding).

        Returns:
            ``(pim, stamp, n)``: the preintegration of the first ``n`` kept samples (the
            running one when all of them are before the scan; ``None`` when none is), the
            smoother's clock at the scan in s, and ``n``.
        """
        kept = self._kept
        n = len(kept)
        while n and kept[n - 1].t > t_scan + 0.5 * kept[n - 1].dt:
            n -= 1
        if n == len(kept):
            return self._pim, self._t, n
        pim = None
        for sample in kept[:n]:
            pim = self._preintegrate(pim, sample)
        return pim, kept[n - 1].clock if n else self._kf_t, n

    def _resume(self, n: int, stamp: float) -> None:
        """After the keyframe at the clock ``stamp`` s: drop the first ``n`` kept samples (now
        in its IMU factor) and preintegrate the others from its bias (the present)."""
        self._kf_t = stamp
        self._kept = self._kept[n:]
        for sample in self._kept:  # the rates stay the latest sample's, as the keyframe set
            self._pim = self._preintegrate(self._pim, sample)
