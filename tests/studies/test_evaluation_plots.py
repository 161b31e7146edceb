"""The figures of ``quadslam run``: labelled axes with units, titles, the reference path, ±3σ
bands, and a 3D view framed on the flown path (read from the matplotlib figures)."""

from __future__ import annotations

import contextlib
import io
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

import quadslam_env  # noqa: F401  (registers the ids)
from agents.control.dflqr import DFLQRPolicy
from agents.evaluation.episodes import Trace, run_episodes
from agents.evaluation.plots import FIGURES, MIN_MARGIN_M, figures, inertial_velocity_error
from agents.lab.cli.main import main

pytest.importorskip("matplotlib")  # the figures need it (the module imports it when drawing)

TITLE = "paper_ekf_figure8 / ekf_slam / seed 0"


@pytest.fixture(scope="module")
def trace() -> Trace:
    """The first seed's episode of two, 3 s of the EKF-SLAM figure-8 (it maps landmarks)."""
    env = gym.make("QuadSLAM-EKF-v0", episode={"duration_s": 3.0})
    trace = Trace()
    run_episodes(env, DFLQRPolicy.from_env(env), [0, 1], trace=trace)
    env.close()
    return trace


@pytest.fixture(scope="module")
def figs(trace: Trace) -> Iterator[dict[str, Any]]:
    import matplotlib.pyplot as plt

    out = figures(trace, TITLE)
    yield out
    for fig in out.values():
        plt.close(fig)


def test_every_figure_is_drawn_with_a_title(figs: dict[str, Any]) -> None:
    assert tuple(figs) == FIGURES
    for name, fig in figs.items():
        if name == "path_3d.png":
            assert fig.axes[0].get_title() == TITLE
        else:
            assert fig._suptitle is not None and fig._suptitle.get_text().startswith(TITLE)
    assert figs["velocity_error.png"]._suptitle.get_text().endswith("inertial velocity error")


@pytest.mark.parametrize(
    ("name", "unit"),
    [("position.png", "m"), ("velocity_body.png", "m/s"), ("attitude.png", "deg")],
)
def test_state_panels_label_both_columns_with_units(
    figs: dict[str, Any], name: str, unit: str
) -> None:
    axes = np.array(figs[name].axes).reshape(3, 2)
    for left, right in axes:
        assert left.get_ylabel().endswith(f"[{unit}]")
        assert right.get_ylabel().endswith(f" error [{unit}]")
        assert "±3σ" in [line.get_label() for line in right.get_lines()]
    assert axes[2, 0].get_xlabel() == axes[2, 1].get_xlabel() == "time [s]"


def test_position_panel_draws_the_reference(figs: dict[str, Any], trace: Trace) -> None:
    axes = np.array(figs["position.png"].axes).reshape(3, 2)
    ref = np.array(trace.ref_pos)
    for i, ax in enumerate(axes[:, 0]):
        lines = {line.get_label(): line for line in ax.get_lines()}
        assert {"reference", "true", "estimated"} <= set(lines)
        np.testing.assert_array_equal(lines["reference"].get_ydata(), ref[:, i])


def test_velocity_error_has_a_band_and_units_on_every_axis(figs: dict[str, Any]) -> None:
    axes = figs["velocity_error.png"].axes
    assert [ax.get_ylabel() for ax in axes] == [
        "north error [m/s]", "east error [m/s]", "down error [m/s]",
    ]  # fmt: skip
    for ax in axes:
        error, upper, lower = ax.get_lines()
        assert (error.get_label(), upper.get_label()) == ("error", "±3σ")
        band = np.asarray(upper.get_ydata())
        assert np.all(np.isfinite(band)) and np.all(band > 0)  # EKF-SLAM has a covariance
        np.testing.assert_array_equal(np.asarray(lower.get_ydata()), -band)


def test_inertial_velocity_sigma_carries_the_heading_uncertainty() -> None:
    # Level, heading north at 2 m/s: a yaw error δψ turns the velocity by 2 δψ to the east,
    # and the body-axis velocity σ reaches the inertial axes unchanged.
    trace = Trace()
    cov = np.zeros((9, 9))
    cov[3, 3], cov[4, 4], cov[5, 5] = 0.01**2, 0.02**2, 0.03**2  # σ of u, v, w
    cov[8, 8] = 0.1**2  # σ of ψ
    trace.t, trace.pose_cov = [0.0], [cov]
    trace.true_state = [np.r_[np.zeros(3), 2.0, 0.0, 0.0, np.zeros(6)]]
    trace.est_euler, trace.est_vel_body = [np.zeros(3)], [np.array([2.1, 0.0, 0.0])]
    err, sigma = inertial_velocity_error(trace)
    np.testing.assert_allclose(err[0], [0.1, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(sigma[0], [0.01, np.hypot(0.02, 2.1 * 0.1), 0.03], rtol=1e-6)


def _path_points(trace: Trace) -> np.ndarray:
    """Every point of the desired, true and estimated paths as (north, east, altitude)."""
    ned = np.concatenate(
        [np.array(trace.ref_pos), np.array(trace.true_state)[:, :3], np.array(trace.est_pos)]
    )
    return ned * np.array([1.0, 1.0, -1.0])


def test_path_view_encloses_the_flown_path_with_a_margin(
    figs: dict[str, Any], trace: Trace
) -> None:
    ax = figs["path_3d.png"].axes[0]
    limits = np.array([ax.get_xlim(), ax.get_ylim(), ax.get_zlim()])
    points = _path_points(trace)
    lo, hi = points.min(axis=0), points.max(axis=0)
    assert np.all(limits[:, 0] <= lo - MIN_MARGIN_M + 1e-9)
    assert np.all(limits[:, 1] >= hi + MIN_MARGIN_M - 1e-9)
    # Framed on the path (a few metres), not on the 40 m landmark field around it.
    assert np.all(limits[:, 1] - limits[:, 0] <= 1.5 * np.max(hi - lo) + 2 * MIN_MARGIN_M)
    assert trace.landmarks is not None
    field = trace.landmarks * np.array([1.0, 1.0, -1.0])
    assert np.max(np.ptp(field, axis=0)) > 2 * np.max(limits[:, 1] - limits[:, 0])


def test_path_view_draws_only_the_landmarks_inside_it(figs: dict[str, Any], trace: Trace) -> None:
    ax = figs["path_3d.png"].axes[0]
    limits = np.array([ax.get_xlim(), ax.get_ylim(), ax.get_zlim()])
    assert trace.landmarks is not None
    shown = trace.landmarks * np.array([1.0, 1.0, -1.0])
    inside = np.all((shown >= limits[:, 0]) & (shown <= limits[:, 1]), axis=1)
    drawn = next(c for c in ax.collections if c.get_label().startswith("landmarks"))
    xs, ys, zs = drawn._offsets3d
    assert len(xs) == int(inside.sum())
    assert drawn.get_label() == f"landmarks ({int(inside.sum())} of {len(shown)} in view)"
    for x, y, z in zip(xs, ys, zs, strict=True):
        assert limits[0, 0] <= x <= limits[0, 1] and limits[2, 0] <= z <= limits[2, 1]
        assert limits[1, 0] <= y <= limits[1, 1]


@pytest.fixture(scope="module")
def cli_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    """``quadslam run`` of seeds 3 and 4 with ``--plots``: the folder and what it printed."""
    folder = tmp_path_factory.mktemp("run") / "figs"
    args = ["run", "--duration", "0.3", "--seed", "3", "--seeds", "2", "--plots", str(folder)]
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert main(args) == 0
    return folder, out.getvalue()


def test_run_says_which_seed_its_figures_show(cli_run: tuple[Path, str]) -> None:
    folder, out = cli_run
    lines = [x for x in out.splitlines() if x.startswith("figures: ")]
    pngs = len(list(folder.glob("*.png")))
    assert lines == [f"figures: {folder} ({pngs} PNG, seed 3 only, of 2 seeds)"]


def test_run_writes_the_printed_table_beside_the_figures(cli_run: tuple[Path, str]) -> None:
    folder, out = cli_run
    saved = (folder / "results.txt").read_text(encoding="utf-8").splitlines()
    assert saved[0] == "paper_ekf_figure8 / ekf_slam / dflqr, seeds 3-4"
    printed = out.splitlines()
    first = next(i for i, x in enumerate(printed) if x.lstrip().startswith("seed "))
    table = printed[first : first + len(saved) - 1]
    assert saved[1:] == table and table[-1].startswith("median")
    assert [int(x.split()[0]) for x in table[2:4]] == [3, 4]  # one row per seed
    assert f"table: {folder / 'results.txt'}" in printed
