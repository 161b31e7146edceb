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

FIGURES = (
    "path_3d.png", "position.png", "velocity_body.png", "attitude.png", "velocity_error.png",
    "landmarks.png",
)  # fmt: skip
"""The figures of an episode, in the order they are written (``landmarks.png`` only when the
estimator mapped a landmark)."""

PATH_MARGIN = 0.1
"""Margin of the 3D path figure's axes on every side: this fraction of the path's largest
extent (at least :data:`MIN_MARGIN_M`)."""
MIN_MARGIN_M = 0.5


def write_figures(
    trace: Trace, out_dir: Path, title: str, saver: Saver | None = None
) -> list[Path]:
    """Write the figures of :func:`figures` as PNG files.

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
    own = saver is None
    saver = saver or Saver()
    paths = [_save(saver, fig, out_dir / name) for name, fig in figures(trace, title).items()]
    if own:
        saver.check()
    return paths


def figures(trace: Trace, title: str) -> dict[str, Any]:
    """The matplotlib figures of an episode, by file name (:data:`FIGURES`): the 3D path; the
    position (with the reference), body velocity and attitude, true and estimated, and their
    errors against ±3σ; the inertial velocity error against ±3σ; the mapped landmarks' errors.

    Args:
        trace: The recorded episode.
        title: Figure title prefix.

    Raises:
        quadslam_env.extras.MissingExtraError: matplotlib is not installed.
    """
    matplotlib = require("matplotlib", "plots", "figures (--plots)")
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = np.array(trace.t)
    true = np.array(trace.true_state)
    est_euler = np.array(trace.est_euler)
    std = trace.pose_std
    out = {"path_3d.png": _path_figure(plt, trace, title)}
    panels = (
        ("position", ["x", "y", "z"], POS, np.array(trace.est_pos), "m", 1.0, False),
        ("velocity_body", ["u", "v", "w"], VEL, np.array(trace.est_vel_body), "m/s", 1.0, False),
        ("attitude", ["φ", "θ", "ψ"], EUL, est_euler, "deg", 180.0 / np.pi, True),
    )
    for name, labels, part, est, unit, scale, wrap in panels:
        truth, sigma = true[:, part], std[:, part]  # pose_std (ρ, v_B, Λ): the state's layout
        ref = np.array(trace.ref_pos) if name == "position" else None
        fig = _state_panel(plt, t, labels, truth, est, sigma, unit, scale, wrap, ref)
        fig.suptitle(f"{title}: {name}")
        out[f"{name}.png"] = fig
    fig = _velocity_error_figure(plt, trace)
    fig.suptitle(f"{title}: inertial velocity error")
    out["velocity_error.png"] = fig
    if trace.est_landmarks is not None and trace.est_landmarks.size and trace.landmarks is not None:
        fig = _landmark_figure(plt, trace)
        fig.suptitle(f"{title}: landmark errors")
        out["landmarks.png"] = fig
    return out


def path_limits(trace: Trace) -> np.ndarray:
    """(3, 2) axis limits (north, east, altitude) of the 3D path figure: the desired, true and
    estimated paths with :data:`PATH_MARGIN` on every side."""
    points = np.concatenate([np.array(trace.ref_pos), np.array(trace.true_state)[:, POS],
                             np.array(trace.est_pos)])  # fmt: skip
    points = points * np.array([1.0, 1.0, -1.0])  # altitude = −z
    lo, hi = np.nanmin(points, axis=0), np.nanmax(points, axis=0)
    margin = max(PATH_MARGIN * float(np.max(hi - lo)), MIN_MARGIN_M)
    return np.stack([lo - margin, hi + margin], axis=1)


def _path_figure(plt: Any, trace: Trace, title: str) -> Any:
    """The desired, true and estimated paths, with the true and estimated landmarks that fall
    inside the axes (:func:`path_limits`), in 3D."""
    ref, true = np.array(trace.ref_pos), np.array(trace.true_state)
    est_pos = np.array(trace.est_pos)
    limits = path_limits(trace)
    fig = plt.figure(figsize=(7, 6))
    ax = fig.add_subplot(projection="3d")
    ax.plot(ref[:, 0], ref[:, 1], -ref[:, 2], "k--", lw=0.8, label="desired")
    ax.plot(true[:, 0], true[:, 1], -true[:, 2], "b-", lw=1.2, label="true")
    ax.plot(est_pos[:, 0], est_pos[:, 1], -est_pos[:, 2], "r-", lw=0.8, label="estimated")
    for points, style in (
        (trace.landmarks, {"c": "g", "marker": "^", "label": "landmarks"}),
        (trace.est_landmarks, {"c": "m", "marker": "x", "label": "estimated map"}),
    ):
        if points is None or not len(points):
            continue
        shown = points[_inside(points, limits)]
        style["label"] += f" ({len(shown)} of {len(points)} in view)"
        ax.scatter(shown[:, 0], shown[:, 1], -shown[:, 2], s=15, **style)
    ax.set_xlim(*limits[0])
    ax.set_ylim(*limits[1])
    ax.set_zlim(*limits[2])
    ax.set_xlabel("north [m]")
    ax.set_ylabel("east [m]")
    ax.set_zlabel("altitude [m]")
    ax.set_title(title)
    ax.legend(fontsize=7)
    return fig


def _inside(points: np.ndarray, limits: np.ndarray) -> np.ndarray:
    """(n,) which NED ``points`` fall inside the (north, east, altitude) ``limits``."""
    shown = points * np.array([1.0, 1.0, -1.0])
    return np.all((shown >= limits[:, 0]) & (shown <= limits[:, 1]), axis=1)


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
    ref: np.ndarray | None = None,
) -> Any:
    """Three components, true and estimated (left, with the reference if given), error and
    ±3σ (right); angles wrapped."""
    fig, axes = plt.subplots(3, 2, figsize=(11, 7), sharex=True)
    err = np.asarray(wrap_angle(est - truth) if wrap else est - truth)
    for i, label in enumerate(labels):
        if ref is not None:
            axes[i, 0].plot(t, scale * ref[:, i], "k:", lw=0.8, label="reference")
        axes[i, 0].plot(t, scale * truth[:, i], "b-", lw=1, label="true")
        axes[i, 0].plot(t, scale * est[:, i], "r--", lw=1, label="estimated")
        axes[i, 0].set_ylabel(f"{label} [{unit}]")
        _error_band(axes[i, 1], t, scale * err[:, i], 3 * scale * sigma[:, i])
        axes[i, 1].set_ylabel(f"{label} error [{unit}]")
    axes[0, 0].legend(fontsize=7)
    axes[0, 1].legend(fontsize=7)
    axes[2, 0].set_xlabel("time [s]")
    axes[2, 1].set_xlabel("time [s]")
    return fig


def _error_band(ax: Any, t: np.ndarray, err: np.ndarray, bound: np.ndarray) -> None:
    """The error and its ±3σ bound (``bound`` = 3σ) on one axes."""
    ax.plot(t, err, "r-", lw=0.8, label="error")
    ax.plot(t, bound, "k:", lw=0.8, label="±3σ")
    ax.plot(t, -bound, "k:", lw=0.8)


def inertial_velocity_error(trace: Trace) -> tuple[np.ndarray, np.ndarray]:
    """The inertial (NED) velocity error of the estimate and its 1σ at each recorded step.

    The estimate's inertial velocity is ``C_NB(Λ̂) v̂_B``; its covariance is that of
    (v_B, Λ) carried through the linearisation ``J = [C_NB, ∂(C_NB v_B)/∂Λ]`` (the Euler
    derivative by central differences).

    Returns:
        ``(error (N, 3), sigma (N, 3))`` in m/s; sigma NaN where the estimate has no
        covariance.
    """
    true = np.array(trace.true_state)
    euler, vel = np.array(trace.est_euler), np.array(trace.est_vel_body)
    true_n = np.einsum("nij,nj->ni", dcm_from_euler_batch(true[:, EUL]), true[:, VEL])
    est_n = np.einsum("nij,nj->ni", dcm_from_euler_batch(euler), vel)
    step = 1e-6
    d_euler = np.empty((len(euler), 3, 3))
    for k in range(3):
        dk = np.zeros(3)
        dk[k] = step
        up = np.einsum("nij,nj->ni", dcm_from_euler_batch(euler + dk), vel)
        down = np.einsum("nij,nj->ni", dcm_from_euler_batch(euler - dk), vel)
        d_euler[:, :, k] = (up - down) / (2 * step)
    jac = np.concatenate([dcm_from_euler_batch(euler), d_euler], axis=2)  # (N, 3, 6)
    cov = np.array(trace.pose_cov).reshape(-1, 9, 9)
    block = np.r_[VEL, EUL]
    cov_ve = cov[:, block][:, :, block]  # (N, 6, 6) over (v_B, Λ)
    cov_n = np.einsum("nij,njk,nlk->nil", jac, cov_ve, jac)
    sigma = np.sqrt(np.clip(np.diagonal(cov_n, axis1=1, axis2=2), 0.0, None))
    return est_n - true_n, sigma


def _velocity_error_figure(plt: Any, trace: Trace) -> Any:
    """The inertial velocity error per NED axis against ±3σ."""
    t = np.array(trace.t)
    err, sigma = inertial_velocity_error(trace)
    fig, axes = plt.subplots(3, 1, figsize=(8, 6), sharex=True)
    for i, label in enumerate(["north", "east", "down"]):
        _error_band(axes[i], t, err[:, i], 3 * sigma[:, i])
        axes[i].set_ylabel(f"{label} error [m/s]")
    axes[0].legend(fontsize=7)
    axes[2].set_xlabel("time [s]")
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
