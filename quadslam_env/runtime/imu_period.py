"""The IMU samples of one control period of B lanes (docs/timing.md "IMU rate").

:class:`~quadslam_env.core.SimCore` flies the vehicle over a control period and hands the
estimator that period's IMU samples (:data:`~quadslam_env.runtime.period_log.Sample`): at or below
the control rate one sample, taken after the period (an IMU m times slower samples every m-th step
and holds it, :meth:`~quadslam_env.sim.imu.ImuBatch.sample_held`); an IMU m times faster is sampled
after each of the m sub-periods the vehicle is integrated over (command held).
"""

from __future__ import annotations

import numpy as np

from quadslam_env.runtime.period_log import Sample
from quadslam_env.sim.imu import ImuBatch
from quadslam_env.sim.vehicle import VehicleBatch
from quadslam_env.types import FloatArray


def period_sample(
    vehicle: VehicleBatch,
    imu: ImuBatch,
    t: FloatArray,
    rates: FloatArray,
    steps: np.ndarray,
    steps_per_imu: int,
    active: np.ndarray,
) -> Sample:
    """The IMU input of the control period just flown (IMU at or below the control rate).

    Args:
        vehicle: The lanes' vehicles, at the end of the period.
        imu: The lanes' IMUs.
        t: (B,) lane times at the end of the period, s.
        rates: (B, 3) true body rates averaged over the period, rad/s.
        steps: (B,) int control steps since each lane's reset, this period counted.
        steps_per_imu: Control steps per IMU sample (1: the control rate).
        active: (B,) bool lanes that flew the period.

    Returns:
        ``(t (B,), accel (B, 3), gyro (B, 3), thrust (B,), torque (B, 3))``: the sample
        taken now, or (slower IMU) the latest one held.
    """
    vel = vehicle.air_velocity()
    if steps_per_imu == 1:
        accel, gyro = imu.sample(t, vel, rates, vehicle.applied_thrust, active)
    else:
        imu.accumulate(vel, rates, vehicle.applied_thrust, active)
        due = active & (steps % steps_per_imu == 0)
        if due.any():
            imu.sample_held(t, due)
        accel, gyro = imu.held_accel, imu.held_gyro
    return t, accel, gyro, vehicle.applied_thrust, vehicle.applied_torque


def fast_period_samples(
    vehicle: VehicleBatch,
    imu: ImuBatch,
    t: FloatArray,
    period_s: float,
    per_step: int,
    thrust: FloatArray,
    torque: FloatArray,
    active: np.ndarray,
) -> tuple[list[Sample], FloatArray]:
    """Integrate the vehicle over the m = ``per_step`` sub-periods of the control period
    (command held) with an IMU sample after each (an IMU m times faster than the control).

    Args:
        vehicle: The lanes' vehicles, at the start of the period (advanced in place).
        imu: The lanes' IMUs.
        t: (B,) lane times at the start of the period, s.
        period_s: The control period dt, s.
        per_step: m, IMU samples per control step.
        thrust: (B,) commanded thrust, N. torque: (B, 3) commanded torque, N·m.
        active: (B,) bool lanes to fly.

    Returns:
        ``(samples, rates)``: m tuples ``(t (B,), accel (B, 3), gyro (B, 3), thrust (B,),
        torque (B, 3))`` and the (B, 3) body rates averaged over the whole period, rad/s.
    """
    m = per_step
    h = period_s / m
    rates = np.zeros((t.shape[0], 3))
    samples: list[Sample] = []
    for i in range(m):
        sub_rates = vehicle.step(thrust, torque, h, active)
        rates += sub_rates
        t_imu = t + (i + 1) * h
        vel = vehicle.air_velocity()
        accel, gyro = imu.sample(t_imu, vel, sub_rates, vehicle.applied_thrust, active)
        f_t, tau = vehicle.applied_thrust.copy(), vehicle.applied_torque.copy()
        samples.append((t_imu, accel, gyro, f_t, tau))
    return samples, rates / m
