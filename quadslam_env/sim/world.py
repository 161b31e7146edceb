"""Landmark layouts (docs/design.md §3)."""

from __future__ import annotations

import numpy as np

from quadslam_env.config.world import LandmarksConfig
from quadslam_env.types import DEG, FloatArray


def landmark_capacity(cfg: LandmarksConfig) -> int:
    """Number of landmarks the layout makes (the map's size bound Lmax)."""
    return cfg.size


def make_landmarks(
    cfg: LandmarksConfig, center: FloatArray, rng: np.random.Generator
) -> tuple[np.ndarray, FloatArray]:
    """Build the episode's landmark map.

    Layouts:
        ``rauniyar2023``: ``count`` points in spherical coordinates around ``center`` with
            azimuth, elevation and range uniform in the configured intervals (seed 001 Table 3:
            [-180°, 180°], [-50°, 50°], [8, 20] m); elevation is positive above the centre.
        ``poles4``: seed 000's four poles, one point landmark per pole centre at
            (±spacing, ±spacing, -pole_altitude_m) (seed 000 §IV.B: spacing 2 m, altitude 1 m).
        ``explicit``: the given ``positions``.

    Args:
        cfg: Landmark settings.
        center: (3,) NED centre used when ``cfg.center`` is null (the trajectory centre), m.
        rng: Generator for the random layout.

    Returns:
        ``(ids (L,) int, positions (L, 3) NED m)``.
    """
    if cfg.layout == "rauniyar2023":
        c = np.asarray(cfg.center if cfg.center is not None else center, dtype=float)
        az = rng.uniform(cfg.azimuth_deg[0], cfg.azimuth_deg[1], cfg.count) * DEG
        el = rng.uniform(cfg.elevation_deg[0], cfg.elevation_deg[1], cfg.count) * DEG
        rng_m = rng.uniform(cfg.range_m[0], cfg.range_m[1], cfg.count)
        offsets = np.stack(
            [rng_m * np.cos(el) * np.cos(az), rng_m * np.cos(el) * np.sin(az), -rng_m * np.sin(el)],
            axis=1,
        )  # NED: positive elevation is up, i.e. -z
        points = c + offsets
    elif cfg.layout == "poles4":
        s, h = cfg.pole_spacing_m, cfg.pole_altitude_m
        points = np.array([[s, s, -h], [-s, s, -h], [-s, -s, -h], [s, -s, -h]])
    else:
        points = np.array(cfg.positions, dtype=float)
    return np.arange(points.shape[0]), points


def put_landmarks(
    landmarks: FloatArray, n_landmarks: np.ndarray, lane: int, points: FloatArray
) -> FloatArray:
    """Write ``points`` (L, 3) as ``lane``'s map into the lanes' ``landmarks`` (B, Lmax, 3)
    (rows past L zeroed) and L into ``n_landmarks`` (B,).

    Returns:
        ``landmarks``, or a larger copy when L > Lmax (a reset option brought a larger map).
    """
    n = points.shape[0]
    if n > landmarks.shape[1]:
        grown = np.zeros((landmarks.shape[0], n, 3))
        grown[:, : landmarks.shape[1]] = landmarks
        landmarks = grown
    landmarks[lane, :n] = points
    landmarks[lane, n:] = 0.0
    n_landmarks[lane] = n
    return landmarks
