"""Fixtures and helpers shared by the test modules (helpers imported as ``from conftest import
...``)."""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

from agents.control.dflqr import DFLQRPolicy
from quadslam_env.measurements import Control, ImuSample, LidarScan


def fly_dflqr(
    env: gym.Env, seed: int, steps: int | None = None
) -> tuple[list[dict[str, Any]], bool]:
    """DF-LQR on the env's observation from ``reset(seed=seed)``, until the episode ends or
    after ``steps`` steps; every observation and reward must be finite.

    Returns:
        The per-step ``info`` dicts and whether the episode terminated (not truncated).
    """
    policy = DFLQRPolicy.from_env(env)
    obs, _ = env.reset(seed=seed)
    infos: list[dict[str, Any]] = []
    terminated = truncated = False
    while not (terminated or truncated) and (steps is None or len(infos) < steps):
        obs, reward, terminated, truncated, info = env.step(policy.predict(obs)[0])
        assert np.isfinite(obs).all() and np.isfinite(reward)
        infos.append(info)
    return infos, bool(terminated)


@pytest.fixture
def temp_root(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> Path:
    """The temporary folder (a failed write's last fallback) inside the test's folder."""
    root = tmp_path / "tmp"
    root.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(root))
    return root


# ------------------------------------------------- one vehicle's data into lane 0 of a batch
def lane_reset(
    est: Any,
    mean0: np.ndarray,
    cov0: np.ndarray,
    rng: np.random.Generator,
    known: tuple[np.ndarray, np.ndarray] | None = None,
) -> None:
    """``reset_lanes`` of lane 0 of the batch estimator ``est`` from a (12,) mean and
    (12, 12) covariance, with ``known = (ids (L,), positions (L, 3))`` or ``None``."""
    known_maps = None if known is None else [known]
    est.reset_lanes(np.zeros(1, dtype=np.int64), mean0[None], cov0[None], [rng], known_maps)


def lane_predict(est: Any, imu: ImuSample, control: Control, dt: float) -> None:
    """``predict`` of lane 0 of the batch estimator ``est`` with one IMU sample."""
    est.predict(
        np.array([imu.t]),
        np.asarray(imu.accel, dtype=float)[None],
        np.asarray(imu.gyro, dtype=float)[None],
        imu.accel_sigma,
        imu.gyro_sigma,
        np.array([control.thrust]),
        np.asarray(control.torque, dtype=float)[None],
        dt,
        np.ones(1, dtype=bool),
    )


def lane_update(est: Any, scan: LidarScan) -> np.ndarray | None:
    """``update`` of lane 0 of the batch estimator ``est`` with one scan: by landmark id
    (``scan.ids`` (k,) distinct), or ``update_unlabeled`` when ``scan.ids`` is ``None``.

    Returns:
        For an unlabeled scan the (k,) label of each return (-1: none), else ``None``.
    """
    lane, t = np.zeros(1, dtype=np.int64), np.array([scan.t])
    meas = np.asarray(scan.meas, dtype=float).reshape(-1, 3)
    if scan.ids is None:
        k = meas.shape[0]
        est.update_unlabeled(t, lane, np.array([k]), meas[None], scan.sigma)
        return np.asarray(est.last_association[0, :k]).copy()
    ids = np.asarray(scan.ids, dtype=np.int64)
    width = max(int(ids.max()) + 1 if ids.size else 0, getattr(est, "landmark_capacity", 0))
    visible = np.zeros((1, width), dtype=bool)
    visible[0, ids] = True
    by_id = np.zeros((1, width, 3))
    by_id[0, ids] = meas
    est.update(t, lane, visible, by_id, scan.sigma)
    return None


def fd_jacobian(f: Any, x: np.ndarray, eps: float = 1e-6) -> np.ndarray:
    """Central-difference Jacobian ``∂f/∂x`` (m, n) of ``f`` (n,) → (m,) at ``x``."""
    cols = [(f(x + eps * e) - f(x - eps * e)) / (2 * eps) for e in np.eye(x.size)]
    return np.column_stack(cols)


def random_spd(rng: np.random.Generator, n: int, lo: float = 1e-3, hi: float = 5e-2) -> np.ndarray:
    """A random symmetric positive definite (n, n) matrix, eigenvalues uniform in [lo, hi]."""
    q, _ = np.linalg.qr(rng.normal(size=(n, n)))
    a = (q * rng.uniform(lo, hi, n)) @ q.T
    return 0.5 * (a + a.T)


def assert_zero_residual_flies_base(make: Any, base: str, steps: int, **options: Any) -> None:
    """A residual wrapper on the ``base`` controller (with its ``options``) fed a zero residual
    flies exactly as the bare controller: the vector env ``make()`` twice, ``steps`` steps of
    two lanes, observations equal bit for bit."""
    from agents.control.named import build_controller
    from agents.rl.wrappers import ResidualDFLQRVectorWrapper, parse_wrapper_spec

    spec = parse_wrapper_spec({"name": "residual_dflqr", "base": base, **options})
    assert spec is not None
    wrapped, plain = ResidualDFLQRVectorWrapper(make(), **spec[1]), make()
    try:
        policy = build_controller(base, plain, **options)
        o_w, _ = wrapped.reset(seed=1)
        o_p, _ = plain.reset(seed=1)
        state = None
        for _ in range(steps):
            o_w, *_ = wrapped.step(np.zeros((2, 4), np.float32))
            act, state = policy.predict(o_p, state=state)
            o_p, *_ = plain.step(act)
            np.testing.assert_array_equal(o_w, o_p)
    finally:
        wrapped.close()
        plain.close()


def assert_lanes_equal_scalar_env(
    env_id: str,
    env_kwargs: dict[str, Any],
    base: str,
    seeds: list[int],
    steps: int,
    **options: Any,
) -> tuple[Any, Any]:
    """The ``base`` controller (with its ``options``) flown ``steps`` steps on the lanes of one
    vector env (lane i seeded ``seeds[0] + i``) and on one scalar env per seed: every lane's
    observations equal its scalar env's bit for bit.

    Returns:
        The vector env's controller and its state after the last step (for further checks).
    """
    from agents.control.named import build_controller

    vec = gym.make_vec(env_id, num_envs=len(seeds), vectorization_mode="vector_entry_point",
                       **env_kwargs)  # fmt: skip
    try:
        policy = build_controller(base, vec, **options)
        obs, _ = vec.reset(seed=seeds[0])
        state, start, lanes = None, np.ones(len(seeds), dtype=bool), [obs]
        for _ in range(steps):
            act, state = policy.predict(obs, state=state, episode_start=start)
            obs, _, term, trunc, _ = vec.step(act)
            start = term | trunc
            lanes.append(obs)
    finally:
        vec.close()
    for i, seed in enumerate(seeds):
        env = gym.make(env_id, **env_kwargs)
        try:
            scalar = build_controller(base, env, **options)
            o, _ = env.reset(seed=seed)
            s = None
            for k in range(steps):
                np.testing.assert_array_equal(o, lanes[k][i])
                a, s = scalar.predict(o, state=s)
                o, *_ = env.step(a)
            np.testing.assert_array_equal(o, lanes[steps][i])
        finally:
            env.close()
    return policy, state
