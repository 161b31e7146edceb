"""FastSLAM with unknown data association: per-particle maximum-likelihood association,
tentative landmarks under clutter, reporting and settings (estimators/fastslam/associate.py)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

import estimators
from estimators.fastslam.associate import ParticleMaps
from estimators.fastslam.dynamic import DynamicFastSLAM
from estimators.fastslam.kinematic import KinematicFastSLAM
from estimators.fastslam.landmarks import landmark_ekf_update
from estimators.fastslam.particles import FastSLAMBase
from estimators.fastslam.settings import AssociationSettings
from quadslam_env.estimation.measurements import Control, ImuSample, LidarScan
from quadslam_env.estimation.registry import associates_unlabeled
from quadslam_env.models.frames import dcm_from_euler
from quadslam_env.models.lidar import lidar_measure
from quadslam_env.models.params import vehicle_preset
from quadslam_env.models.rigid_body import specific_force

LIDAR_SIGMA = np.array([math.radians(0.33), math.radians(0.30), 0.1])
# Well separated landmarks around a vehicle hovering at the origin (NED, m).
LANDMARKS = np.array(
    [
        [6.0, 0.0, -1.0],
        [0.0, 7.0, 0.5],
        [-5.0, 1.0, -0.5],
        [1.0, -6.0, 1.0],
        [4.0, 4.0, 0.0],
        [-4.0, -4.0, -1.5],
    ]
)
N_PARTICLES = 40


@dataclass
class Run:
    """A static-scene run: the filter, and per scan the true id and the label of each return."""

    est: FastSLAMBase
    truth: list[np.ndarray] = field(default_factory=list)
    labels: list[np.ndarray] = field(default_factory=list)


def _static_run(
    name: str,
    unknown: bool,
    n_scans: int,
    clutter_rate: float = 0.0,
    seed: int = 0,
    known_map: bool = False,
    **params: object,
) -> Run:
    """Hover at the origin at rest (a fixed point of the dynamics), 100 Hz IMU, 10 Hz scans.

    The noise of the IMU and of the landmark returns comes from ``seed`` alone, so a known-
    and an unknown-association run see the same landmark measurements; clutter (uniform in
    azimuth, ±15° elevation and 1–20 m range) and the shuffling use a second generator.
    """
    vehicle = vehicle_preset("sadeghzadeh2021")
    est = estimators.make(name, vehicle=vehicle, n_particles=N_PARTICLES, **params).lanes[0]
    assert isinstance(est, FastSLAMBase)
    cov0 = np.diag([1e-4] * 6 + [1e-6] * 3 + [1e-8] * 3)
    known = (np.arange(len(LANDMARKS)) + 10, LANDMARKS) if known_map else None
    est.reset(np.zeros(12), cov0, np.random.default_rng(seed + 1), known_landmarks=known)
    noise, extra = np.random.default_rng(seed), np.random.default_rng(seed + 100)
    thrust, torque = vehicle.mass * 9.81, np.zeros(3)
    force = specific_force(np.zeros(3), thrust, vehicle)
    z_true = lidar_measure(np.zeros(3), dcm_from_euler(np.zeros(3)), LANDMARKS)
    sa, sg = 0.03, 0.002
    run = Run(est)
    for k in range(10 * n_scans):
        t = (k + 1) * 0.01
        imu = ImuSample(t, force + noise.normal(0, sa, 3), noise.normal(0, sg, 3), sa, sg)
        est.predict(imu, Control(thrust, torque), 0.01)
        if (k + 1) % 10:
            continue
        z = z_true + noise.normal(size=z_true.shape) * LIDAR_SIGMA
        ids = np.arange(len(LANDMARKS))
        if not unknown:
            est.update(LidarScan(t, ids, z, LIDAR_SIGMA))
            continue
        n_false = extra.poisson(clutter_rate)
        false = np.column_stack(
            [
                extra.uniform(-math.pi, math.pi, n_false),
                extra.uniform(-0.26, 0.26, n_false),
                extra.uniform(1.0, 20.0, n_false),
            ]
        )
        order = extra.permutation(len(ids) + n_false)
        returns = np.vstack([z, false])[order]
        truth = np.r_[ids, np.full(n_false, -1)][order]
        est.update(LidarScan(t, None, returns, LIDAR_SIGMA))
        run.truth.append(truth)
        run.labels.append(est.last_association.copy())
    return run


def _true_id_of_labels(run: Run) -> dict[int, int]:
    """Each reported landmark's label → the id of the nearest true landmark (within 0.3 m)."""
    e = run.est.estimate()
    out = {}
    for label, mean in zip(e.landmark_ids().tolist(), e.mapped_landmarks()[1], strict=True):
        dist = np.linalg.norm(LANDMARKS - mean, axis=1)
        assert dist.min() < 0.3, f"landmark {label} at {mean} is no true landmark"
        out[label] = int(dist.argmin())
    return out


@pytest.mark.parametrize(
    ("name", "params"),
    [
        ("fastslam", {}),
        # Untempered (the baseline's default λ = 1), FastSLAM 1.0 resamples every scan, the
        # cloud collapses onto one lineage whose pose then drifts out of its own landmarks'
        # gates, and a landmark may be mapped twice (docs/fastslam.md); tempered it is fine.
        ("fastslam_kinematic", {"likelihood_inflation": 30.0}),
    ],
)
def test_ml_association_recovers_the_known_association_map(
    name: str, params: dict[str, Any]
) -> None:
    n_scans = 30
    known = _static_run(name, unknown=False, n_scans=n_scans, **params)
    run = _static_run(name, unknown=True, n_scans=n_scans, **params)
    named = _true_id_of_labels(run)
    assert sorted(named.values()) == list(range(len(LANDMARKS)))  # one entry per landmark
    # M = 3 of N = 5 (default): no landmark before its third sighting, every landmark
    # confirmed within its first five; from then on every return is paired with the entry
    # of its own landmark.
    assert np.all(run.labels[0] == -1) and np.all(run.labels[1] == -1)
    for truth, labels in zip(run.truth[4:], run.labels[4:], strict=True):
        np.testing.assert_array_equal([named.get(int(c), -1) for c in labels], truth)
    # The same map as with known association, up to SLAM's unobservable common translation
    # (compare the landmarks relative to the estimated vehicle): the landmarks are ≥ 5 m
    # apart and both maps ~5 cm off the truth, so 0.15 m tells the same map from a mix-up.
    e, ek = run.est.estimate(), known.est.estimate()
    order = np.argsort([named[int(c)] for c in e.landmark_ids()])
    relative = e.mapped_landmarks()[1][order] - e.position[0]
    np.testing.assert_allclose(relative, ek.mapped_landmarks()[1] - ek.position[0], atol=0.15)
    assert run.est.state.maps is not None
    np.testing.assert_array_equal(run.est.state.maps.size, len(LANDMARKS))  # no duplicates


def _two_particle_scene(p0: float = 1e-3) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Particle 0 at the origin, particle 1 0.5 m ahead (both level); each maps landmarks
    (5, 0, 0) and (0, 5, 0) m with σ = 0.1 m. Returns: both landmarks seen noise-free from
    particle 0, and a false return; the returns are (α, β, δ)."""
    x = np.zeros((2, 12))
    x[1, 0] = 0.5
    mu = np.broadcast_to(np.array([[5.0, 0.0, 0.0], [0.0, 5.0, 0.0]]), (2, 2, 3)).copy()
    sigma = np.broadcast_to(0.01 * np.eye(3), (2, 2, 3, 3)).copy()
    z = lidar_measure(np.zeros(3), np.eye(3), np.vstack([mu[0], [[-5.0, -5.0, 0.0]]]))
    return x, mu, sigma, z


def _maps(n: int) -> ParticleMaps:
    """Per-particle maps of n particles holding the two landmarks of the scene."""
    maps = ParticleMaps(n, None)
    maps.size[:] = 2
    return maps


def test_ml_association_kernel_pairs_updates_and_weights_per_particle() -> None:
    x, mu, sigma, z = _two_particle_scene()
    R = np.diag(LIDAR_SIGMA**2)
    cfg = AssociationSettings(new_landmark_likelihood=1e-3)
    ref_mu, ref_sigma, ref_ll, _ = landmark_ekf_update(
        mu[0], sigma[0], x[0, 0:3], np.eye(3), z[:2], R
    )
    maps = _maps(2)
    for scan in range(3):
        mu, sigma, loglik, _, dof = maps.associate(x, mu, sigma, z, R, cfg, 1.0)
        if scan == 0:
            # Particle 0 pairs each landmark return with its landmark (the same EKF update and
            # likelihood as with known association) and leaves the false return unpaired.
            np.testing.assert_array_equal(maps.assoc[0, :3], [0, 1, -1])
            np.testing.assert_allclose(mu[0, :2], ref_mu, atol=1e-12)
            np.testing.assert_allclose(sigma[0, :2], ref_sigma, atol=1e-15)
            np.testing.assert_allclose(loglik[0], ref_ll.sum() + math.log(1e-3), rtol=1e-12)
            # Particle 1 is 0.5 m off (νᵀS⁻¹ν ≫ χ²₃): nothing gates, every return is p0.
            np.testing.assert_array_equal(maps.assoc[1, :3], -1)
            np.testing.assert_allclose(loglik[1], 3 * math.log(1e-3))
            np.testing.assert_array_equal(maps.n_paired, [2, 0])
            np.testing.assert_array_equal(dof, [6, 0])
    # M = 3 of N = 5: the third sighting of each unexplained return maps it, in the next slot.
    np.testing.assert_array_equal(maps.size, [3, 5])
    np.testing.assert_array_equal(maps.assoc[0, :3], [0, 1, 2])
    np.testing.assert_array_equal(maps.assoc[1, :3], [2, 3, 4])
    np.testing.assert_allclose(mu[0, 2], [-5.0, -5.0, 0.0], atol=1e-9)


def test_likelihood_inflation_widens_the_gate_and_tempers_the_likelihood() -> None:
    x, mu, sigma, z = _two_particle_scene()
    R = np.diag(LIDAR_SIGMA**2)
    lam = 100.0
    _, _, ll, q = landmark_ekf_update(mu[1], sigma[1], x[1, 0:3], np.eye(3), z[:2], R)
    assert np.all(q > 11.35) and np.all(q / lam < 11.34)  # outside χ²₃(0.99), inside λ·χ²₃
    maps = _maps(2)
    cfg = AssociationSettings()
    _, _, loglik, nis, _ = maps.associate(x, mu, sigma, z, R, cfg, lam)
    np.testing.assert_array_equal(maps.assoc[1, :3], [0, 1, -1])
    # log N(ν; 0, λS) = log N(ν; 0, S) + ½ q (1 − 1/λ) − (3/2) log λ
    tempered = ll + 0.5 * q * (1.0 - 1.0 / lam) - 1.5 * math.log(lam)
    np.testing.assert_allclose(loglik[1], tempered.sum() + math.log(cfg.new_landmark_likelihood))
    np.testing.assert_allclose(nis[1], q.sum())  # the NIS is not inflated


def test_a_landmark_takes_the_most_likely_return_and_p0_rejects_unlikely_pairs() -> None:
    x, mu, sigma, z = _two_particle_scene()
    R = np.diag(LIDAR_SIGMA**2)
    near = z[0] + np.array([0.0, 0.0, 0.05])  # a second return close to landmark 0
    returns = np.vstack([near, z[0]])
    maps = _maps(2)
    maps.associate(x[:1], mu[:1], sigma[:1], returns, R, AssociationSettings(), 1.0)
    np.testing.assert_array_equal(maps.assoc[0, :2], [-1, 0])  # the exact one wins
    assert maps.candidates.active()[0] == 0  # the ambiguous one starts no candidate
    huge = AssociationSettings(new_landmark_likelihood=1e12)  # above any N(ν; 0, S) here
    maps = _maps(1)
    maps.associate(x[:1], mu[:1], sigma[:1], returns, R, huge, 1.0)
    np.testing.assert_array_equal(maps.assoc[0, :2], [-1, -1])
    assert maps.candidates.active()[0] == 2  # new-landmark hypotheses


def test_clutter_does_not_enter_the_map_of_any_particle() -> None:
    run = _static_run("fastslam", unknown=True, n_scans=40, clutter_rate=3.0, seed=4)
    n_false = sum(int((t < 0).sum()) for t in run.truth)
    assert n_false > 80  # the scans did carry clutter
    named = _true_id_of_labels(run)
    assert len(named) == len(LANDMARKS)
    maps = run.est.state.maps
    assert maps is not None
    np.testing.assert_array_equal(maps.size, len(LANDMARKS))  # no spurious landmark anywhere
    for truth, labels in zip(run.truth[4:], run.labels[4:], strict=True):
        assert np.all(labels[truth < 0] == -1)  # clutter paired with nothing
        true = truth >= 0
        np.testing.assert_array_equal([named.get(int(c), -1) for c in labels[true]], truth[true])


def test_same_seed_gives_the_same_association_and_map() -> None:
    a = _static_run("fastslam", unknown=True, n_scans=15, clutter_rate=3.0, seed=9)
    b = _static_run("fastslam", unknown=True, n_scans=15, clutter_rate=3.0, seed=9)
    for la, lb in zip(a.labels, b.labels, strict=True):
        np.testing.assert_array_equal(la, lb)
    ea, eb = a.est.estimate(), b.est.estimate()
    np.testing.assert_array_equal(ea.mapped_landmarks()[1], eb.mapped_landmarks()[1])
    np.testing.assert_array_equal(ea.position[0], eb.position[0])
    np.testing.assert_array_equal(a.est.state.logw, b.est.state.logw)


def test_known_map_mode_pairs_with_the_known_ids_and_drops_the_rest() -> None:
    run = _static_run("fastslam", unknown=True, n_scans=10, clutter_rate=3.0, known_map=True)
    for truth, labels in zip(run.truth, run.labels, strict=True):
        np.testing.assert_array_equal(labels[truth >= 0], truth[truth >= 0] + 10)
        assert np.all(labels[truth < 0] == -1)
    e = run.est.estimate()
    np.testing.assert_array_equal(e.landmark_ids(), np.arange(len(LANDMARKS)) + 10)
    np.testing.assert_allclose(e.mapped_landmarks()[1], LANDMARKS, atol=1e-2)


def test_resampling_carries_the_per_particle_maps_and_the_reported_particle() -> None:
    run = _static_run("fastslam", unknown=True, n_scans=4, clutter_rate=3.0)
    est, maps = run.est, run.est.state.maps
    assert maps is not None
    maps.size[:] = np.arange(N_PARTICLES) % 7  # distinguishable map sizes
    maps.candidates.hits[:, 0] = np.arange(N_PARTICLES)
    maps.report = 5
    idx = np.r_[np.full(10, 3), np.full(N_PARTICLES - 10, 5)]
    est._resample(idx)
    np.testing.assert_array_equal(maps.size, idx % 7)
    np.testing.assert_array_equal(maps.candidates.hits[:, 0], idx)
    assert maps.report == 10  # the first copy of particle 5
    e = est.estimate()
    np.testing.assert_array_equal(e.landmark_ids(), np.arange(5))
    np.testing.assert_array_equal(e.mapped_landmarks()[1], est.state.mu[10, :5])


def test_labeled_and_unlabeled_scans_do_not_mix_in_slam() -> None:
    est = DynamicFastSLAM(vehicle_preset("sadeghzadeh2021"), n_particles=10)
    est.reset(np.zeros(12), np.eye(12) * 1e-6, np.random.default_rng(0))
    z = lidar_measure(np.zeros(3), np.eye(3), LANDMARKS)
    est.update(LidarScan(0.0, None, z, LIDAR_SIGMA))
    with pytest.raises(ValueError, match="labeled scan after unlabeled"):
        est.update(LidarScan(0.1, np.arange(len(LANDMARKS)), z, LIDAR_SIGMA))
    other = KinematicFastSLAM(n_particles=10)
    other.reset(np.zeros(12), np.eye(12) * 1e-6, np.random.default_rng(0))
    other.update(LidarScan(0.0, np.arange(len(LANDMARKS)), z, LIDAR_SIGMA))
    with pytest.raises(ValueError, match="unlabeled scan after labeled"):
        other.update(LidarScan(0.1, None, z, LIDAR_SIGMA))
    with pytest.raises(ValueError, match="finite"):
        est.update(LidarScan(0.2, None, np.full((2, 3), np.nan), LIDAR_SIGMA))


@pytest.mark.parametrize(
    ("key", "value", "allowed"),
    [
        ("gate_probability", 0.0, "> 0.0 and <= 1.0"),
        ("gate_probability", 1.5, "> 0.0 and <= 1.0"),
        ("new_landmark_likelihood", 0.0, "> 0"),
        ("new_landmark_likelihood", float("nan"), "> 0"),
        ("confirm_hits", 0, ">= 1 and <= 1000"),
        ("confirm_window", 2, r"\[confirm_hits = 3, 1000\]"),
        ("confirm_hits", 2.5, "an integer"),
        ("confirm_window", True, "an integer"),
    ],
)
def test_invalid_association_settings_name_key_value_and_what_is_allowed(
    key: str, value: object, allowed: str
) -> None:
    for cls in (DynamicFastSLAM, KinematicFastSLAM):
        with pytest.raises(ValueError, match=rf"estimator\.params\.{key}.*{value!r}.*{allowed}|"
                           rf"estimator\.params\.{key}: {allowed}.*{value!r}"):  # fmt: skip
            cls(vehicle_preset("sadeghzadeh2021"), **{key: value})


def test_registered_fastslam_filters_accept_unknown_association_in_the_env() -> None:
    assert associates_unlabeled("fastslam") and associates_unlabeled("fastslam_kinematic")
    env = gym.make(
        "QuadSLAM-v0",
        scenario="fastslam_helix_unknown",
        estimator={"params": {"n_particles": 30}},
        episode={"duration_s": 1.0},
    )
    env.reset(seed=0)
    info: dict[str, object] = {}
    for _ in range(100):
        _, _, terminated, truncated, info = env.step(np.zeros(4, dtype=np.float32))
        if terminated or truncated:
            break
    assert "episode_assoc_wrong_rate" in info and "episode_spurious_landmarks" in info
    env.close()
