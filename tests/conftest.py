"""Fixtures and helpers shared by the test modules (helpers imported as ``from conftest import
...``): flying DF-LQR, one vehicle's data into lane 0 of a batch estimator, finite
differences, and the hostile file systems of the CLI's tests (read-only folders, full disks,
failing renames)."""

from __future__ import annotations

import errno
import os
import stat
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

from agents.control.dflqr import DFLQRPolicy
from quadslam_env.estimation.measurements import Control, ImuSample, LidarScan


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


AHEAD = [[6, -2, -1], [8, 1, 0.5], [10, 3, -2], [12, -4, 1], [7, 0, 2], [9, -1, -3]]
"""Six well-separated landmarks ahead of the hovering vehicle (NED, m), all in the FOV."""


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


# ------------------------------------------ mistakes and hostile file systems (the CLI tests)
RUN = ["run", "--duration", "0.3"]
"""A one-scan run of the CLI."""


def cli(capsys: pytest.CaptureFixture[str], argv: list[str]) -> tuple[int, str, str]:
    """Run the CLI; return (status, stdout, last stderr line)."""
    from agents.lab.cli.main import main

    code = main(argv)
    out, err = capsys.readouterr()
    lines = [line for line in err.replace("\r", "\n").splitlines() if line.strip()]
    return code, out, lines[-1] if lines else ""


@pytest.fixture
def no_work(monkeypatch: pytest.MonkeyPatch) -> None:
    """Any flight, benchmark, study or training fails the test: errors must come first."""

    def forbidden(*args: Any, **kwargs: Any) -> Any:
        raise AssertionError("the work started before the output paths were checked")

    import agents.evaluation.episodes
    import agents.lab.bench.runner
    import agents.lab.control_studies.cost
    import agents.rl.policies
    import agents.rl.training

    monkeypatch.setattr(agents.evaluation.episodes, "run_episodes", forbidden)
    monkeypatch.setattr(agents.rl.policies, "load_policy", forbidden)
    monkeypatch.setattr(agents.lab.bench.runner, "run_bench", forbidden)
    monkeypatch.setattr(agents.lab.control_studies.cost, "run_study", forbidden)
    monkeypatch.setattr(agents.rl.training, "train", forbidden)


def _inside(path: Any, folder: Path) -> bool:
    return Path(os.path.abspath(path)).is_relative_to(folder.resolve())


@pytest.fixture
def read_only(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> Path:
    """A folder that refuses new files, even for root (the probe fails like EACCES)."""
    folder = tmp_path / "ro"
    folder.mkdir()
    real: Any = tempfile.mkstemp

    def mkstemp(*args: Any, dir: Any = None, **kwargs: Any) -> Any:
        if dir is not None and _inside(dir, folder):
            raise PermissionError(errno.EACCES, "Permission denied")
        return real(*args, dir=dir, **kwargs)

    import agents.io.outputs as outputs

    monkeypatch.setattr(outputs.tempfile, "mkstemp", mkstemp)
    return folder


@pytest.fixture
def chmod_read_only(tmp_path: Path) -> Iterator[Path]:
    folder = tmp_path / "chmod_ro"
    folder.mkdir()
    folder.chmod(stat.S_IRUSR | stat.S_IXUSR)
    if os.access(folder, os.W_OK):
        folder.chmod(0o700)
        pytest.skip("chmod does not make folders read-only here (running as root)")
    yield folder
    folder.chmod(0o700)


def full_disk(monkeypatch: pytest.MonkeyPatch, folder: Path) -> None:
    """Writing any file inside ``folder`` fails with ENOSPC (a full file system): files can
    still be created (the early check passes), but no data can be written to them."""
    import builtins
    import io

    real = builtins.open

    def guarded(file: Any, mode: str = "r", *args: Any, **kwargs: Any) -> Any:
        writing = any(c in mode for c in "wax+")
        if writing and isinstance(file, str | os.PathLike) and _inside(file, folder):
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(file, mode, *args, **kwargs)

    monkeypatch.setattr(builtins, "open", guarded)
    monkeypatch.setattr(io, "open", guarded)  # pathlib's write_text opens through io


def failing_rename(monkeypatch: pytest.MonkeyPatch, folder: Path) -> None:
    """``os.replace`` into ``folder`` fails (the last step of every atomic write)."""
    real = os.replace

    def replace(src: Any, dst: Any) -> None:
        if _inside(dst, folder):
            raise OSError(errno.EIO, "Input/output error")
        real(src, dst)

    import agents.io.outputs as outputs

    monkeypatch.setattr(outputs.os, "replace", replace)


def no_temp_files(folder: Path) -> bool:
    return not [p for p in folder.rglob(".*") if ".tmp-" in p.name or "probe" in p.name]
