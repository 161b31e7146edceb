"""Sections of ``quadslam bench`` measured in fresh subprocesses: ``memory`` and ``compile``.

Each sample runs :func:`probe` in a new interpreter (``subprocess.run([sys.executable, "-c",
...])``) so that one measurement's memory or compiled kernels do not leak into the next:

* ``memory``: peak RSS (:func:`peak_rss_mb`) of a process that makes a B-lane EKF unknown-map
  vector env and steps it with DF-LQR;
* ``compile``: wall time of the first ``gymnasium.make_vec("QuadSLAM-EKF-v0", num_envs=4)`` +
  reset + 20 DF-LQR steps with an empty numba cache (``NUMBA_CACHE_DIR`` a new directory), then
  again in a second process with that cache warm. The probe asks for the EKF warm-up process
  (``QUADSLAM_EKF_WARMUP=1``, :mod:`estimators.ekf.warmup`) as the ``quadslam`` command does,
  so the empty-cache figure is the first run of a command after an install: the LiDAR update
  compiles in a second process while the probe compiles the rest. Every plan measures the
  same, whatever the caller's environment says; it compiles every kernel the default scenario
  flies with (about 100, all needed by its first steps), so it cannot be shortened.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from typing import Any

from agents.io.memory import peak_rss_mb
from agents.lab.bench.plan import Plan, Results

MEMORY_ENV_ID = "QuadSLAM-EKF-v0"  # default scenario paper_ekf_figure8: unknown map
COMPILE_ENV_ID = "QuadSLAM-EKF-v0"
COMPILE_LANES = 4
COMPILE_STEPS = 20
COMPILE_TARGETS_S = {"empty_cache": 20.0, "warm_cache": 2.0}
COMPILE_WARMUP = {"QUADSLAM_EKF_WARMUP": "1"}
"""The compile probe's EKF warm-up setting: on, as in the ``quadslam`` command."""


def fly_vector(env_id: str, num_envs: int, steps: int, kwargs: dict[str, Any]) -> None:
    """Make a B-lane vector env, reset it and fly ``steps`` batched DF-LQR steps."""
    from agents.control.dflqr import DFLQRPolicy
    from agents.lab.bench.envs import make_vector

    vec = make_vector(env_id, num_envs, **kwargs)
    policy = DFLQRPolicy.from_env(vec)
    obs, _ = vec.reset(seed=0)
    for _ in range(steps):
        obs = vec.step(policy.predict(obs)[0])[0]
    vec.close()


def probe(env_id: str, num_envs: str, steps: str, kwargs_json: str = "{}") -> None:
    """Subprocess body: make, reset and step a vector env; print its time and peak RSS.

    Prints one JSON line ``{"seconds": ..., "maxrss_mb": ...}``: seconds from before importing
    the package (numba loads or compiles its kernels then) to after the last step, and
    :func:`peak_rss_mb`.

    Args:
        env_id: Registered id.
        num_envs: Lanes B (a string: it comes from the command line).
        steps: DF-LQR steps after the reset.
        kwargs_json: ``gymnasium.make_vec`` keyword arguments as JSON.
    """
    tic = time.perf_counter()
    fly_vector(env_id, int(num_envs), int(steps), json.loads(kwargs_json))
    seconds = time.perf_counter() - tic
    print(json.dumps({"seconds": seconds, "maxrss_mb": peak_rss_mb()}))


def run_probe(
    env_id: str,
    num_envs: int,
    steps: int,
    kwargs: dict[str, Any] | None = None,
    env: dict[str, str] | None = None,
) -> dict[str, float]:
    """Run :func:`probe` in a fresh interpreter.

    Args:
        env_id: Registered id.
        num_envs: Lanes B.
        steps: Steps after the reset.
        kwargs: ``gymnasium.make_vec`` keyword arguments (plain data).
        env: Extra environment variables of the subprocess (single-threaded BLAS by default).

    Returns:
        ``{"seconds", "maxrss_mb"}``.

    Raises:
        RuntimeError: The subprocess failed (its stderr is included).
    """
    code = "import sys; from agents.lab.bench.process import probe; probe(*sys.argv[1:])"
    args = [env_id, str(num_envs), str(steps), json.dumps(kwargs or {})]
    full_env = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    full_env.update(os.environ)
    full_env.update(env or {})
    proc = subprocess.run(
        [sys.executable, "-c", code, *args], capture_output=True, text=True, env=full_env
    )
    if proc.returncode != 0:
        raise RuntimeError(f"bench probe {args} failed:\n{proc.stderr[-2000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def bench_memory(results: Results, plan: Plan) -> None:
    """Peak RSS of a fresh process stepping a B-lane EKF unknown-map vector env."""
    fly_vector(MEMORY_ENV_ID, 2, 2, {})  # compiles (and caches) the kernels of the probes
    for b in plan.memory_batches:
        samples = [
            run_probe(MEMORY_ENV_ID, b, plan.memory_steps)["maxrss_mb"]
            for _ in range(plan.process_repeats)
        ]
        results.add(
            "memory",
            "peak_rss/ekf_unknown_map",
            samples,
            "MB",
            note=(
                f"peak RSS (VmHWM, MiB) of a fresh process: imports, make_vec, reset and "
                f"{plan.memory_steps} DF-LQR steps; numba cache warm"
            ),
            env_id=MEMORY_ENV_ID,
            num_envs=b,
            steps=plan.memory_steps,
        )


def first_use_seconds(cache_dir: str) -> float:
    """Seconds of the first make_vec + reset + steps in a fresh process using ``cache_dir``."""
    env = {"NUMBA_CACHE_DIR": cache_dir, **COMPILE_WARMUP}
    return run_probe(COMPILE_ENV_ID, COMPILE_LANES, COMPILE_STEPS, env=env)["seconds"]


def bench_compile(results: Results, plan: Plan) -> None:
    """First-use time with an empty numba cache, then with that cache warm."""
    samples: dict[str, list[float]] = {key: [] for key in COMPILE_TARGETS_S}
    for _ in range(plan.process_repeats):
        with tempfile.TemporaryDirectory(prefix="quadslam-numba-") as cache_dir:
            for key in COMPILE_TARGETS_S:  # empty first, then warm (the same directory)
                samples[key].append(first_use_seconds(cache_dir))
    for key, target in COMPILE_TARGETS_S.items():
        results.add(
            "compile",
            f"first_use/{key}",
            samples[key],
            "s",
            note=(
                "fresh process, NUMBA_CACHE_DIR set to a new directory (warm: the same one "
                "again), EKF warm-up process on (QUADSLAM_EKF_WARMUP=1, as the quadslam "
                "command); from before importing the package to after the last step, "
                "interpreter start-up excluded"
            ),
            env_id=COMPILE_ENV_ID,
            lanes=COMPILE_LANES,
            steps=COMPILE_STEPS,
            target_s=target,
        )
