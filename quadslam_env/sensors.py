"""Simulated LiDAR of B vehicles: the FOV-limited scanner of point landmarks.

DESIGN.md §3, §9. Each lane's sensor owns one ``numpy.random.Generator`` handed to it at reset
(a child of that lane's env generator), so lane i with seed s is the single env with seed s,
bit for bit. Generators are called in a Python loop over lanes (draws cannot be shared between
lanes); the arithmetic is batched. :class:`Lidar` is the one-lane case. The IMU lives in
:mod:`quadslam_env.imu` (re-exported here).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

from quadslam_env.config import LidarConfig
from quadslam_env.imu import Imu, ImuBatch
from quadslam_env.measurements import LidarScan, ScanReturns
from quadslam_env.models.frames import wrap_angle
from quadslam_env.models.lidar import lidar_measure
from quadslam_env.sensor_lanes import LANE0 as _LANE0
from quadslam_env.sensor_lanes import lane_generators as _generators
from quadslam_env.sensor_lanes import lane_indices as _lanes
from quadslam_env.types import DEG, MEAS_DIM, FloatArray

__all__ = ["Imu", "ImuBatch", "Lidar", "LidarBatch"]


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
