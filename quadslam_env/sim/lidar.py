"""Simulated LiDAR of B vehicles: the FOV-limited scanner of point landmarks.

docs/design.md §3, §9. Each lane's sensor owns one ``numpy.random.Generator`` handed to it at reset
(a child of that lane's env generator), so lane i with seed s is the single env with seed s,
bit for bit. Generators are called in a Python loop over lanes (draws cannot be shared between
lanes); the arithmetic is batched. :class:`Lidar` is the one-lane case. The IMU is
:mod:`quadslam_env.sim.imu`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

from quadslam_env.config.hardware import LidarConfig
from quadslam_env.estimation.measurements import LidarScan, ScanReturns
from quadslam_env.models.frames import wrap_pi
from quadslam_env.models.jit import kernel
from quadslam_env.models.lidar import measure_landmark
from quadslam_env.sim.sensor_lanes import LANE0 as _LANE0
from quadslam_env.sim.sensor_lanes import lane_generators as _generators
from quadslam_env.sim.sensor_lanes import lane_indices as _lanes
from quadslam_env.types import DEG, MEAS_DIM, FloatArray


@kernel
def _in_view_lanes(
    pos: FloatArray,
    dcm: FloatArray,
    landmarks: FloatArray,
    n_landmarks: np.ndarray,
    idx: np.ndarray,
    limits: FloatArray,
    true: FloatArray,
    mask: np.ndarray,
) -> None:
    """Noise-free measurements ``true`` (k, Lmax, 3) of the present landmarks of the lanes
    ``idx`` (k,) and which are in view, ``mask`` (k, Lmax) (absent slots: False, 0).

    ``limits`` = (α_max, β_max, δ_min, δ_max): in view iff ``|α| ≤ α_max``, ``|β| ≤ β_max``
    and ``δ_min ≤ δ ≤ δ_max``.
    """
    for j in range(idx.shape[0]):
        lane = idx[j]
        for m in range(landmarks.shape[1]):
            if m >= n_landmarks[lane]:
                mask[j, m] = False
                true[j, m, 0] = true[j, m, 1] = true[j, m, 2] = 0.0
                continue
            a, e, d = measure_landmark(pos[lane], dcm[lane], landmarks[lane, m])
            true[j, m, 0], true[j, m, 1], true[j, m, 2] = a, e, d
            mask[j, m] = (
                abs(a) <= limits[0] and abs(e) <= limits[1] and d >= limits[2] and d <= limits[3]
            )


@kernel
def _add_noise(
    true: FloatArray, mask: np.ndarray, noise: FloatArray, sigma: FloatArray, out: FloatArray
) -> None:
    """``out[mask]`` (k, Lmax, 3) = ``true[mask] + sigma · noise`` with the azimuth wrapped,
    taking the rows of ``noise`` (Σ mask, 3) in lane-major, ascending-id order; other slots 0.
    ``sigma`` (k, 3) is each lane's noise std."""
    r = 0
    for j in range(mask.shape[0]):
        for m in range(mask.shape[1]):
            if not mask[j, m]:
                out[j, m, 0] = out[j, m, 1] = out[j, m, 2] = 0.0
                continue
            for i in range(3):
                out[j, m, i] = true[j, m, i] + sigma[j, i] * noise[r, i]
            out[j, m, 0] = wrap_pi(out[j, m, 0])
            r += 1


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
        sigma: (3,) nominal noise std (σ_α rad, σ_β rad, σ_δ m), what the estimators are told.
        lane_sigma: (B, 3) each lane's true noise std (the nominal one times the lane's
            ``lidar_noise_scale`` under domain randomisation).

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
        self.lane_sigma = np.tile(self.sigma, (self.num_lanes, 1))
        self._az_max = cfg.azimuth_fov_deg * DEG
        self._el_max = cfg.elevation_fov_deg * DEG
        self._limits = np.array([self._az_max, self._el_max, cfg.range_min_m, cfg.range_max_m])
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

    def set_scales(self, lanes: ArrayLike, noise: ArrayLike) -> None:
        """Scale the noise std of ``lanes`` (k,) by ``noise`` (k,) (domain randomisation)."""
        idx = _lanes(lanes)
        self.lane_sigma[idx] = self.sigma * np.asarray(noise, dtype=float)[:, None]

    def _in_view(
        self,
        pos: FloatArray,
        dcm: FloatArray,
        landmarks: FloatArray,
        n_landmarks: np.ndarray,
        idx: np.ndarray,
    ) -> tuple[np.ndarray, FloatArray, list[np.random.Generator]]:
        """Noisy measurements of the landmarks in view of each lane of ``idx`` (k,).

        Returns:
            ``(mask (k, Lmax) bool, meas (k, Lmax, 3), gens)``: which landmarks are in view,
            their noisy measurements (0 elsewhere), and the lanes' generators (positioned
            after the noise draw, one ``standard_normal((kᵢ, 3))`` per lane in id order).
        """
        k, lmax = idx.shape[0], landmarks.shape[1]
        true = np.empty((k, lmax, MEAS_DIM))
        mask = np.empty((k, lmax), dtype=bool)
        _in_view_lanes(pos, dcm, landmarks, np.asarray(n_landmarks), idx, self._limits, true,
                       mask)  # fmt: skip
        counts = mask.sum(axis=1).tolist()
        gens = _generators(self._rngs, idx, "LidarBatch")
        draws = [rng.standard_normal((n, MEAS_DIM)) for rng, n in zip(gens, counts, strict=True)]
        noise = draws[0] if k == 1 else np.concatenate(draws)
        meas = np.empty((k, lmax, MEAS_DIM))
        _add_noise(true, mask, noise, self.lane_sigma[idx], meas)
        return mask, meas, gens

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
        mask, out, gens = self._in_view(pos, dcm, landmarks, n_landmarks, idx)
        if self.cfg.detection_prob < 1.0:
            for j, rng in enumerate(gens):
                seen = np.flatnonzero(mask[j])
                detected = self._detected(rng, seen.shape[0])
                if detected is not None:
                    mask[j, seen[~detected]] = False
            out[~mask] = 0.0
        visible[idx] = mask
        meas[idx] = out
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
            mask, noisy, gens = self._in_view(pos, dcm, landmarks, n_landmarks, idx)
        else:
            mask = np.zeros((idx.size, 0), dtype=bool)
            noisy = np.zeros((idx.size, 0, MEAS_DIM))
            gens = _generators(self._rngs, idx, "LidarBatch")
        scans = []
        for j, rng in enumerate(gens):
            ids = np.flatnonzero(mask[j])
            meas = noisy[j, ids]
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
