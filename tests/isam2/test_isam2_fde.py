"""The integrity monitor of the iSAM2 smoother (estimators/isam2/fde.py).

* Its solution separations are what leaving a landmark's return out of the smoother does: the
  measurement stream of a flight is replayed into fresh smoothers, once whole and once per
  landmark without that landmark's return in the last scan, and the position covariance each
  ends with, less the whole one's, is the separation variance the monitor predicted.
* Detection alone changes nothing in the graph (the estimate is the unmonitored one, bit for
  bit); a moving landmark is excluded and re-initialised where it has moved to (the lanes of
  the vector env against the scalar env: tests/integrity/test_integrity_env.py).
"""

from __future__ import annotations

import copy
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from conftest import fly_dflqr

import quadslam_env  # noqa: F401  (registers the ids)
from agents.control.dflqr import DFLQRPolicy
from estimators.isam2.estimator import Isam2Slam
from estimators.isam2.fde import RETIRED_BASE
from quadslam_env.config.scenario import load_scenario
from quadslam_env.estimation.integrity import MonitorSettings
from quadslam_env.estimation.measurements import LidarScan

pytest.importorskip("gtsam")

SCENARIO = "paper_ekf_figure8"
ISAM2 = {"estimator": {"name": "isam2"}}
SHORT = {"episode": {"duration_s": 6.0}}
EXCLUDE = {"integrity": {"monitor": "exclude", "alert_limit_m": 0.5}}
MOVING = {"faults": {"kind": "landmark_moves", "magnitude": 0.5, "onset_s": 2.0}}
DETECT = MonitorSettings(p_fa=1e-3, exclude=False, max_exclusions=1, readmit_s=5.0)


def _record(monkeypatch: pytest.MonkeyPatch, steps: int) -> list[tuple[str, Any]]:
    """The calls (reset, predict, update) the env makes on its iSAM2 estimator in ``steps``
    DF-LQR steps from seed 3, with copies of their arguments."""
    calls: list[tuple[str, Any]] = []
    for name in ("reset", "predict", "update"):
        original = getattr(Isam2Slam, name)

        def recorder(self: Isam2Slam, *args: Any, _f: Any = original, _n: str = name, **kw: Any):
            calls.append((_n, copy.deepcopy((args, kw))))
            return _f(self, *args, **kw)

        monkeypatch.setattr(Isam2Slam, name, recorder)
    env = gym.make("QuadSLAM-v0", scenario=SCENARIO, **ISAM2, **SHORT)
    try:
        fly_dflqr(env, seed=3, steps=steps)
    finally:
        env.close()
    monkeypatch.undo()
    return calls


def _replay(
    calls: list[tuple[str, Any]], last: LidarScan, monitor: MonitorSettings | None
) -> Isam2Slam:
    """A fresh estimator fed ``calls``, their last scan replaced by ``last``."""
    est = Isam2Slam(None, **load_scenario(SCENARIO, ISAM2).estimator.params)
    est.set_monitor(monitor)
    for name, (args, kw) in calls[:-1]:
        getattr(est, name)(*args, **kw)
    est.update(last)
    return est


def test_separations_are_the_smoothers_own_subset_solutions(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The Kalman update the monitor's ``S`` and ``U`` imply, ``P = P⁻ − Uᵀ S⁻¹ U``, is the
    smoother's own position covariance after the scan; and ``D_i = P_(i) − P``, the largest
    over the scan's landmarks per axis, with ``P_(i)`` from a smoother that never saw landmark
    i's return of the scan. Both to 0.1% of the position variance: the monitor linearises at
    the prediction, the smoother's covariance is at its new estimate (and a relinearisation)."""
    calls = _record(monkeypatch, steps=250)
    last_update = max(n for n, (name, _) in enumerate(calls) if name == "update")
    calls = calls[: last_update + 1]
    scan: LidarScan = calls[-1][1][0][0]
    seen: list[Any] = []
    innovations = Isam2Slam._innovations

    def capture(self: Isam2Slam, pred: Any, *args: Any) -> Any:
        out = innovations(self, pred, *args)
        seen.append((pred, *out))
        return out

    monkeypatch.setattr(Isam2Slam, "_innovations", capture)
    whole = _replay(calls, scan, DETECT)
    monkeypatch.undo()
    k = len(scan.ids)
    assert k >= 3
    assert whole._fde_sep[3] == k  # every return tested
    P = whole.estimate().pose_cov[0, :3, :3]
    tol = 1e-3 * np.diag(P)
    pred, S, U, _ = seen[-1]
    prior = pred.dcm @ pred.cov[3:6, 3:6] @ pred.dcm.T  # the tangent's δt is in B
    kalman = prior - U.T @ np.linalg.solve(S, U)
    assert (np.abs(np.diag(kalman - P)) <= tol).all()
    assert (np.diag(prior - P) > 10 * tol).all()  # the scan's information is far above it
    worst = np.zeros(3)
    for i in range(k):
        drop = LidarScan(scan.t, np.delete(scan.ids, i), np.delete(scan.meas, i, 0), scan.sigma)
        P_i = _replay(calls, drop, None).estimate().pose_cov[0, :3, :3]
        worst = np.maximum(worst, np.diag(P_i - P))
    assert (worst > 5 * tol).all()
    assert (np.abs(whole._fde_sep[:3] - worst) <= tol).all()


def _fly(seed: int, steps: int, **overrides: Any) -> tuple[list[np.ndarray], list[dict]]:
    env = gym.make("QuadSLAM-v0", scenario=SCENARIO, **ISAM2, **SHORT, **overrides)
    try:
        policy = DFLQRPolicy.from_env(env)
        obs, _ = env.reset(seed=seed)
        out, infos = [obs], []
        for _ in range(steps):
            obs, _, _, _, info = env.step(policy.predict(obs)[0])
            out.append(obs)
            infos.append(info)
    finally:
        env.close()
    return out, infos


def test_detection_alone_changes_nothing() -> None:
    """``monitor: detect`` on the moving landmark: the observations are those without a
    monitor, bit for bit, and it alarms."""
    plain, _ = _fly(1, 400, **MOVING)
    detect = {"integrity": {**EXCLUDE["integrity"], "monitor": "detect"}}
    watched, infos = _fly(1, 400, **MOVING, **detect)
    for a, b in zip(plain, watched, strict=True):
        np.testing.assert_array_equal(a, b)
    assert sum(float(i["fde_alarm"]) for i in infos) >= 1


def test_a_moving_landmark_is_excluded_and_reinitialised_where_it_went() -> None:
    """A landmark moving at 0.5 m/s from 2 s to 4 s (1 m) is left out, its variable retired,
    and a sighting after readmission (1 s later) maps it anew at most 0.1 m from where it went
    (the old variable sits where the landmark was)."""
    moving = {"faults": {**MOVING["faults"], "duration_s": 2.0}}
    exclude = {"integrity": {**EXCLUDE["integrity"], "readmit_s": 1.0}}
    env = gym.make(
        "QuadSLAM-v0", scenario=SCENARIO, **ISAM2, **moving, **exclude,
        episode={"duration_s": 12.0},
    )  # fmt: skip
    try:
        infos, _ = fly_dflqr(env, seed=1)
        core = env.unwrapped.core
        est = core.estimator.lanes[0]
        target = int(np.nanmax([i.get("fault_landmark", np.nan) for i in infos]))
        moved = core.landmarks[0, target]
        assert est._landmark_keys.index(target) >= RETIRED_BASE  # a new variable
        mean = core.estimator.estimate().landmark_means[0, target]
    finally:
        env.close()
    assert sum(float(i["fde_excluded"]) for i in infos) >= 1
    assert infos[-1]["episode_fde_missed_detection"] == 0.0
    assert np.linalg.norm(mean - moved) < 0.1
