"""Simulated sensors of B vehicles: the biased, drifting IMU and the FOV-limited LiDAR.

DESIGN.md §3, §9. Each lane's sensor owns one ``numpy.random.Generator`` handed to it at reset
(a child of that lane's env generator), so lane i with seed s is the single env with seed s,
bit for bit. Generators are called in a Python loop over lanes (draws cannot be shared between
lanes); the arithmetic is batched. :class:`Imu` and :class:`Lidar` are the one-lane cases.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

from quadslam_env.config import ImuConfig, LidarConfig
from quadslam_env.measurements import ImuSample, LidarScan, ScanReturns
from quadslam_env.models.frames import wrap_angle
from quadslam_env.models.imu_noise import gauss_markov_discretisation, white_noise_sigma
from quadslam_env.models.jit import kernel
from quadslam_env.models.lidar import lidar_measure
from quadslam_env.models.params import VehicleParams
from quadslam_env.models.rigid_body import specific_force_body
from quadslam_env.types import DEG, GRAVITY, IMU_DIM, MEAS_DIM, FloatArray

_LANE0 = np.zeros(1, dtype=int)


def _lanes(lanes: ArrayLike) -> np.ndarray:
    return np.asarray(lanes, dtype=int).reshape(-1)


def _generators(
    current: list[np.random.Generator | None], lanes: np.ndarray, who: str
) -> list[np.random.Generator]:
    gens = [current[i] for i in lanes.tolist()]
    missing = [i for i, g in zip(lanes.tolist(), gens, strict=True) if g is None]
    if missing:
        raise RuntimeError(f"{who}: lanes {missing} were used before reset() gave them a generator")
    return gens


class ImuBatch:
    """Accelerometer + gyro per lane with constant bias, Gauss–Markov drift and white noise.

    Seed 000 eq. 5–11 with a physical accelerometer (DESIGN.md §3):
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

    Args:
        cfg: IMU settings.
        vehicle: Vehicle parameters (mass and drag enter the specific force).
        rate_hz: Sample rate f_s in Hz (the control rate).
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
        # Full-scale ranges (inf: unlimited).
        self.accel_range = math.inf if cfg.accel_range_g is None else cfg.accel_range_g * GRAVITY
        self.gyro_range = math.inf if cfg.gyro_range_dps is None else cfg.gyro_range_dps * DEG
        # The sample kernel's constants: mass, drag, σ_a, σ_ω, decay, drift driving scale,
        # accelerometer and gyro ranges.
        self._coeffs = np.array(
            [vehicle.mass, vehicle.drag, self.accel_sigma, self.gyro_sigma, self._decay,
             self._drift_scale, self.accel_range, self.gyro_range]
        )  # fmt: skip

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
                self._noise[lane] = rng.standard_normal((self.BLOCK, 2 * IMU_DIM))
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
            vel_body: (B, 3) true body velocity in m/s (enters the drag specific force).
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
            self._drift_sigma,
            accel,
            gyro,
        )
        return accel, gyro


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

    ``coeffs`` = (mass kg, drag 1/s, σ_a, σ_ω, Gauss–Markov decay a, √(1 − a²), accelerometer
    range m/s², gyro range rad/s); ``noise[i, cursor[i]]`` holds lane i's 12 normals for this
    sample (white noise, then the drift step). Each reading saturates at ±range (after noise
    and bias, as a real sensor's output does).
    """
    mass, drag, sigma_a, sigma_g, decay, scale = (
        coeffs[0], coeffs[1], coeffs[2], coeffs[3], coeffs[4], coeffs[5]
    )  # fmt: skip
    a_max, g_max = coeffs[6], coeffs[7]
    for i in lanes:
        z = noise[i, cursor[i]]
        cursor[i] += 1
        f_b = specific_force_body(
            vel_body[i, 0], vel_body[i, 1], vel_body[i, 2], thrust[i], mass, drag
        )
        for k in range(3):
            a = f_b[k] + (bias0[i, k] + drift[i, k]) + sigma_a * z[k]
            g = rates[i, k] + (bias0[i, 3 + k] + drift[i, 3 + k]) + sigma_g * z[3 + k]
            accel[i, k] = min(max(a, -a_max), a_max)
            gyro[i, k] = min(max(g, -g_max), g_max)
        for k in range(6):
            drift[i, k] = decay * drift[i, k] + scale * drift_sigma[k] * z[6 + k]


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


class LidarBatch:
    """FOV-limited LiDAR per lane returning (azimuth, elevation, range) of point landmarks.

    A landmark is in view iff its *true* ``|α| ≤ α_max``, ``|β| ≤ β_max`` and
    ``δ_min ≤ δ ≤ δ_max`` (seed 001 Table 4); Gaussian noise is then added per channel and the
    azimuth wrapped, and a landmark in view is returned with probability ``detection_prob``.
    With ``association: known`` (both papers) returns carry their landmark id (:meth:`scan`);
    with ``association: unknown`` they are unlabeled, joined by Poisson(``clutter_rate``)
    false returns uniform over the FOV volume, and shuffled (:meth:`returns`).

    Random stream per lane and scan (k landmarks in view, ascending id order): one
    ``standard_normal((k, 3))``; then, only if ``detection_prob < 1``, one ``random(k)``;
    then, only with unknown association, ``poisson(clutter_rate)`` (if the rate is > 0) and
    ``random((m, 3))`` for m false returns, and ``permutation(n)`` of the n returns. The
    defaults draw exactly the first call, as before these settings existed.

    Attributes:
        sigma: (3,) noise std (σ_α rad, σ_β rad, σ_δ m).

    Args:
        cfg: LiDAR settings.
        num_lanes: B.
    """

    def __init__(self, cfg: LidarConfig, num_lanes: int) -> None:
        self.cfg = cfg
        self.num_lanes = int(num_lanes)
        self.sigma = np.array(
            [cfg.sigma_azimuth_deg * DEG, cfg.sigma_elevation_deg * DEG, cfg.sigma_range_m]
        )
        self._az_max = cfg.azimuth_fov_deg * DEG
        self._el_max = cfg.elevation_fov_deg * DEG
        self._rngs: list[np.random.Generator | None] = [None] * self.num_lanes
        self._returns = ScanReturns(
            count=np.zeros(self.num_lanes, dtype=np.int64),
            meas=np.zeros((self.num_lanes, 0, MEAS_DIM)),
            truth=np.zeros((self.num_lanes, 0), dtype=np.int64),
        )

    def reset(self, lanes: ArrayLike, rngs: Sequence[np.random.Generator]) -> None:
        """Take the generators of ``lanes`` (k,) for their episodes (k generators)."""
        for lane, rng in zip(_lanes(lanes).tolist(), rngs, strict=True):
            self._rngs[lane] = rng

    def visible(self, meas: FloatArray) -> np.ndarray:
        """Boolean mask (...) of noise-free measurements (..., 3) inside the FOV and range."""
        return (
            (np.abs(meas[..., 0]) <= self._az_max)
            & (np.abs(meas[..., 1]) <= self._el_max)
            & (meas[..., 2] >= self.cfg.range_min_m)
            & (meas[..., 2] <= self.cfg.range_max_m)
        )

    def _in_view(
        self,
        pos: FloatArray,
        dcm: FloatArray,
        landmarks: FloatArray,
        n_landmarks: np.ndarray,
        idx: np.ndarray,
    ) -> tuple[np.ndarray, list[FloatArray], list[np.random.Generator]]:
        """Noisy measurements of the landmarks in view of each lane of ``idx`` (k,).

        Returns:
            ``(mask (k, Lmax) bool, rows, gens)``: which landmarks are in view, per lane the
            (kᵢ, 3) noisy measurements of those landmarks in ascending id order, and the
            lanes' generators (positioned after the noise draw).
        """
        lmax = landmarks.shape[1]
        true = lidar_measure(pos[idx, None, :], dcm[idx, None], landmarks[idx])  # (k, Lmax, 3)
        present = np.arange(lmax) < np.asarray(n_landmarks)[idx, None]
        mask = self.visible(true) & present
        counts = mask.sum(axis=1).tolist()
        gens = _generators(self._rngs, idx, "LidarBatch")
        noise = np.concatenate(
            [rng.standard_normal((k, MEAS_DIM)) for rng, k in zip(gens, counts, strict=True)]
        )
        noisy = true[mask] + self.sigma * noise  # rows in lane-major, ascending-id order
        noisy[:, 0] = wrap_angle(noisy[:, 0])
        rows = np.split(noisy, np.cumsum(counts)[:-1])
        return mask, rows, gens

    def _detected(self, rng: np.random.Generator, k: int) -> np.ndarray | None:
        """(k,) bool detections of k landmarks in view, or ``None`` when all are returned."""
        if self.cfg.detection_prob >= 1.0:
            return None
        return rng.random(k) < self.cfg.detection_prob

    def _clutter(self, rng: np.random.Generator) -> FloatArray:
        """(m, 3) false returns, m ~ Poisson(clutter_rate), uniform over the FOV volume.

        Uniform in volume: α uniform, sin β uniform (the cos β area element) and δ³ uniform
        on [δ_min³, δ_max³] (the δ² volume element).
        """
        if self.cfg.clutter_rate <= 0.0:
            return np.zeros((0, MEAS_DIM))
        m = int(rng.poisson(self.cfg.clutter_rate))
        u = rng.random((m, MEAS_DIM))
        r_lo, r_hi = self.cfg.range_min_m**3, self.cfg.range_max_m**3
        s_el = math.sin(self._el_max)
        return np.column_stack(
            (
                self._az_max * (2.0 * u[:, 0] - 1.0),
                np.arcsin(s_el * (2.0 * u[:, 1] - 1.0)),
                np.cbrt(r_lo + (r_hi - r_lo) * u[:, 2]),
            )
        )

    def scan(
        self,
        pos: FloatArray,
        dcm: FloatArray,
        landmarks: FloatArray,
        n_landmarks: np.ndarray,
        lanes: ArrayLike,
    ) -> tuple[np.ndarray, FloatArray]:
        """One labeled scan of each lane in ``lanes`` from its true pose (known association).

        Args:
            pos: (B, 3) true positions in N, m.
            dcm: (B, 3, 3) true ``C_NB``.
            landmarks: (B, Lmax, 3) true landmark positions in N, m; slot j is landmark id j.
            n_landmarks: (B,) int, landmarks present per lane (slots ≥ this are ignored).
            lanes: (k,) int lanes that scan now.

        Returns:
            ``(visible (B, Lmax) bool, meas (B, Lmax, 3))``: measurements (α rad, β rad, δ m) of
            returned landmarks; other slots and lanes are False / 0.
        """
        b, lmax = landmarks.shape[0], landmarks.shape[1]
        idx = _lanes(lanes)
        visible = np.zeros((b, lmax), dtype=bool)
        meas = np.zeros((b, lmax, MEAS_DIM))
        if idx.size == 0 or lmax == 0:
            return visible, meas
        mask, rows, gens = self._in_view(pos, dcm, landmarks, n_landmarks, idx)
        out = np.zeros((idx.size, lmax, MEAS_DIM))
        out[mask] = np.concatenate(rows)
        for j, rng in enumerate(gens):
            detected = self._detected(rng, rows[j].shape[0])
            if detected is not None:
                mask[j, np.flatnonzero(mask[j])[~detected]] = False
        visible[idx] = mask
        meas[idx] = np.where(mask[..., None], out, 0.0)
        return visible, meas

    def returns(
        self,
        pos: FloatArray,
        dcm: FloatArray,
        landmarks: FloatArray,
        n_landmarks: np.ndarray,
        lanes: ArrayLike,
    ) -> ScanReturns:
        """One unlabeled scan of each lane in ``lanes`` (unknown association, with clutter).

        Args: as :meth:`scan`.

        Returns:
            The lanes' returns in a buffer this object reuses (read, don't keep): lanes not in
            ``lanes`` have count 0.
        """
        out = self._returns
        out.count[:] = 0
        idx = _lanes(lanes)
        if idx.size == 0:
            return out
        if landmarks.shape[1]:
            mask, rows, gens = self._in_view(pos, dcm, landmarks, n_landmarks, idx)
        else:
            mask = np.zeros((idx.size, 0), dtype=bool)
            rows = [np.zeros((0, MEAS_DIM))] * idx.size
            gens = _generators(self._rngs, idx, "LidarBatch")
        scans = []
        for j, rng in enumerate(gens):
            meas, ids = rows[j], np.flatnonzero(mask[j])
            detected = self._detected(rng, ids.shape[0])
            if detected is not None:
                meas, ids = meas[detected], ids[detected]
            clutter = self._clutter(rng)
            meas = np.concatenate((meas, clutter))
            ids = np.concatenate((ids, np.full(clutter.shape[0], -1, dtype=np.int64)))
            if ids.shape[0] > 1:
                order = rng.permutation(ids.shape[0])
                meas, ids = meas[order], ids[order]
            scans.append((meas, ids))
        width = max(s[1].shape[0] for s in scans)
        if width > out.meas.shape[1]:
            out.meas = np.zeros((self.num_lanes, width, MEAS_DIM))
            out.truth = np.full((self.num_lanes, width), -1, dtype=np.int64)
        for lane, (meas, ids) in zip(idx.tolist(), scans, strict=True):
            n = ids.shape[0]
            out.count[lane] = n
            out.meas[lane, :n] = meas
            out.truth[lane, :n] = ids
            out.truth[lane, n:] = -1
        return out


class Lidar:
    """One LiDAR: the one-lane case of :class:`LidarBatch` (same model, same random stream).

    Args:
        cfg: LiDAR settings.
    """

    def __init__(self, cfg: LidarConfig) -> None:
        self._batch = LidarBatch(cfg, 1)
        self.cfg = cfg
        self.sigma = self._batch.sigma
        self.last_truth: np.ndarray = np.zeros(0, dtype=np.int64)

    def reset(self, rng: np.random.Generator) -> None:
        """Take the generator for this episode."""
        self._batch.reset(_LANE0, [rng])

    def visible(self, meas: FloatArray) -> np.ndarray:
        """Boolean mask (k,) of noise-free measurements (k, 3) inside the FOV and range limits."""
        return self._batch.visible(meas)

    def scan(
        self,
        t: float,
        pos: FloatArray,
        dcm: FloatArray,
        landmark_ids: np.ndarray,
        landmarks: FloatArray,
    ) -> LidarScan:
        """One scan from the true pose (labeled, or unlabeled with ``association: unknown``).

        Args:
            t: Scan time in s.
            pos: (3,) true position in N, m.
            dcm: (3, 3) true ``C_NB``.
            landmark_ids: (L,) sorted landmark ids.
            landmarks: (L, 3) true landmark positions in N, m.

        Returns:
            The scan; with unknown association its ``ids`` are ``None`` and the true id of each
            return (-1: false return) is kept in :attr:`last_truth` for metrics.
        """
        pts = np.asarray(landmarks, dtype=float).reshape(1, -1, 3)
        args = (
            np.asarray(pos, dtype=float).reshape(1, 3),
            np.asarray(dcm, dtype=float).reshape(1, 3, 3),
            pts,
            np.array([pts.shape[1]]),
            _LANE0,
        )
        if self.cfg.association == "unknown":
            out = self._batch.returns(*args)
            n = int(out.count[0])
            truth = out.truth[0, :n]
            ids = np.append(np.asarray(landmark_ids, dtype=np.int64), -1)  # [-1]: clutter
            self.last_truth = ids[truth]
            return LidarScan(t=t, ids=None, meas=out.meas[0, :n].copy(), sigma=self.sigma)
        visible, meas = self._batch.scan(*args)
        mask = visible[0]
        return LidarScan(
            t=t, ids=np.asarray(landmark_ids)[mask], meas=meas[0][mask], sigma=self.sigma
        )
