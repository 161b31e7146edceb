"""Paper-style figures (seed 001 Fig. 7–11) from a recorded
:class:`~agents.evaluation.episodes.Trace`."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from agents.evaluation.episodes import Trace
from agents.io.outputs import Saver
from quadslam_env.extras import require
from quadslam_env.models.frames import dcm_from_euler_batch, wrap_angle
from quadslam_env.types import EUL, POS, VEL


def write_figures(
    trace: Trace, out_dir: Path, title: str, saver: Saver | None = None
) -> list[Path]:
    """Write the 3D path, state-estimate and landmark-error figures as PNG files.

    Args:
        trace: The recorded episode.
        out_dir: Folder for the PNGs (created when missing).
        title: Figure title prefix.
        saver: Writes the files atomically and records failures (a file that cannot be
            written goes to a fallback place); without one, a failure raises after every
            figure was written somewhere.

    Returns:
        Where each file was written.

    Raises:
        agents.io.outputs.OutputWriteError: Without ``saver``, when a file could not be written
            in ``out_dir``.
    """
    matplotlib = require("matplotlib", "plots", "figures (--plots)")
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    own = saver is None
    saver = saver or Saver()
    t = np.array(trace.t)
    true = np.array(trace.true_state)
    est_euler = np.array(trace.est_euler)
    std = np.array(trace.pose_std)
    paths = [_save(saver, _path_figure(plt, trace, title), out_dir / "path_3d.png")]
    panels = (
        ("position", ["x", "y", "z"], POS, np.array(trace.est_pos), "m", 1.0, False),
        ("velocity_body", ["u", "v", "w"], VEL, np.array(trace.est_vel_body), "m/s", 1.0, False),
        ("attitude", ["φ", "θ", "ψ"], EUL, est_euler, "deg", 180.0 / np.pi, True),
    )
    for name, labels, part, est, unit, scale, wrap in panels:
        truth, sigma = true[:, part], std[:, part]  # pose_std (ρ, v_B, Λ): the state's layout
        fig = _state_panel(plt, t, labels, truth, est, sigma, unit, scale, wrap)
        fig.suptitle(f"{title}: {name}")
        paths.append(_save(saver, fig, out_dir / f"{name}.png"))
    true_vel_n = np.einsum("nij,nj->ni", dcm_from_euler_batch(true[:, EUL]), true[:, VEL])
    est_vel_n = np.einsum(
        "nij,nj->ni", dcm_from_euler_batch(est_euler), np.array(trace.est_vel_body)
    )
    fig, ax = plt.subplots(figsize=(8, 3.5))
    ax.plot(t, np.linalg.norm(true_vel_n - est_vel_n, axis=1), "r-", lw=0.8)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("inertial velocity error [m/s]")
    paths.append(_save(saver, fig, out_dir / "velocity_error.png"))
    if trace.est_landmarks is not None and trace.est_landmarks.size and trace.landmarks is not None:
        fig = _landmark_figure(plt, trace)
        fig.suptitle(f"{title}: landmark errors")
        paths.append(_save(saver, fig, out_dir / "landmarks.png"))
    if own:
        saver.check()
    return paths


def _path_figure(plt: Any, trace: Trace, title: str) -> Any:
    """The desired, true and estimated paths with the true and estimated maps, in 3D."""
    ref, true = np.array(trace.ref_pos), np.array(trace.true_state)
    est_pos = np.array(trace.est_pos)
    fig = plt.figure(figsize=(7, 6))
    ax = fig.add_subplot(projection="3d")
    ax.plot(ref[:, 0], ref[:, 1], -ref[:, 2], "k--", lw=0.8, label="desired")
    ax.plot(true[:, 0], true[:, 1], -true[:, 2], "b-", lw=1.2, label="true")
    ax.plot(est_pos[:, 0], est_pos[:, 1], -est_pos[:, 2], "r-", lw=0.8, label="estimated")
    if trace.landmarks is not None:
        lm = trace.landmarks
        ax.scatter(lm[:, 0], lm[:, 1], -lm[:, 2], c="g", marker="^", s=15, label="landmarks")
    if trace.est_landmarks is not None and trace.est_landmarks.size:
        el = trace.est_landmarks
        ax.scatter(el[:, 0], el[:, 1], -el[:, 2], c="m", marker="x", s=15, label="estimated map")
    ax.set_xlabel("north [m]")
    ax.set_ylabel("east [m]")
    ax.set_zlabel("altitude [m]")
    ax.set_title(title)
    ax.legend(fontsize=7)
    return fig


def _state_panel(
    plt: Any,
    t: np.ndarray,
    labels: list[str],
    truth: np.ndarray,
    est: np.ndarray,
    sigma: np.ndarray,
    unit: str,
    scale: float,
    wrap: bool,
) -> Any:
    """Three components, true and estimated (left), error and ±3σ (right); angles wrapped."""
    fig, axes = plt.subplots(3, 2, figsize=(11, 7), sharex=True)
    err = np.asarray(wrap_angle(est - truth) if wrap else est - truth)
    for i, label in enumerate(labels):
        axes[i, 0].plot(t, scale * truth[:, i], "b-", lw=1, label="true")
        axes[i, 0].plot(t, scale * est[:, i], "r--", lw=1, label="estimated")
        axes[i, 0].set_ylabel(f"{label} [{unit}]")
        axes[i, 1].plot(t, scale * err[:, i], "r-", lw=0.8, label="error")
        axes[i, 1].plot(t, 3 * scale * sigma[:, i], "k:", lw=0.8, label="±3σ")
        axes[i, 1].plot(t, -3 * scale * sigma[:, i], "k:", lw=0.8)
    axes[0, 0].legend(fontsize=7)
    axes[0, 1].legend(fontsize=7)
    axes[2, 0].set_xlabel("time [s]")
    axes[2, 1].set_xlabel("time [s]")
    return fig


def _landmark_figure(plt: Any, trace: Trace) -> Any:
    """Each mapped landmark's final error with its ±3σ bar, per axis."""
    ids, sig = trace.est_landmark_ids, trace.est_landmark_std
    assert ids is not None and sig is not None  # recorded together with est_landmarks
    assert trace.est_landmarks is not None and trace.landmarks is not None
    err = trace.est_landmarks - trace.landmarks[ids]
    fig, axes = plt.subplots(3, 1, figsize=(9, 7), sharex=True)
    for i, label in enumerate(["x", "y", "z"]):
        axes[i].errorbar(ids, err[:, i], yerr=3 * sig[:, i], fmt="o", ms=3, capsize=2)
        axes[i].axhline(0.0, color="k", lw=0.5)
        axes[i].set_ylabel(f"{label} error [m]")
    axes[2].set_xlabel("landmark id (bars: ±3σ)")
    return fig


def _save(saver: Saver, fig: object, path: Path) -> Path:
    import matplotlib.pyplot as plt

    fig.tight_layout()  # type: ignore[attr-defined]
    where = saver.save_figure(fig, path, "--plots", dpi=110)
    plt.close(fig)  # type: ignore[arg-type]
    return where
