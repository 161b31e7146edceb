"""Long-flight soak test: numerical health and memory of the env with an estimator in the loop.

One long episode of the DF-LQR baseline flying on the estimate, with per-step checks that the
estimate stays finite and periodic checks (every ``sample_every`` steps) that the covariances
stay symmetric and positive semi-definite, plus resident memory (RSS) samples from which the
growth per 1000 steps is fitted. Not part of the default tests (an hour of simulated flight
takes tens of minutes); ``tests/studies/test_soak.py`` runs a short version.

Scenarios:

* ``ekf_slam``: ``paper_ekf_figure8`` (the 25 s figure-8 is periodic, so it simply repeats).
* ``fastslam`` / ``fastslam_kinematic``: ``paper_fastslam_helix`` with the climb rate set to 0
  (a circle at 0.75 m altitude); with the scenario's 0.01 m/s climb an hour of flight would
  climb 36 m and leave the ±15° vertical FOV of the poles.
* ``isam2``: ``ekf_out_of_view_600s`` (the landmarks leave the LiDAR's view for about two
  thirds of every lap and come back), the fixed-lag smoother with its default window; a
  landmark's variable outlives the window, so this exercises re-observation after
  marginalisation (needs GTSAM).

Usage::

    OPENBLAS_NUM_THREADS=1 quadslam study soak --estimator ekf_slam --hours 1 \\
        --json docs/results/soak_ekf_slam.json
    OPENBLAS_NUM_THREADS=1 quadslam study soak --estimator fastslam --particles 200 \\
        --hours 1 --json docs/results/soak_fastslam.json
"""

from __future__ import annotations

import os

# Single-threaded BLAS (see agents/lab/cli/main.py); set before numpy is imported.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import math  # noqa: E402
import platform  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from collections.abc import Sequence  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402

from agents.evaluation.episodes import json_float  # noqa: E402
from agents.io.memory import peak_rss_mb, rss_mb  # noqa: E402
from agents.io.outputs import OutputWriteError, Saver  # noqa: E402
from agents.io.paths import check_output_file  # noqa: E402

SCENARIOS: dict[str, tuple[str, dict[str, Any]]] = {
    "ekf_slam": ("paper_ekf_figure8", {}),
    "fastslam": ("paper_fastslam_helix", {"trajectory": {"climb_rate_mps": 0.0}}),
    "fastslam_kinematic": ("paper_fastslam_helix", {"trajectory": {"climb_rate_mps": 0.0}}),
    "isam2": ("ekf_out_of_view_600s", {}),
}
DEFAULT_PARTICLES = 200


def cov_health(cov: np.ndarray) -> tuple[float, float, float]:
    """``(max|P − Pᵀ|, min eigenvalue of ½(P + Pᵀ), scale = max |diag P|)`` of a square matrix.

    A stack (..., n, n) is reduced over all its matrices.
    """
    cov = np.asarray(cov, dtype=float)
    if cov.size == 0:
        return 0.0, math.inf, 0.0
    sym = 0.5 * (cov + np.swapaxes(cov, -1, -2))
    asym = float(np.max(np.abs(cov - np.swapaxes(cov, -1, -2))))
    min_eig = float(np.min(np.linalg.eigvalsh(sym)))
    scale = float(np.max(np.abs(np.diagonal(cov, axis1=-2, axis2=-1))))
    return asym, min_eig, scale


class _Extremes:
    """Running worst case of a covariance's asymmetry and smallest eigenvalue."""

    def __init__(self) -> None:
        self.max_asym = 0.0
        self.max_rel_asym = 0.0
        self.min_eig = math.inf
        self.min_rel_eig = math.inf
        self.max_scale = 0.0
        self.samples = 0

    def add(self, cov: np.ndarray | None) -> None:
        if cov is None or np.asarray(cov).size == 0:
            return
        asym, min_eig, scale = cov_health(cov)
        rel = max(scale, 1e-300)
        self.max_asym = max(self.max_asym, asym)
        self.max_rel_asym = max(self.max_rel_asym, asym / rel)
        self.min_eig = min(self.min_eig, min_eig)
        self.min_rel_eig = min(self.min_rel_eig, min_eig / rel)
        self.max_scale = max(self.max_scale, scale)
        self.samples += 1

    def as_dict(self) -> dict[str, Any]:
        return {
            "samples": self.samples,
            "max_asymmetry": json_float(self.max_asym),
            "max_rel_asymmetry": json_float(self.max_rel_asym),
            "min_eigenvalue": json_float(self.min_eig),
            "min_rel_eigenvalue": json_float(self.min_rel_eig),
            "max_diag": json_float(self.max_scale),
        }


def make_soak_env(
    estimator: str, sim_seconds: float, n_particles: int | None = None
) -> tuple[Any, str, dict[str, Any]]:
    """The soak env, its scenario name and the overrides applied (for the report)."""
    import gymnasium as gym

    import quadslam_env  # noqa: F401  (registers the ids)

    if estimator not in SCENARIOS:
        raise ValueError(f"estimator: got {estimator!r}; allowed: {sorted(SCENARIOS)}")
    if not (math.isfinite(sim_seconds) and sim_seconds > 0):
        raise ValueError(f"sim_seconds: got {sim_seconds!r}; allowed: a finite number > 0")
    scenario, extra = SCENARIOS[estimator]
    est_cfg: dict[str, Any] = {"name": estimator}
    if estimator.startswith("fastslam"):
        n = DEFAULT_PARTICLES if n_particles is None else int(n_particles)
        est_cfg["params"] = {"n_particles": n}
    elif n_particles is not None:
        raise ValueError(f"n_particles: got {n_particles!r}; only the FastSLAM filters use it")
    overrides = {**extra, "estimator": est_cfg, "episode": {"duration_s": float(sim_seconds)}}
    env = gym.make("QuadSLAM-v0", scenario=scenario, **overrides)
    return env, scenario, overrides


def run_soak(
    estimator: str,
    sim_seconds: float,
    n_particles: int | None = None,
    seed: int = 0,
    progress: bool = True,
    sample_every: int = 100,
    control: str = "estimate",
) -> dict[str, Any]:
    """Fly one long DF-LQR episode on the estimate and report numerical health and memory.

    Args:
        estimator: ``"ekf_slam"``, ``"fastslam"``, ``"fastslam_kinematic"`` or ``"isam2"``.
        sim_seconds: Simulated flight time in s (the episode's ``duration_s``).
        n_particles: Particle count for the FastSLAM filters (default 200).
        seed: Reset seed.
        progress: Show a tqdm progress bar on stderr.
        sample_every: Steps between covariance and RSS samples.
        control: ``"estimate"`` (default): the DF-LQR flies on the env's observation, i.e. on
            the estimate. ``"truth"``: it flies on the observation built from the true state
            (as in :mod:`agents.lab.estimator_studies.consistency`), so the flight does not depend
            on the estimate and the estimator is exercised for the whole duration even if its
            accuracy would make an estimate-driven flight leave the position-error limit.

    Returns:
        A JSON-serialisable report: wall/simulated time, steps, RSS at start/end and the fitted
        growth per 1000 steps, the worst asymmetry ``max|P − Pᵀ|`` and smallest eigenvalue of
        the pose covariance (and of the landmark and, for EKF-SLAM, the full covariance), final
        and worst errors, whether any estimate was non-finite, and the termination reason.
    """
    from agents.control.dflqr import DFLQRPolicy
    from estimators.oracle import OracleBatch

    if control not in ("estimate", "truth"):
        raise ValueError(f"control: got {control!r}; allowed: 'estimate' or 'truth'")
    env, scenario, overrides = make_soak_env(estimator, sim_seconds, n_particles)
    base = env.unwrapped
    policy = DFLQRPolicy.from_env(env)
    oracle = OracleBatch(num_lanes=1, landmark_capacity=0) if control == "truth" else None

    record = _SoakRecord()
    obs, info = env.reset(seed=seed)
    record.rss_start = rss_mb()
    bar = _progress_bar(base.max_steps, f"soak {estimator}") if progress else None
    tic = time.perf_counter()
    info, terminated, truncated = _fly(env, obs, policy, oracle, record, sample_every, bar)
    wall = time.perf_counter() - tic
    if bar is not None:
        bar.close()
    rss_end = rss_mb()
    env.close()
    steps = record.steps
    params = base.scenario.estimator.params
    return {
        "estimator": estimator,
        "scenario": scenario,
        "overrides": overrides,
        "n_particles": params.get("n_particles"),
        "seed": int(seed),
        "control": control,
        "sim_seconds_requested": float(sim_seconds),
        "sim_seconds": float(info["t"]),
        "steps": steps,
        "wall_time_s": wall,
        "steps_per_s": steps / wall if wall > 0 else None,
        "terminated": bool(terminated),
        "termination_reason": str(info.get("termination_reason", "")) if terminated else "",
        "truncated": bool(truncated),
        **record.report(rss_end),
        "final_est_pos_err_m": json_float(info["est_pos_err_m"]),
        "final_est_att_err_deg": json_float(info["est_att_err_deg"]),
        "final_track_pos_err_m": json_float(info["track_pos_err_m"]),
        "final_map_rmse_m": json_float(info.get("est_map_rmse_m", math.nan)),
        "final_n_mapped": json_float(info["est_n_mapped"]),
        "sample_every": sample_every,
        "machine": _machine(),
    }


def _fly(
    env: Any,
    obs: np.ndarray,
    policy: Any,
    oracle: Any,
    record: _SoakRecord,
    sample_every: int,
    bar: Any,
) -> tuple[dict[str, Any], bool, bool]:
    """Fly from ``obs`` to the episode's end; ``(last info, terminated, truncated)``.

    Every step goes to ``record``; every ``sample_every`` steps and the last, the estimate's
    health (and the full covariance's, for an estimator that has one) and the RSS too. The
    policy sees ``obs``, or the true state's observation when an ``oracle`` is given.
    """
    from agents.lab.estimator_studies.consistency import truth_observation
    from quadslam_env.estimation.protocol import HasFullState

    base = env.unwrapped
    full_state = base.estimator.full_state if isinstance(base.estimator, HasFullState) else None
    terminated = truncated = False
    while not (terminated or truncated):
        action, _ = policy.predict(obs if oracle is None else truth_observation(env, oracle))
        obs, _, terminated, truncated, info = env.step(action)
        record.step(info, obs)
        if record.steps % sample_every == 0 or terminated or truncated:
            record.sample(base.last_estimate, full_state)
            if bar is not None:
                bar.update(record.steps - bar.n)
    return info, terminated, truncated


def _progress_bar(total: int, desc: str) -> Any:
    """A tqdm progress bar on stderr over ``total`` steps."""
    from tqdm import tqdm

    return tqdm(total=total, unit="step", desc=desc, file=sys.stderr, mininterval=2.0)


def _machine() -> dict[str, Any]:
    """Where the soak ran: Python, NumPy, the platform, its cores and BLAS threads."""
    return {
        "python": platform.python_version(),
        "numpy": np.__version__,
        "platform": platform.platform(),
        "cores": os.cpu_count(),
        "openblas_threads": os.environ.get("OPENBLAS_NUM_THREADS"),
    }


class _SoakRecord:
    """What a soak flight accumulates: errors every step; covariance health and RSS samples."""

    def __init__(self) -> None:
        self.steps = 0
        self.pose, self.landmarks, self.full = _Extremes(), _Extremes(), _Extremes()
        self.rss_start = math.nan
        self.rss_steps: list[int] = []
        self.rss_values: list[float] = []
        self.non_finite_steps = 0
        self.first_problem = ""
        self.max_pos_err = self.max_att_err = 0.0
        self.sq_pos = self.sq_att = 0.0

    def step(self, info: dict[str, Any], obs: np.ndarray) -> None:
        """One step's estimation errors (and whether anything was non-finite)."""
        self.steps += 1
        pos_err, att_err = info["est_pos_err_m"], info["est_att_err_deg"]
        if not (math.isfinite(pos_err) and math.isfinite(att_err) and np.isfinite(obs).all()):
            self.non_finite_steps += 1
        self.max_pos_err = max(self.max_pos_err, pos_err)
        self.max_att_err = max(self.max_att_err, att_err)
        self.sq_pos += pos_err * pos_err
        self.sq_att += att_err * att_err

    def sample(self, est: Any, full_state: Any) -> None:
        """The health of the estimate's covariances and the process's RSS, now."""
        from quadslam_env.estimation.health import health_problem

        problem = health_problem(est)
        if problem is not None and not self.first_problem:
            self.first_problem = f"step {self.steps}: {problem}"
        self.pose.add(None if est.pose_cov is None else est.pose_cov[0])
        self.landmarks.add(est.mapped_landmarks()[2])
        if full_state is not None:
            self.full.add(full_state()[1])
        self.rss_steps.append(self.steps)
        self.rss_values.append(rss_mb())

    def report(self, rss_end: float) -> dict[str, Any]:
        """The health, memory and error entries of the soak report."""
        # Growth is fitted after a warm-up (the first 10% of the flight, at least one lap),
        # during which the map fills and buffers grow to their final size.
        steps_arr = np.array(self.rss_steps, dtype=float)
        rss_arr = np.array(self.rss_values)
        warm = steps_arr >= max(0.1 * self.steps, 3000.0)
        growth_kb = rss_warm = math.nan
        if warm.sum() >= 3:
            growth_kb = float(np.polyfit(steps_arr[warm], rss_arr[warm], 1)[0] * 1000.0 * 1024.0)
            rss_warm = float(rss_arr[warm][0])
        n = max(self.steps, 1)
        return {
            "non_finite_steps": self.non_finite_steps,
            "any_non_finite": self.non_finite_steps > 0,
            "health_problem": self.first_problem,
            "rss_start_mb": self.rss_start,
            "rss_after_warmup_mb": json_float(rss_warm),
            "rss_middle_mb": json_float(
                float(rss_arr[np.argmin(np.abs(steps_arr - 0.5 * self.steps))])
                if rss_arr.size
                else math.nan
            ),
            "rss_end_mb": rss_end,
            # ru_maxrss is updated lazily by the kernel: never report a peak below a sample.
            "rss_peak_mb": max(peak_rss_mb(), rss_end, *self.rss_values),
            "rss_growth_kb_per_1000_steps": json_float(growth_kb),
            "pose_cov": self.pose.as_dict(),
            "landmark_covs": self.landmarks.as_dict(),
            "full_cov": self.full.as_dict() if self.full.samples else None,
            "max_est_pos_err_m": self.max_pos_err,
            "max_est_att_err_deg": self.max_att_err,
            "rms_est_pos_err_m": math.sqrt(self.sq_pos / n),
            "rms_est_att_err_deg": math.sqrt(self.sq_att / n),
        }


def format_report(rep: dict[str, Any]) -> str:
    """A short human-readable summary of :func:`run_soak`'s report."""
    pc = rep["pose_cov"]
    lines = [
        f"soak {rep['estimator']} on {rep['scenario']} (seed {rep['seed']}"
        + (f", N = {rep['n_particles']}" if rep["n_particles"] else "")
        + f", DF-LQR on the {rep['control']})",
        f"  simulated {rep['sim_seconds']:.1f} s in {rep['wall_time_s']:.1f} s wall "
        f"({rep['steps']} steps, {rep['steps_per_s']:.0f} steps/s)",
        f"  end: {rep['termination_reason'] or 'time limit'}; non-finite steps: "
        f"{rep['non_finite_steps']}; health: {rep['health_problem'] or 'ok'}",
        f"  RSS start {rep['rss_start_mb']:.1f} MiB, middle {rep['rss_middle_mb']:.1f} MiB, "
        f"end {rep['rss_end_mb']:.1f} MiB, peak "
        f"{rep['rss_peak_mb']:.1f} MiB, growth "
        + (
            "n/a (flight too short)"
            if rep["rss_growth_kb_per_1000_steps"] is None
            else f"{rep['rss_growth_kb_per_1000_steps']:.2f} KiB/1000 steps"
        ),
        f"  pose cov: max|P-P^T| {pc['max_asymmetry']:.3g} (rel {pc['max_rel_asymmetry']:.3g}), "
        f"min eig {pc['min_eigenvalue']:.3g} (rel {pc['min_rel_eigenvalue']:.3g})",
        f"  final errors: pos {rep['final_est_pos_err_m']:.4f} m, att "
        f"{rep['final_est_att_err_deg']:.3f} deg; max pos {rep['max_est_pos_err_m']:.4f} m, "
        f"max att {rep['max_est_att_err_deg']:.3f} deg",
    ]
    if rep["full_cov"]:
        fc = rep["full_cov"]
        lines.append(
            f"  full cov: max|P-P^T| {fc['max_asymmetry']:.3g}, min eig {fc['min_eigenvalue']:.3g}"
        )
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    """``quadslam study soak``: exit 0 when the flight ended healthy, 1 otherwise."""
    parser = argparse.ArgumentParser(
        prog="quadslam study soak",
        description="Long-flight soak test of the QuadSLAM env.",
    )
    parser.add_argument("--estimator", required=True, choices=sorted(SCENARIOS))
    length = parser.add_mutually_exclusive_group()
    length.add_argument("--hours", type=float, help="simulated hours (default 1)")
    length.add_argument("--seconds", type=float, help="simulated seconds")
    parser.add_argument("--particles", type=int, help="FastSLAM particles (default 200)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--sample-every", type=int, default=100, help="steps between samples")
    parser.add_argument(
        "--control",
        choices=["estimate", "truth"],
        default="estimate",
        help="what the DF-LQR flies on (default: the estimate)",
    )
    parser.add_argument("--json", type=Path, help="write the report as JSON here")
    parser.add_argument("--no-progress", action="store_true")
    args = parser.parse_args(argv)
    seconds = args.seconds if args.seconds is not None else 3600.0 * (args.hours or 1.0)
    try:
        if args.json is not None:
            check_output_file(args.json, "--json")
        rep = run_soak(
            args.estimator,
            seconds,
            n_particles=args.particles,
            seed=args.seed,
            progress=not args.no_progress,
            sample_every=args.sample_every,
            control=args.control,
        )
    except ValueError as exc:
        print(f"quadslam soak: error: {exc}", file=sys.stderr)
        return 2
    rep["command"] = "quadslam study soak " + " ".join(argv if argv is not None else sys.argv[1:])
    print(format_report(rep))
    if args.json is not None:
        saver = Saver()
        print(f"json: {saver.write_json(args.json, rep, '--json')}")
        try:
            saver.check()
        except OutputWriteError as exc:
            print(f"quadslam soak: error: {exc}", file=sys.stderr)
            return 2
    healthy = not rep["terminated"] and not rep["any_non_finite"] and not rep["health_problem"]
    return 0 if healthy else 1
