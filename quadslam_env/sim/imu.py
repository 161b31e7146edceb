"""Simulated IMU of B vehicles: accelerometer and gyro with bias, drift and white noise.

docs/design.md §3, §9. Each lane's IMU owns one ``numpy.random.Generator`` handed to it at reset
(a child of that lane's env generator), so lane i with seed s is the single env with seed s,
bit for bit. :class:`Imu` is the one-lane case of :class:`ImuBatch`.

The IMU samples at its own rate f_IMU (``imu.rate_hz``; default the control rate). Every
sample reports its inputs averaged over its sample period (an integrating sensor): at the
control rate the simulator hands it the body rates averaged over the period; an IMU slower
than the control rate averages m control periods (:meth:`ImuBatch.accumulate`,
:meth:`ImuBatch.sample_held`); a faster one is sampled after each of the m sub-periods the
simulator splits the control period into (:class:`quadslam_env.core.SimCore`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

from quadslam_env.config.hardware import ImuConfig
from quadslam_env.estimation.measurements import ImuSample
from quadslam_env.models.imu_noise import gauss_markov_discretisation, white_noise_sigma
from quadslam_env.models.jit import kernel
from quadslam_env.models.params import VehicleParams
from quadslam_env.models.rigid_body import aero_specific_force, specific_force_body
from quadslam_env.sim.sensor_lanes import LANE0 as _LANE0
from quadslam_env.sim.sensor_lanes import lane_generators as _generators
from quadslam_env.sim.sensor_lanes import lane_indices as _lanes
from quadslam_env.types import DEG, GRAVITY, IMU_DIM, FloatArray


class ImuBatch:
    """Accelerometer + gyro per lane with constant bias, Gauss–Markov drift and white noise.

    Seed 000 eq. 5–11 with a physical accelerometer (docs/design.md §3):
    ``a_m = f_B + b0_a + b1_a + v_a``, ``ω_m = ω + b0_ω + b1_ω + v_ω``, where ``f_B`` is the
    specific force; with ``accel_range_g`` / ``gyro_range_dps`` each reading saturates at the
    sensor's full scale. The drift is first-order Gauss–Markov, discretised exactly:
    ``b1 ← e^{-T/τ} b1 + N(0, σ_b1² (1 - e^{-2T/τ}))`` (so its stationary std is σ_b1). White
    noise per sample has std ``ND · √f_s`` for noise density ND and sample rate f_s.

    Random stream per lane (the contract with the single env): at reset ``choice([-1, 1], 6)``
    (only with random bias signs) then ``standard_normal(6)`` for the initial drift; per sample
    ``standard_normal(6)`` white noise then ``standard_normal(6)`` for the drift step. Samples
    are drawn ahead in blocks of :attr:`BLOCK` × 12 normals per lane, which is the same sequence
    (a Generator fills arrays from one stream) at a fraction of the per-call cost.

    Attributes:
        accel_sigma: White-noise std per axis of the accelerometer in m/s².
        gyro_sigma: White-noise std per axis of the gyro in rad/s.
        bias0: (B, 6) constant biases (accel m/s², gyro rad/s).
        drift: (B, 6) current drift b1.
        accel_range: Accelerometer full scale per axis in m/s² (inf: unlimited).
        gyro_range: Gyro full scale per axis in rad/s (inf: unlimited).
        period: Sample period T = 1/f_s in s.
        held_accel: (B, 3) the latest sample of :meth:`sample_held` / :meth:`prime`, m/s².
        held_gyro: (B, 3) likewise, rad/s (what a filter holds between samples).

    Args:
        cfg: IMU settings.
        vehicle: Vehicle parameters (mass and drag enter the specific force).
        rate_hz: Sample rate f_s in Hz (``imu.rate_hz``, by default the control rate).
        num_lanes: B.
    """

    BLOCK = 64
    """Samples drawn ahead per lane and generator call."""

    def __init__(
        self, cfg: ImuConfig, vehicle: VehicleParams, rate_hz: float, num_lanes: int
    ) -> None:
        self.cfg = cfg
        self.vehicle = vehicle
        self.num_lanes = int(num_lanes)
        self.period = 1.0 / rate_hz
        self.accel_sigma = white_noise_sigma(cfg.accel_noise_density, rate_hz)
        self.gyro_sigma = white_noise_sigma(cfg.gyro_noise_density, rate_hz)
        self._decay, variance = gauss_markov_discretisation(self.period, cfg.drift_tau_s)
        self._drift_scale = math.sqrt(variance)
        self._drift_sigma = np.array([cfg.accel_drift_sigma] * 3 + [cfg.gyro_drift_sigma] * 3)
        self._bias_nominal = np.array(cfg.accel_bias + cfg.gyro_bias, dtype=float)
        self.bias0 = np.zeros((self.num_lanes, IMU_DIM))
        self.drift = np.zeros((self.num_lanes, IMU_DIM))
        self._rngs: list[np.random.Generator | None] = [None] * self.num_lanes
        self._noise = np.zeros((self.num_lanes, self.BLOCK, 2 * IMU_DIM))
        self._cursor = np.full(self.num_lanes, self.BLOCK)
        self._lane_ids = np.arange(self.num_lanes)
        self.held_accel = np.zeros((self.num_lanes, 3))
        self.held_gyro = np.zeros((self.num_lanes, 3))
        # Running sums of (v_B, ω, f_T) over the current sample period, and their counts.
        self._sums = np.zeros((self.num_lanes, 7))
        self._counts = np.zeros(self.num_lanes, dtype=np.int64)
        # Full-scale ranges (inf: unlimited).
        self.accel_range = math.inf if cfg.accel_range_g is None else cfg.accel_range_g * GRAVITY
        self.gyro_range = math.inf if cfg.gyro_range_dps is None else cfg.gyro_range_dps * DEG
        # The sample kernel's constants: mass, drag, σ_a, σ_ω, decay, drift driving scale,
        # accelerometer and gyro ranges, quadratic drag (3).
        # One row per lane (domain randomisation scales a lane's mass and noise: set_scales).
        self._nominal = np.array(
            [vehicle.mass, vehicle.drag, self.accel_sigma, self.gyro_sigma, self._decay,
             self._drift_scale, self.accel_range, self.gyro_range, *vehicle.drag_quadratic]
        )  # fmt: skip
        self._coeffs = np.tile(self._nominal, (self.num_lanes, 1))
        self._lane_drift_sigma = np.tile(self._drift_sigma, (self.num_lanes, 1))

    def set_scales(
        self, lanes: ArrayLike, mass: ArrayLike, bias: ArrayLike, noise: ArrayLike
    ) -> None:
        """Scale the IMU of ``lanes`` (k,) for the episode that :meth:`reset` just started.

        Args:
            lanes: (k,) lane indices (already reset: their drawn biases are scaled here).
            mass: (k,) scale of the vehicle's mass (the specific force the IMU senses).
            bias: (k,) scale of the constant bias and of the drift (its std and its state).
            noise: (k,) scale of the white-noise std of both sensors.
        """
        idx = _lanes(lanes)
        ms, bs = np.asarray(mass, dtype=float), np.asarray(bias, dtype=float)
        ns = np.asarray(noise, dtype=float)
        self._coeffs[idx, 0] = self._nominal[0] * ms
        self._coeffs[idx, 2] = self._nominal[2] * ns
        self._coeffs[idx, 3] = self._nominal[3] * ns
        self.bias0[idx] *= bs[:, None]
        self.drift[idx] *= bs[:, None]
        self._lane_drift_sigma[idx] = self._drift_sigma * bs[:, None]

    def reset(self, lanes: ArrayLike, rngs: Sequence[np.random.Generator]) -> None:
        """Draw each lane's constant bias signs (if random) and a stationary initial drift.

        Args:
            lanes: (k,) int lane indices.
            rngs: k generators, one per lane, used by this IMU only from now on.
        """
        idx = _lanes(lanes)
        for lane, rng in zip(idx.tolist(), rngs, strict=True):
            bias = self._bias_nominal.copy()
            if self.cfg.random_bias_sign:
                bias *= rng.choice([-1.0, 1.0], size=IMU_DIM)
            self.bias0[lane] = bias
            self.drift[lane] = self._drift_sigma * rng.standard_normal(IMU_DIM)
            self._rngs[lane] = rng
        self._cursor[idx] = self.BLOCK  # the pre-drawn block belonged to the old generator
        self._sums[idx] = 0.0
        self._counts[idx] = 0

    @property
    def total_bias(self) -> FloatArray:
        """(B, 6) current total bias ``b0 + b1`` (accel m/s², then gyro rad/s): for metrics."""
        return self.bias0 + self.drift

    def _refill(self, lanes: np.ndarray) -> None:
        """Draw the next block of normals for the ``lanes`` (k,) whose block is used up."""
        empty = lanes[self._cursor[lanes] >= self.BLOCK]
        if empty.size:
            gens = _generators(self._rngs, empty, "ImuBatch")
            for lane, rng in zip(empty.tolist(), gens, strict=True):
                rng.standard_normal(out=self._noise[lane])  # (BLOCK, 12) in place, no copy
            self._cursor[empty] = 0

    def sample(
        self,
        t: ArrayLike,
        vel_body: FloatArray,
        rates: FloatArray,
        thrust: FloatArray,
        active: np.ndarray | None = None,
    ) -> tuple[FloatArray, FloatArray]:
        """Measure the active lanes, then advance their drift by one sample period.

        Args:
            t: Sample time(s) in s; not used by the model (kept to mirror :meth:`Imu.sample`).
            vel_body: (B, 3) true body velocity relative to the air in m/s (enters the drag
                specific force; the body velocity in still air).
            rates: (B, 3) true body rates in rad/s.
            thrust: (B,) applied thrust in N.
            active: (B,) bool lanes that sample now (default: all).

        Returns:
            ``(accel (B, 3) m/s², gyro (B, 3) rad/s)`` in B; rows of inactive lanes are zero.
        """
        b = self.num_lanes
        accel, gyro = np.zeros((b, 3)), np.zeros((b, 3))
        lanes = self._lane_ids if active is None or active.all() else np.flatnonzero(active)
        if lanes.size == 0:
            return accel, gyro
        self._refill(lanes)
        _sample_lanes(
            lanes,
            self._cursor,
            self._noise,
            self.bias0,
            self.drift,
            np.ascontiguousarray(vel_body, dtype=float),
            np.ascontiguousarray(rates, dtype=float),
            np.ascontiguousarray(thrust, dtype=float),
            self._coeffs,
            self._lane_drift_sigma,
            accel,
            gyro,
        )
        return accel, gyro

    def accumulate(
        self, vel_body: FloatArray, rates: FloatArray, thrust: FloatArray, active: np.ndarray
    ) -> None:
        """Add one control period's truth to the running sums of the ``active`` (B,) lanes.

        For an IMU slower than the control rate: its sample reports the mean of its inputs
        over its own period T = m control periods (:meth:`sample_held`).

        Args:
            vel_body: (B, 3) true air-relative body velocity at the end of the period, m/s.
            rates: (B, 3) true body rates averaged over the period in rad/s.
            thrust: (B,) applied thrust in N.
            active: (B,) bool lanes that stepped.
        """
        self._sums[active, 0:3] += vel_body[active]
        self._sums[active, 3:6] += rates[active]
        self._sums[active, 6] += thrust[active]
        self._counts[active] += 1

    def sample_held(self, t: ArrayLike, due: np.ndarray) -> None:
        """Sample the ``due`` (B,) lanes with the mean of their accumulated inputs (the IMU's
        average over its period), hold the readings in :attr:`held_accel` / :attr:`held_gyro`
        and restart their sums.

        Args:
            t: Sample time(s) in s (unused, as in :meth:`sample`).
            due: (B,) bool lanes whose sample period ends now (each has ≥ 1 period summed).
        """
        mean = self._sums / np.maximum(self._counts, 1)[:, None]
        self._hold(t, mean[:, 0:3], mean[:, 3:6], mean[:, 6], due)
        self._sums[due] = 0.0
        self._counts[due] = 0

    def prime(
        self, lanes: ArrayLike, vel_body: FloatArray, rates: FloatArray, thrust: FloatArray
    ) -> None:
        """The sample at t = 0 of freshly reset ``lanes`` (k,), from their initial air-relative
        velocity (k, 3) m/s, rates (k, 3) rad/s and thrust (k,) N, held (the sample a
        slower-than-control IMU hands the filter for its first period; the vehicle is taken
        as in that state over the IMU period before).
        """
        idx = _lanes(lanes)
        b = self.num_lanes
        vel, rate, f_t = np.zeros((b, 3)), np.zeros((b, 3)), np.zeros(b)
        vel[idx], rate[idx], f_t[idx] = vel_body, rates, thrust
        due = np.zeros(b, dtype=bool)
        due[idx] = True
        self._hold(0.0, vel, rate, f_t, due)

    def _hold(
        self, t: ArrayLike, vel: FloatArray, rates: FloatArray, thrust: FloatArray, due: np.ndarray
    ) -> None:
        accel, gyro = self.sample(t, vel, rates, thrust, due)
        self.held_accel[due] = accel[due]
        self.held_gyro[due] = gyro[due]


@kernel
def _sample_lanes(
    lanes: np.ndarray,
    cursor: np.ndarray,
    noise: FloatArray,
    bias0: FloatArray,
    drift: FloatArray,
    vel_body: FloatArray,
    rates: FloatArray,
    thrust: FloatArray,
    coeffs: FloatArray,
    drift_sigma: FloatArray,
    accel: FloatArray,
    gyro: FloatArray,
) -> None:
    """One IMU sample of each lane in ``lanes`` (see :class:`ImuBatch`), in place.

    ``coeffs`` (B, 11) per lane = (mass kg, drag 1/s, σ_a, σ_ω, Gauss–Markov decay a,
    √(1 − a²), accelerometer range m/s², gyro range rad/s, quadratic drag c_q (3) 1/m);
    ``drift_sigma`` (B, 6) per lane the drift's stationary std; ``noise[i, cursor[i]]`` holds
    lane i's 12 normals for this sample (white noise, then the drift step). Each reading
    saturates at ±range (after noise and bias, as a real sensor's output does). ``vel_body``
    is relative to the air, so the drag the accelerometer senses is the one the body feels.
    """
    for i in lanes:
        c = coeffs[i]
        mass, drag, sigma_a, sigma_g, decay, scale = c[0], c[1], c[2], c[3], c[4], c[5]
        a_max, g_max = c[6], c[7]
        cq = (c[8], c[9], c[10])
        quadratic = cq[0] != 0.0 or cq[1] != 0.0 or cq[2] != 0.0
        z = noise[i, cursor[i]]
        cursor[i] += 1
        ua, va, wa = vel_body[i, 0], vel_body[i, 1], vel_body[i, 2]
        if quadratic:
            f_b = aero_specific_force(ua, va, wa, thrust[i], mass, drag, cq)
        else:
            f_b = specific_force_body(ua, va, wa, thrust[i], mass, drag)
        for k in range(3):
            a = f_b[k] + (bias0[i, k] + drift[i, k]) + sigma_a * z[k]
            g = rates[i, k] + (bias0[i, 3 + k] + drift[i, 3 + k]) + sigma_g * z[3 + k]
            accel[i, k] = min(max(a, -a_max), a_max)
            gyro[i, k] = min(max(g, -g_max), g_max)
        for k in range(6):
            drift[i, k] = decay * drift[i, k] + scale * drift_sigma[i, k] * z[6 + k]


class Imu:
    """One IMU: the one-lane case of :class:`ImuBatch` (same model, same random stream).

    Args:
        cfg: IMU settings.
        vehicle: Vehicle parameters (mass and drag enter the specific force).
        rate_hz: Sample rate f_s in Hz (the control rate).
    """

    def __init__(self, cfg: ImuConfig, vehicle: VehicleParams, rate_hz: float) -> None:
        self._batch = ImuBatch(cfg, vehicle, rate_hz, 1)
        self.cfg = cfg
        self.vehicle = vehicle
        self.period = self._batch.period
        self.accel_sigma = self._batch.accel_sigma
        self.gyro_sigma = self._batch.gyro_sigma

    def reset(self, rng: np.random.Generator) -> None:
        """Draw the episode's constant bias signs (if random) and a stationary initial drift."""
        self._batch.reset(_LANE0, [rng])

    @property
    def bias0(self) -> FloatArray:
        """(6,) constant bias (accel m/s², gyro rad/s)."""
        return self._batch.bias0[0].copy()

    @property
    def drift(self) -> FloatArray:
        """(6,) current drift b1 (accel m/s², gyro rad/s)."""
        return self._batch.drift[0].copy()

    @property
    def total_bias(self) -> FloatArray:
        """(6,) current total bias ``b0 + b1`` (accel m/s², then gyro rad/s): truth for metrics."""
        return self._batch.total_bias[0]

    def sample(self, t: float, vel_body: FloatArray, rates: FloatArray, thrust: float) -> ImuSample:
        """Measure, then advance the drift by one sample period.

        Args:
            t: Sample time in s.
            vel_body: (3,) true body velocity in m/s (enters the drag specific force).
            rates: (3,) true body rates in rad/s.
            thrust: Applied thrust in N.
        """
        accel, gyro = self._batch.sample(
            t,
            np.asarray(vel_body, dtype=float).reshape(1, 3),
            np.asarray(rates, dtype=float).reshape(1, 3),
            np.array([float(thrust)]),
        )
        return ImuSample(
            t=t,
            accel=accel[0],
            gyro=gyro[0],
            accel_sigma=self.accel_sigma,
            gyro_sigma=self.gyro_sigma,
        )
