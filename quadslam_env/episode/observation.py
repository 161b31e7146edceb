"""Observation built only from the estimate and the reference (docs/design.md §4).

Everything is expressed in the reference-heading frame (rotated by ``C3(ψ_d)ᵀ``), so the
observation is invariant to the reference's yaw. Built for B lanes at once (the scalar env is
the one-lane case).
"""

from __future__ import annotations

import math

import numpy as np
from gymnasium import spaces

from quadslam_env.config.episode import ObservationConfig
from quadslam_env.estimation.snapshot import BatchEstimate
from quadslam_env.models.frames import dcm_from_euler_batch, wrap_pi
from quadslam_env.models.jit import kernel
from quadslam_env.models.lidar import lidar_measure
from quadslam_env.models.rigid_body import air_velocity_lanes
from quadslam_env.sim.trajectories import FlatOutputs, Trajectory
from quadslam_env.types import EUL, VEL, FloatArray

BASE_LAYOUT: tuple[tuple[str, int], ...] = (
    ("pos_err", 3),  # C3(ψ_d)ᵀ (ρ̂ - ρ_d), m
    ("vel_err", 3),  # C3(ψ_d)ᵀ (C_NB v̂ - ρ̇_d), m/s
    ("roll_pitch", 2),  # φ̂, θ̂, rad
    ("yaw_err", 1),  # wrap(ψ̂ - ψ_d), rad
    ("rates", 3),  # ω̂, rad/s (body)
    ("acc_ref", 3),  # C3(ψ_d)ᵀ ρ̈_d, m/s²
    ("yaw_rate_ref", 1),  # ψ̇_d, rad/s
)
BASE_SIZE = sum(n for _, n in BASE_LAYOUT)


@kernel
def _base_block(
    position: FloatArray,
    vel_inertial: FloatArray,
    euler: FloatArray,
    rates: FloatArray,
    ref_pos: FloatArray,
    ref_vel: FloatArray,
    ref_acc: FloatArray,
    ref_yaw: FloatArray,
    ref_yaw_rate: FloatArray,
    pos_cov: FloatArray,
    with_std: bool,
    out: FloatArray,
) -> None:
    """Fill ``out[:, :16]`` (and the position std ``out[:, 16:19]`` if ``with_std``)."""
    for i in range(out.shape[0]):
        c, s = math.cos(ref_yaw[i]), math.sin(ref_yaw[i])
        dx, dy = position[i, 0] - ref_pos[i, 0], position[i, 1] - ref_pos[i, 1]
        out[i, 0] = c * dx + s * dy
        out[i, 1] = -s * dx + c * dy
        out[i, 2] = position[i, 2] - ref_pos[i, 2]
        dx, dy = vel_inertial[i, 0] - ref_vel[i, 0], vel_inertial[i, 1] - ref_vel[i, 1]
        out[i, 3] = c * dx + s * dy
        out[i, 4] = -s * dx + c * dy
        out[i, 5] = vel_inertial[i, 2] - ref_vel[i, 2]
        out[i, 6] = euler[i, 0]
        out[i, 7] = euler[i, 1]
        out[i, 8] = wrap_pi(euler[i, 2] - ref_yaw[i])
        out[i, 9], out[i, 10], out[i, 11] = rates[i, 0], rates[i, 1], rates[i, 2]
        out[i, 12] = c * ref_acc[i, 0] + s * ref_acc[i, 1]
        out[i, 13] = -s * ref_acc[i, 0] + c * ref_acc[i, 1]
        out[i, 14] = ref_acc[i, 2]
        out[i, 15] = ref_yaw_rate[i]
        if with_std:
            # √diag(R Σ Rᵀ) for R = C3(ψ_d)ᵀ: only the horizontal 2×2 block mixes.
            sxx, syy, sxy = pos_cov[i, 0, 0], pos_cov[i, 1, 1], pos_cov[i, 0, 1]
            vx = c * c * sxx + 2 * c * s * sxy + s * s * syy
            vy = s * s * sxx - 2 * c * s * sxy + c * c * syy
            out[i, 16] = math.sqrt(max(vx, 0.0))
            out[i, 17] = math.sqrt(max(vy, 0.0))
            out[i, 18] = math.sqrt(max(pos_cov[i, 2, 2], 0.0))


@kernel
def _finish(obs: FloatArray, clip: float, out: np.ndarray) -> None:
    """``out`` (B, n) float32 = ``obs`` (B, n) clipped to ±``clip``, non-finite entries 0.

    A non-finite estimate ends the episode ("estimator_diverged"); the observation itself must
    still be finite, so such entries are zeroed.
    """
    for i in range(obs.shape[0]):
        for j in range(obs.shape[1]):
            v = obs[i, j]
            out[i, j] = min(max(v, -clip), clip) if math.isfinite(v) else 0.0


def nearest_landmarks(est: BatchEstimate, k: int) -> FloatArray:
    """The ``k`` nearest mapped landmarks as the estimate sees them.

    Each is the LiDAR measurement model (``quadslam_env.models.lidar``, seed 001 eq. 30–31) of
    its estimated position from the estimated pose: azimuth α (rad, positive right), elevation
    β (rad, positive down), range δ (m), then 1; rows past the mapped landmarks are zeros.

    Args:
        est: Belief of B lanes.
        k: Landmarks per lane.

    Returns:
        (B, k, 4) ``(α, β, δ, mask)``, nearest first.
    """
    b = est.position.shape[0]
    out = np.zeros((b, k, 4))
    if est.landmark_means.shape[1] == 0:
        return out
    dcm = dcm_from_euler_batch(est.euler)
    meas = lidar_measure(est.position[:, None, :], dcm[:, None], est.landmark_means)
    rng = np.where(est.landmark_mapped, meas[..., 2], np.inf)
    order = np.argsort(rng, axis=1, kind="stable")[:, :k]
    n = order.shape[1]
    picked = np.take_along_axis(meas, order[..., None], axis=1)
    mapped = np.take_along_axis(est.landmark_mapped, order, axis=1)
    out[:, :n, :3] = np.where(mapped[..., None], picked, 0.0)
    out[:, :n, 3] = mapped
    return out


def _wind_ne(est: BatchEstimate, wind: FloatArray | None) -> FloatArray:
    """(B, 2) horizontal wind (w_N, w_E) in m/s: ``wind``'s if given, else the estimate's.

    Raises:
        ValueError: Neither is there (the scenario check refuses such an estimator first).
    """
    if wind is not None:
        return np.asarray(wind, dtype=float)[:, :2]
    if est.wind is None:
        raise ValueError(
            "observation.estimated_wind/air_velocity: the estimate has no wind; allowed: an "
            "estimator that estimates it (ekf_slam with estimator.params.wind: estimate)"
        )
    return est.wind


def air_velocity(est: BatchEstimate, wind_ne: FloatArray) -> FloatArray:
    """The estimated velocity relative to the air, ``v̂_a = v̂ − C_NBᵀ(Λ̂) (ŵ_N, ŵ_E, 0)``.

    The simulator's air velocity (:func:`~quadslam_env.models.rigid_body.air_velocity_lanes`,
    what its drag acts on) of the estimated state in the estimated wind.

    Args:
        est: Belief of B lanes (``vel_body`` (B, 3) m/s in B, ``euler`` (B, 3) rad).
        wind_ne: (B, 2) horizontal wind (w_N, w_E) in N, m/s.

    Returns:
        (B, 3) air-relative velocity in B (FRD), m/s.
    """
    b = est.vel_body.shape[0]
    states = np.zeros((b, 12))
    states[:, VEL], states[:, EUL] = est.vel_body, est.euler
    wind = np.zeros((b, 3))
    wind[:, :2] = wind_ne
    out = np.empty((b, 3))
    air_velocity_lanes(states, wind, out)
    return out


def observation_layout(cfg: ObservationConfig) -> list[tuple[str, int]]:
    """The blocks of the observation, ``(name, entries)`` in order (:class:`ObservationBuilder`)."""
    layout = list(BASE_LAYOUT)
    if cfg.pos_uncertainty:
        layout.append(("pos_std", 3))
    if cfg.landmark_counts:
        layout.append(("landmark_counts", 2))
    for dt in cfg.lookahead_s:
        layout.append((f"lookahead_{dt:g}s", 3))
    if cfg.landmarks_nearest:
        layout.append(("landmarks_nearest", 4 * cfg.landmarks_nearest))
    if cfg.estimated_wind:
        layout.append(("est_wind", 2))
    if cfg.air_velocity:
        layout.append(("air_velocity", 3))
    if cfg.protection_levels:
        layout.append(("protection_levels", 2))
    return layout


def observation_size(cfg: ObservationConfig) -> int:
    """Entries of one lane's observation under ``cfg`` (before any env is built)."""
    return sum(n for _, n in observation_layout(cfg))


class ObservationBuilder:
    """Builds the float32 observations of B lanes and the single-lane ``Box`` space.

    Optional blocks, appended in this order: position uncertainty (3, √diag of the position
    covariance in the heading frame, m; 0 without a covariance), landmark counts (2: visible
    in the last scan, mapped), reference look-ahead (3 per entry of ``lookahead_s``:
    ``C3(ψ_d)ᵀ(ρ_d(t+Δ) - ρ_d(t))``, m), the nearest mapped landmarks (4 per landmark of
    ``landmarks_nearest``: :func:`nearest_landmarks`), the estimated horizontal wind (2,
    ``estimated_wind``: ``(ŵ_N, ŵ_E)``, N frame, m/s), the estimated air-relative velocity (3,
    ``air_velocity``: :func:`air_velocity`) and the protection levels (2, ``protection_levels``:
    HPL, VPL of the integrity monitor, m; 0 where none is given).
    """

    def __init__(self, cfg: ObservationConfig, trajectory: Trajectory) -> None:
        self.cfg = cfg
        self.trajectory = trajectory
        self.layout = observation_layout(cfg)
        self.size = sum(n for _, n in self.layout)
        self.space = spaces.Box(-cfg.clip, cfg.clip, shape=(self.size,), dtype=np.float32)

    def build(
        self,
        est: BatchEstimate,
        ref: FlatOutputs,
        t: FloatArray,
        n_visible: np.ndarray,
        levels: tuple[FloatArray, FloatArray] | None = None,
        wind: FloatArray | None = None,
    ) -> np.ndarray:
        """Observations (B, size) float32 of the lanes at times ``t`` (B,).

        Args:
            est: Belief of the B lanes.
            ref: Reference of the B lanes at ``t``.
            t: (B,) lane times in s.
            n_visible: (B,) landmarks returned by each lane's last scan.
            levels: ``(hpl, vpl)`` (B,) each, the step's protection levels in m
                (:mod:`quadslam_env.runtime.integrity`); ``None``: zeros.
            wind: (B, ≥2) wind in N, m/s for the wind blocks instead of ``est.wind`` (the true
                wind of a privileged observation); ``None``: the estimate's.
        """
        b = t.shape[0]
        obs = np.empty((b, self.size))
        with_std = self.cfg.pos_uncertainty and est.pose_cov is not None
        cov = est.pose_cov if with_std else np.zeros((1, 3, 3))
        _base_block(
            est.position,
            est.vel_inertial,
            est.euler,
            est.rates,
            ref.pos,
            ref.vel,
            ref.acc,
            ref.yaw,  # type: ignore[arg-type]
            ref.yaw_rate,  # type: ignore[arg-type]
            cov,  # type: ignore[arg-type]
            with_std,
            obs,
        )
        i = BASE_SIZE
        if self.cfg.pos_uncertainty:
            if not with_std:
                obs[:, i : i + 3] = 0.0
            i += 3
        if self.cfg.landmark_counts:
            obs[:, i] = n_visible
            obs[:, i + 1] = est.landmark_mapped.sum(axis=1)
            i += 2
        if self.cfg.lookahead_s:
            c, s = np.cos(ref.yaw), np.sin(ref.yaw)
            for dt in self.cfg.lookahead_s:
                d = self.trajectory.batch(t + dt).pos - ref.pos
                obs[:, i] = c * d[:, 0] + s * d[:, 1]
                obs[:, i + 1] = -s * d[:, 0] + c * d[:, 1]
                obs[:, i + 2] = d[:, 2]
                i += 3
        if self.cfg.landmarks_nearest:
            k = self.cfg.landmarks_nearest
            obs[:, i : i + 4 * k] = nearest_landmarks(est, k).reshape(b, 4 * k)
            i += 4 * k
        if self.cfg.estimated_wind or self.cfg.air_velocity:
            ne = _wind_ne(est, wind)
            if self.cfg.estimated_wind:
                obs[:, i : i + 2] = ne
                i += 2
            if self.cfg.air_velocity:
                obs[:, i : i + 3] = air_velocity(est, ne)
                i += 3
        if self.cfg.protection_levels:
            obs[:, i : i + 2] = 0.0 if levels is None else np.stack(levels, axis=-1)
            i += 2
        out = np.empty((b, self.size), dtype=np.float32)
        _finish(obs, float(self.cfg.clip), out)
        return out
