"""EKF-SLAM and FastSLAM sections of ``quadslam bench`` (``ekf``, ``fastslam``).

Estimator scaling is measured on one vehicle with synthetic scans (no env), so it isolates the
filter's own cost: EKF-SLAM as the batch filter with one lane, called with the arrays the env
passes it, FastSLAM through its one-vehicle
:class:`~quadslam_env.estimation.protocol.Estimator` interface:

* EKF-SLAM prediction, update and registration time vs the number of mapped / observed / new
  landmarks (seed 001 Fig. 12);
* FastSLAM prediction and LiDAR-update time vs particles and landmarks.
"""

from __future__ import annotations

import copy
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from functools import partial
from typing import Any

import numpy as np

from agents.lab.bench.plan import Plan, Results
from estimators.ekf.filter import EkfSlamBatch
from estimators.fastslam.dynamic import DynamicFastSLAM
from quadslam_env.estimation.measurements import Control, ImuSample, LidarScan
from quadslam_env.models.frames import dcm_from_euler
from quadslam_env.models.lidar import lidar_measure
from quadslam_env.models.params import vehicle_preset
from quadslam_env.types import GRAVITY

LIDAR_SIGMA = np.radians([0.33, 0.30, 0.0]) + np.array([0.0, 0.0, 0.1])


@contextmanager
def _timer(out: list[float], scale: float = 1e3) -> Iterator[None]:
    tic = time.perf_counter()
    yield
    out.append(scale * (time.perf_counter() - tic))


def _repeat(fn: Callable[[], None], repeats: int, number: int) -> list[float]:
    """``repeats`` samples of the mean time of ``number`` calls of ``fn`` in ms (after warm-up)."""
    fn()
    samples: list[float] = []
    for _ in range(repeats):
        with _timer(samples, 1e3 / number):
            for _ in range(number):
                fn()
    return samples


# ---------------------------------------------------------------- synthetic estimator inputs
def _landmarks_ahead(n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, 3) landmarks inside a ±40° × ±25° cone ahead of a level vehicle at the origin."""
    az = rng.uniform(-0.7, 0.7, n)
    el = rng.uniform(-0.43, 0.43, n)
    rng_m = rng.uniform(8.0, 20.0, n)
    return np.stack(
        [rng_m * np.cos(el) * np.cos(az), rng_m * np.cos(el) * np.sin(az), rng_m * np.sin(el)],
        axis=1,
    )


def _scan(ids: np.ndarray, points: np.ndarray, rng: np.random.Generator) -> LidarScan:
    meas = lidar_measure(np.zeros(3), dcm_from_euler(np.zeros(3)), points)
    meas = meas + LIDAR_SIGMA * rng.standard_normal(meas.shape)
    return LidarScan(t=0.0, ids=ids, meas=meas, sigma=LIDAR_SIGMA)


def _hover_inputs(mass: float) -> tuple[ImuSample, Control]:
    imu = ImuSample(
        t=0.0,
        accel=np.array([0.0, 0.0, -GRAVITY]),
        gyro=np.zeros(3),
        accel_sigma=0.03,
        gyro_sigma=0.002,
    )
    return imu, Control(thrust=mass * GRAVITY, torque=np.zeros(3))


_COV0 = np.diag([1e-3] * 3 + [1e-2] * 3 + [1e-4] * 3 + [1e-6] * 3)
_LANE = np.zeros(1, dtype=np.int64)


def _fresh(name: str, seed: int, **params: Any) -> Any:
    """A reset estimator at the origin: ``"ekf_slam"`` (a batch of one lane) or ``"fastslam"``."""
    vehicle = vehicle_preset("rauniyar2023")
    rng = np.random.default_rng(seed)
    if name == "ekf_slam":
        ekf = EkfSlamBatch(1, 0, vehicle=vehicle, **params)
        ekf.reset_lanes(_LANE, np.zeros((1, 12)), _COV0[None], [rng])
        return ekf
    est = DynamicFastSLAM(vehicle=vehicle, **params)
    est.reset(np.zeros(12), _COV0, rng)
    return est


def _ekf_predict(est: EkfSlamBatch, imu: ImuSample, control: Control) -> Callable[[], None]:
    """One 10 ms prediction of lane 0, its input arrays built once."""
    return partial(
        est.predict,
        np.zeros(1),
        imu.accel[None],
        imu.gyro[None],
        imu.accel_sigma,
        imu.gyro_sigma,
        np.array([control.thrust]),
        control.torque[None],
        0.01,
        np.ones(1, dtype=bool),
    )


def _ekf_update(est: EkfSlamBatch, scan: LidarScan) -> Callable[[], None]:
    """The correction of lane 0 with ``scan`` (ids ≥ 0), its input arrays built once."""
    assert scan.ids is not None
    width = max(est.landmark_capacity, int(scan.ids.max()) + 1)
    visible = np.zeros((1, width), dtype=bool)
    visible[0, scan.ids] = True
    meas = np.zeros((1, width, 3))
    meas[0, scan.ids] = scan.meas
    return partial(est.update, np.zeros(1), _LANE, visible, meas, scan.sigma)


def _mapped(name: str, n_mapped: int, seed: int, **params: Any) -> tuple[Any, np.ndarray]:
    """An estimator that has registered ``n_mapped`` landmarks; returns it and their points."""
    rng = np.random.default_rng(seed)
    points = _landmarks_ahead(n_mapped, rng)
    est = _fresh(name, seed, **params)
    scan = _scan(np.arange(n_mapped), points, rng)
    if name == "ekf_slam":
        _ekf_update(est, scan)()
    else:
        est.update(scan)
    return est, points


def bench_ekf(results: Results, plan: Plan) -> None:
    """EKF-SLAM predict / update / registration time vs landmarks (seed 001 Fig. 12)."""
    vehicle = vehicle_preset("rauniyar2023")
    imu, control = _hover_inputs(vehicle.mass)
    number = 100 if plan.name == "full" else 20
    for n in plan.ekf_sizes:
        est, points = _mapped("ekf_slam", n, seed=n)
        results.add(
            "ekf_slam",
            "predict",
            _repeat(_ekf_predict(est, imu, control), plan.repeats, number),
            "ms",
            n_mapped=n,
        )
        k = min(10, n)
        rng = np.random.default_rng(1)
        scan = _scan(np.arange(k), points[:k], rng)
        results.add(
            "ekf_slam",
            "update",
            _repeat(_ekf_update(est, scan), plan.repeats, number // 4 or 1),
            "ms",
            n_mapped=n,
            n_observed=k,
        )
    n_big = max(plan.ekf_sizes)
    est, points = _mapped("ekf_slam", n_big, seed=7)
    for k in plan.ekf_observed:
        scan = _scan(np.arange(k), points[:k], np.random.default_rng(k))
        results.add(
            "ekf_slam",
            "update",
            _repeat(_ekf_update(est, scan), plan.repeats, 5),
            "ms",
            n_mapped=n_big,
            n_observed=k,
        )
    base, _ = _mapped("ekf_slam", 40, seed=11)
    for m in plan.ekf_observed:
        rng = np.random.default_rng(100 + m)
        scan = _scan(np.arange(40, 40 + m), _landmarks_ahead(m, rng), rng)
        samples: list[float] = []
        for _ in range(plan.repeats):
            trial = copy.deepcopy(base)  # registration changes the map: start from a copy
            register = _ekf_update(trial, scan)
            with _timer(samples):
                register()
        results.add("ekf_slam", "registration", samples, "ms", n_mapped=40, n_new=m)


def bench_fastslam(results: Results, plan: Plan) -> None:
    """FastSLAM predict and LiDAR-update time vs particles and landmarks."""
    vehicle = vehicle_preset("rauniyar2023")
    imu, control = _hover_inputs(vehicle.mass)
    for n_particles in plan.fast_particles:
        for n_lm in plan.fast_landmarks:
            est, points = _mapped("fastslam", n_lm, seed=n_lm, n_particles=n_particles)
            results.add(
                "fastslam",
                "predict",
                _repeat(partial(est.predict, imu, control, 0.01), plan.repeats, 5),
                "ms",
                n_particles=n_particles,
                n_landmarks=n_lm,
            )
            k = min(10, n_lm)
            scan = _scan(np.arange(k), points[:k], np.random.default_rng(3))
            results.add(
                "fastslam",
                "update",
                _repeat(partial(est.update, scan), plan.repeats, 3),
                "ms",
                n_particles=n_particles,
                n_landmarks=n_lm,
                n_observed=k,
            )
