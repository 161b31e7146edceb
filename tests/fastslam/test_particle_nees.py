"""Tests of the particle-filter consistency analysis
(agents/lab/estimator_studies/particle_nees.py)."""

from __future__ import annotations

import math

import numpy as np

from agents.lab.estimator_studies.particle_nees import block_nees, summarise, summarise_episode


def test_block_nees_uses_each_blocks_marginal_covariance() -> None:
    rng = np.random.default_rng(0)
    A = rng.normal(size=(9, 9))
    P = A @ A.T + np.eye(9)
    e = rng.normal(size=9)
    out = block_nees(e, P)
    assert math.isclose(out["pose"], float(e @ np.linalg.inv(P) @ e), rel_tol=1e-10)
    for name, s in (("pos", slice(0, 3)), ("vel", slice(3, 6)), ("att", slice(6, 9))):
        assert math.isclose(out[name], float(e[s] @ np.linalg.inv(P[s, s]) @ e[s]), rel_tol=1e-10)
    # A Gaussian error of covariance P: each block's NEES averages its 3 DOF.
    L = np.linalg.cholesky(P)
    draws = [block_nees(L @ rng.normal(size=9), P) for _ in range(4000)]
    assert abs(np.mean([d["pos"] for d in draws]) - 3.0) < 0.2
    assert abs(np.mean([d["pose"] for d in draws]) - 9.0) < 0.4


def _record(pos_err: np.ndarray, map_err: np.ndarray, lineages: list[int]) -> dict:
    k = pos_err.shape[0]
    return {
        "t": list(np.arange(k) * 0.01), "nees": {"pose": [9.0] * k, "pos": [3.0] * k,
        "vel": [3.0] * k, "att": [3.0] * k}, "pos_err": list(pos_err), "map_err": list(map_err),
        "pos_sd": [0.1] * k, "yaw_err": [0.0] * k, "yaw_sd": [0.01] * k, "lineages": lineages,
        "end": "",
    }  # fmt: skip


def test_gauge_share_is_one_for_a_common_shift_and_zero_for_none() -> None:
    err = np.random.default_rng(1).normal(size=(50, 3))
    shift = summarise_episode(_record(err, err.copy(), [5] * 25 + [1] * 25), 0.01)
    assert math.isclose(shift["gauge_share"], 1.0)
    assert math.isclose(shift["t_one_lineage_s"], 0.26) and shift["lineages_end"] == 1
    alone = summarise_episode(_record(err, np.zeros((50, 3)), [5] * 50), 0.01)
    assert math.isclose(alone["gauge_share"], 0.0, abs_tol=1e-12)
    assert math.isnan(alone["t_one_lineage_s"])
    s = summarise([shift, alone])
    assert s["episodes_ended_early"] == 0 and s["anees_pose"]["median"] == 9.0
