"""``association`` section of ``quadslam bench``: what unknown data association costs in speed.

* scalar env (``gymnasium.make``, DF-LQR in the loop): EKF-SLAM with JCBB and with NN on
  ``paper_ekf_figure8_unknown`` (40 landmarks, detection 0.9, 2 false returns per scan) with
  the azimuth FOV widened to ±90° so that about 10 landmarks are returned per scan, against the
  same scenario with known association, measured in the same run; the same three for the
  iSAM2 smoother (fixed lag; skipped without GTSAM);
* native vector env (env-steps/s vs lanes B): unknown association with NN against known
  association on the same scenario.

Each entry records the mean number of returns per scan (landmarks and clutter) it ran with.
"""

from __future__ import annotations

import importlib.util
from typing import Any

import numpy as np

from agents.lab.bench.envs import _env_rate, _note, vector_rates
from agents.lab.bench.plan import Plan, Results

SCENARIO = "paper_ekf_figure8_unknown"
WIDE = {"lidar": {"azimuth_fov_deg": 90.0}}  # about 10 landmarks in view of 40
KNOWN = {"lidar": {"association": "known", "clutter_rate": 0.0}}
METHODS: tuple[tuple[str, dict[str, Any]], ...] = (
    ("known", KNOWN),
    ("nn", {"estimator": {"params": {"association": "nn"}}}),
    ("jcbb", {"estimator": {"params": {"association": "jcbb"}}}),
)


def _merge(*parts: dict[str, Any]) -> dict[str, Any]:
    from quadslam_env.config.files import deep_merge

    out: dict[str, Any] = {}
    for part in parts:
        out = deep_merge(out, part)
    return out


def _returns_per_scan(env: Any, steps: int) -> float:
    """Mean returns per scan (landmarks and clutter) over ``steps`` zero-action steps: the
    returns of the last scan, held until the next, averaged over the steps after the first."""
    env.reset(seed=0)
    zero = np.zeros(env.action_space.shape, dtype=np.float32)
    counts = []
    for k in range(steps):
        _, _, term, trunc, info = env.step(zero)
        if k >= env.unwrapped.scenario.lidar_every:
            counts.append(float(info["est_n_visible"]))
        if term or trunc:
            env.reset()
    return float(np.mean(counts)) if counts else float("nan")


def returns_steps(plan: Plan) -> int:
    """Zero-action steps over which the returns per scan are counted: 500 (50 scans), fewer
    (down to 100) when the plan's scalar samples are shorter than that."""
    return max(100, min(500, plan.env_steps))


def bench_association(results: Results, plan: Plan) -> None:
    """Scalar env steps/s with known, NN and JCBB association; vector env NN vs known."""
    import gymnasium as gym

    import quadslam_env  # noqa: F401
    from agents.control.dflqr import DFLQRPolicy

    estimators = [("ekf_slam", "")]
    if importlib.util.find_spec("gtsam") is not None:
        estimators.append(("isam2", "isam2/"))
    for name, prefix in estimators:
        for label, method in METHODS:
            kwargs = _merge(WIDE, method, {"estimator": {"name": name}})
            env = gym.make("QuadSLAM-v0", scenario=SCENARIO, **kwargs)
            per_scan = _returns_per_scan(env, returns_steps(plan))
            rates = _env_rate(env, DFLQRPolicy.from_env(env), plan.env_steps, plan.repeats)
            results.add(
                "association",
                f"steps_per_s/scalar/{prefix}{label}",
                rates,
                "steps/s",
                note="scalar env, DF-LQR; azimuth FOV ±90° for about 10 landmark returns per scan",
                scenario=SCENARIO,
                estimator=name,
                association=label,
                returns_per_scan=round(per_scan, 2),
                landmarks=40,
            )
            env.close()
    for label, method in METHODS[:2]:
        for b in plan.vec_batches:
            rates, dt, _ = vector_rates("QuadSLAM-v0", b, plan, scenario=SCENARIO, **method)
            results.add(
                "association",
                f"env_steps_per_s/vector/{label}",
                rates,
                "env-steps/s",
                note=_note(plan, dt),
                scenario=SCENARIO,
                association=label,
                num_envs=b,
            )
