"""``quadslam bench``: speed and scaling of the envs and the estimators.

Every measurement is repeated (after a warm-up) and reported as median / min / max with its
unit. Estimator scaling is measured through the public :class:`estimators.Estimator` protocol
with synthetic scans (no env), so it isolates the filter's own cost:

* EKF-SLAM prediction, update and registration time vs the number of mapped / observed / new
  landmarks (seed 001 Fig. 12);
* FastSLAM prediction and LiDAR-update time vs particles and landmarks;
* env steps per second through ``gymnasium.make`` (zero action and DF-LQR in the loop) and the
  real-time factor;
* vectorised throughput with ``gymnasium.vector.AsyncVectorEnv`` and SB3 ``SubprocVecEnv``.
"""

from __future__ import annotations

import copy
import json
import math
import os
import platform
import statistics
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

import estimators
from quadslam_env.measurements import Control, ImuSample, LidarScan
from quadslam_env.models.dynamics import GRAVITY, vehicle_preset
from quadslam_env.models.lidar import lidar_measure
from quadslam_env.models.rotations import dcm_from_euler

LIDAR_SIGMA = np.radians([0.33, 0.30, 0.0]) + np.array([0.0, 0.0, 0.1])


@dataclass
class Plan:
    """Sizes and repeats of one benchmark run (``quick`` or full)."""

    env_steps: int
    repeats: int
    ekf_sizes: tuple[int, ...]
    ekf_observed: tuple[int, ...]
    fast_particles: tuple[int, ...]
    fast_landmarks: tuple[int, ...]
    fast_env_particles: tuple[int, ...]
    workers: tuple[int, ...]
    vec_steps: int


QUICK = Plan(
    env_steps=300,
    repeats=3,
    ekf_sizes=(5, 50, 200),
    ekf_observed=(1, 10),
    fast_particles=(100, 1000),
    fast_landmarks=(40,),
    fast_env_particles=(100,),
    workers=(1, 2),
    vec_steps=100,
)
FULL = Plan(
    env_steps=3000,
    repeats=5,
    ekf_sizes=(5, 10, 20, 50, 100, 200, 300, 500),
    ekf_observed=(1, 2, 5, 10, 20, 40),
    fast_particles=(100, 500, 1000, 2000, 5000),
    fast_landmarks=(10, 40, 100, 200),
    fast_env_particles=(100, 500, 1000),
    workers=(1, 2, 4),
    vec_steps=1000,
)


class Results:
    """Collects measurements as JSON-ready entries."""

    def __init__(self) -> None:
        self.entries: list[dict[str, Any]] = []

    def add(
        self, group: str, name: str, samples: list[float], unit: str, **params: Any
    ) -> dict[str, Any]:
        entry = {
            "group": group,
            "name": name,
            "params": params,
            "unit": unit,
            "median": statistics.median(samples),
            "min": min(samples),
            "max": max(samples),
            "n": len(samples),
        }
        self.entries.append(entry)
        return entry


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


def _fresh(name: str, seed: int, **params: Any) -> Any:
    vehicle = vehicle_preset("rauniyar2023")
    est = estimators.make(name, vehicle=vehicle, **params)
    cov0 = np.diag([1e-3] * 3 + [1e-2] * 3 + [1e-4] * 3 + [1e-6] * 3)
    est.reset(np.zeros(12), cov0, np.random.default_rng(seed))
    return est


def _mapped(name: str, n_mapped: int, seed: int, **params: Any) -> tuple[Any, np.ndarray]:
    """An estimator that has registered ``n_mapped`` landmarks; returns it and their points."""
    rng = np.random.default_rng(seed)
    points = _landmarks_ahead(n_mapped, rng)
    est = _fresh(name, seed, **params)
    est.update(_scan(np.arange(n_mapped), points, rng))
    return est, points


def bench_ekf(results: Results, plan: Plan) -> None:
    """EKF-SLAM predict / update / registration time vs landmarks (seed 001 Fig. 12)."""
    vehicle = vehicle_preset("rauniyar2023")
    imu, control = _hover_inputs(vehicle.mass)
    number = 20 if plan is QUICK else 100
    for n in plan.ekf_sizes:
        est, points = _mapped("ekf_slam", n, seed=n)
        results.add(
            "ekf_slam",
            "predict",
            _repeat(lambda e=est: e.predict(imu, control, 0.01), plan.repeats, number),
            "ms",
            n_mapped=n,
        )
        k = min(10, n)
        rng = np.random.default_rng(1)
        scan = _scan(np.arange(k), points[:k], rng)
        results.add(
            "ekf_slam",
            "update",
            _repeat(lambda e=est, s=scan: e.update(s), plan.repeats, number // 4 or 1),
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
            _repeat(lambda e=est, s=scan: e.update(s), plan.repeats, 5),
            "ms",
            n_mapped=n_big,
            n_observed=k,
        )
    base, _ = _mapped("ekf_slam", 40, seed=11)
    for m in plan.ekf_observed:
        rng = np.random.default_rng(100 + m)
        scan = _scan(np.arange(40, 40 + m), _landmarks_ahead(m, rng), rng)
        samples = []
        for _ in range(plan.repeats):
            trial = copy.deepcopy(base)  # registration changes the map: start from a copy
            with _timer(samples):
                trial.update(scan)
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
                _repeat(lambda e=est: e.predict(imu, control, 0.01), plan.repeats, 5),
                "ms",
                n_particles=n_particles,
                n_landmarks=n_lm,
            )
            k = min(10, n_lm)
            scan = _scan(np.arange(k), points[:k], np.random.default_rng(3))
            results.add(
                "fastslam",
                "update",
                _repeat(lambda e=est, s=scan: e.update(s), plan.repeats, 3),
                "ms",
                n_particles=n_particles,
                n_landmarks=n_lm,
                n_observed=k,
            )


# ---------------------------------------------------------------- env throughput
def _env_rate(env: Any, policy: Any, steps: int, repeats: int) -> list[float]:
    """Steps per second over ``repeats`` blocks of ``steps`` steps (resets included)."""
    obs, _ = env.reset(seed=0)
    zero = np.zeros(env.action_space.shape, dtype=np.float32)
    samples = []
    for _ in range(repeats + 1):  # the first block is the warm-up
        tic = time.perf_counter()
        for _ in range(steps):
            action = zero if policy is None else policy.predict(obs)[0]
            obs, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                obs, _ = env.reset()
        samples.append(steps / (time.perf_counter() - tic))
    return samples[1:]


def bench_env(results: Results, plan: Plan) -> None:
    """Steps/s of each env id through ``gymnasium.make`` with a zero action and with DF-LQR."""
    import gymnasium as gym

    import quadslam_env  # noqa: F401
    from agents.dflqr import DFLQRPolicy

    cases: list[tuple[str, str, dict[str, Any]]] = [
        ("QuadSLAM-Oracle-v0", "oracle", {}),
        ("QuadSLAM-EKF-v0", "ekf_slam", {}),
    ]
    for n in plan.fast_env_particles:
        cases.append(
            (
                "QuadSLAM-FastSLAM-v0",
                f"fastslam_N{n}",
                {"estimator": {"params": {"n_particles": n}}},
            )
        )
    for env_id, label, kwargs in cases:
        env = gym.make(env_id, **kwargs)
        dt = env.unwrapped.dt
        n_lm = int(
            env.unwrapped.scenario.landmarks.count
            if env.unwrapped.scenario.landmarks.layout == "rauniyar2023"
            else 4
        )
        steps = plan.env_steps if "fastslam" not in label else max(100, plan.env_steps // 10)
        for policy_name, policy in (("zero", None), ("dflqr", DFLQRPolicy.from_env(env))):
            rates = _env_rate(env, policy, steps, plan.repeats)
            results.add(
                "env",
                f"steps_per_s/{label}/{policy_name}",
                rates,
                "steps/s",
                env_id=env_id,
                estimator=label,
                policy=policy_name,
                landmarks=n_lm,
            )
            results.add(
                "env",
                f"real_time_factor/{label}/{policy_name}",
                [r * dt for r in rates],
                "x real time",
                env_id=env_id,
                estimator=label,
                policy=policy_name,
            )
        env.close()


def _ekf_env() -> Any:
    import gymnasium as gym

    import quadslam_env  # noqa: F401

    return gym.make("QuadSLAM-EKF-v0")


def bench_vector(results: Results, plan: Plan) -> None:
    """Total steps/s of AsyncVectorEnv and SB3 SubprocVecEnv with 1, 2, 4 workers (EKF env)."""
    import gymnasium as gym
    from stable_baselines3.common.vec_env import SubprocVecEnv

    for n in plan.workers:
        for kind in ("gymnasium_async", "sb3_subproc"):
            if kind == "gymnasium_async":
                venv: Any = gym.vector.AsyncVectorEnv([_ekf_env] * n)
                venv.reset(seed=0)

                def step(v: Any = venv, n: int = n) -> None:
                    v.step(np.zeros((n, 4), dtype=np.float32))
            else:
                venv = SubprocVecEnv([_ekf_env] * n)
                venv.seed(0)
                venv.reset()

                def step(v: Any = venv, n: int = n) -> None:
                    v.step(np.zeros((n, 4), dtype=np.float32))

            samples = []
            step()
            for _ in range(plan.repeats):
                tic = time.perf_counter()
                for _ in range(plan.vec_steps):
                    step()
                samples.append(n * plan.vec_steps / (time.perf_counter() - tic))
            venv.close()
            results.add(
                "vector",
                f"{kind}/{n}_workers",
                samples,
                "steps/s",
                workers=n,
                kind=kind,
                env_id="QuadSLAM-EKF-v0",
            )


# ---------------------------------------------------------------- report
def machine_info() -> dict[str, Any]:
    """What the numbers were measured on."""
    import gymnasium
    import stable_baselines3

    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {
        "cpu": cpu,
        "cores": os.cpu_count(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "gymnasium": gymnasium.__version__,
        "stable_baselines3": stable_baselines3.__version__,
        "platform": platform.platform(),
    }


def write_plots(entries: list[dict[str, Any]], out_dir: Path) -> list[Path]:
    """Scaling curves (PNG) of the EKF-SLAM and FastSLAM measurements."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir.mkdir(parents=True, exist_ok=True)

    def series(
        group: str, name: str, x: str, **fixed: Any
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        rows = [
            e
            for e in entries
            if e["group"] == group
            and e["name"] == name
            and x in e["params"]
            and all(e["params"].get(k) == v for k, v in fixed.items())
        ]
        rows.sort(key=lambda e: e["params"][x])
        return (
            np.array([e["params"][x] for e in rows]),
            np.array([e["median"] for e in rows]),
            np.array([e["min"] for e in rows]),
            np.array([e["max"] for e in rows]),
        )

    def plot(ax: Any, data: tuple[np.ndarray, ...], label: str, color: str | None = None) -> None:
        x, med, lo, hi = data
        if x.size:
            ax.errorbar(
                x,
                med,
                yerr=[med - lo, hi - med],
                fmt="o-",
                ms=3,
                capsize=2,
                label=label,
                color=color,
            )

    paths = []
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
    plot(axes[0], series("ekf_slam", "predict", "n_mapped"), "predict")
    axes[0].set_xlabel("mapped landmarks")
    axes[0].set_ylabel("time [ms]")
    axes[0].set_title("EKF-SLAM prediction")
    n_big = max(
        (
            e["params"].get("n_mapped", 0)
            for e in entries
            if e["name"] == "update" and e["group"] == "ekf_slam" and "n_observed" in e["params"]
        ),
        default=0,
    )
    plot(axes[1], series("ekf_slam", "update", "n_mapped", n_observed=10), "10 observed")
    axes[1].set_xlabel("mapped landmarks")
    axes[1].set_title("EKF-SLAM update")
    ax_obs = axes[1].twiny()
    plot(
        ax_obs,
        series("ekf_slam", "update", "n_observed", n_mapped=n_big),
        f"{n_big} mapped (top axis: observed)",
        color="C1",
    )
    axes[1].legend(fontsize=7, loc="upper left")
    ax_obs.legend(fontsize=7, loc="lower right")
    plot(axes[2], series("ekf_slam", "registration", "n_new"), "registration")
    axes[2].set_xlabel("new landmarks in one scan")
    axes[2].set_title("EKF-SLAM registration")
    fig.tight_layout()
    paths.append(out_dir / "ekf_scaling.png")
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    for name, ax in zip(("predict", "update"), axes, strict=True):
        for n_lm in sorted(
            {e["params"]["n_landmarks"] for e in entries if e["group"] == "fastslam"}
        ):
            plot(ax, series("fastslam", name, "n_particles", n_landmarks=n_lm), f"{n_lm} landmarks")
        ax.set_xlabel("particles")
        ax.set_ylabel("time [ms]")
        ax.set_title(f"FastSLAM {name}")
        ax.legend(fontsize=7)
    fig.tight_layout()
    paths.append(out_dir / "fastslam_scaling.png")
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)
    return paths


def format_results(entries: list[dict[str, Any]]) -> str:
    """Plain-text table of all measurements."""
    rows = [("group", "measurement", "params", "median", "min", "max", "unit")]
    for e in entries:
        params = ", ".join(
            f"{k}={v}"
            for k, v in e["params"].items()
            if k not in ("env_id", "kind", "policy", "estimator")
        )
        rows.append(
            (
                e["group"],
                e["name"],
                params,
                _fmt(e["median"]),
                _fmt(e["min"]),
                _fmt(e["max"]),
                e["unit"],
            )
        )
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    return "\n".join("  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)) for r in rows)


def _fmt(value: float) -> str:
    if value == 0 or not math.isfinite(value):
        return str(value)
    return f"{value:.4g}"


SECTIONS: dict[str, Callable[[Results, Plan], None]] = {
    "ekf": bench_ekf,
    "fastslam": bench_fastslam,
    "env": bench_env,
    "vector": bench_vector,
}


def run_bench(quick: bool, only: list[str] | None = None, progress: bool = True) -> dict[str, Any]:
    """Run the benchmark sections and return the JSON document."""
    from tqdm import tqdm

    plan = QUICK if quick else FULL
    results = Results()
    names = only or list(SECTIONS)
    tic = time.perf_counter()
    for name in tqdm(names, desc="bench", unit="section", disable=not progress):
        SECTIONS[name](results, plan)
    return {
        "machine": machine_info(),
        "quick": quick,
        "sections": names,
        "wall_time_s": time.perf_counter() - tic,
        "results": results.entries,
    }


def main_bench(
    quick: bool, json_path: Path | None, plots: Path | None, only: list[str] | None = None
) -> dict[str, Any]:
    """CLI body: run, print the table, write JSON and plots."""
    doc = run_bench(quick, only)
    print(format_results(doc["results"]))
    print(
        f"machine: {doc['machine']['cpu']} ({doc['machine']['cores']} cores); "
        f"wall time {doc['wall_time_s']:.1f} s"
    )
    if json_path is not None:
        json_path.parent.mkdir(parents=True, exist_ok=True)
        json_path.write_text(json.dumps(doc, indent=2))
        print(f"json: {json_path}")
    if plots is not None:
        files = write_plots(doc["results"], plots)
        print(f"plots: {', '.join(str(f) for f in files)}")
    return doc
