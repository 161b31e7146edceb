"""IMU noise parameters: white-noise density → per-sample σ, exact Gauss–Markov drift.

Seed 000 eq. 5–11 and docs/design.md §3. The simulated IMU (:mod:`quadslam_env.sim.imu`) and the
FastSLAM bias Kalman filter (:mod:`estimators.fastslam.bias_kf`) both discretise with these
functions, so the filter's model is the simulator's model.
"""

from __future__ import annotations

import math


def white_noise_sigma(noise_density: float, rate_hz: float) -> float:
    """Per-sample standard deviation ``σ = ND · √f_s`` of white noise.

    Args:
        noise_density: ND in unit/√Hz (m/s²/√Hz for the accelerometer, rad/s/√Hz for the gyro).
        rate_hz: Sample rate f_s in Hz.

    Returns:
        σ per sample in the sensor unit.
    """
    return noise_density * math.sqrt(rate_hz)


def gauss_markov_discretisation(dt: float, tau: float) -> tuple[float, float]:
    """Exact discretisation of the first-order Gauss–Markov drift ``ḃ = −b/τ + w``.

    Over ``dt`` s, ``b ← a b + N(0, σ² (1 − a²))`` with ``a = e^{−dt/τ}`` and σ the stationary
    standard deviation (seed 000 eq. 8, 10 use the first-order ``1 − dt/τ``; the two agree to
    O(dt/τ)).

    Args:
        dt: Sample period in s.
        tau: Correlation time τ in s (> 0).

    Returns:
        ``(a, 1 − a²)``: the decay factor and the variance factor of the driving noise.
    """
    decay = math.exp(-dt / tau)
    return decay, 1.0 - decay * decay
