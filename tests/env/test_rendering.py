"""``rgb_array`` frames (quadslam_env.render) and videos (``--video``, RecordVideo).

Frame content is checked through facts that do not depend on the drawing: sizes, that frames
change when the vehicle moves, that lane 0 of a vector env draws exactly the scalar env's
frame, that rendering leaves the rollout untouched, and that an env without ``render_mode``
imports nothing for it. The frame rate is measured by ``quadslam bench --only render``.
"""

from __future__ import annotations

import importlib.util
import math
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from PIL import Image

import quadslam_env  # noqa: F401  (registers the ids)
from agents.control.dflqr import DFLQRPolicy
from agents.lab.cli.main import main
from quadslam_env.render.history import LaneHistory
from quadslam_env.render.scene import ellipse_lines, plane_cov
from quadslam_env.render.spatial import nice_ceil
from quadslam_env.schema import ConfigError

ROOT = Path(__file__).resolve().parents[2]
SHORT = {"episode": {"duration_s": 3.0}}


def _fly(env, steps: int, obs=None):
    policy = DFLQRPolicy.from_env(env)
    if obs is None:
        obs, _ = env.reset(seed=3)
    for _ in range(steps):
        obs, *_ = env.step(policy.predict(obs)[0])
    return obs


# ----------------------------------------------------------------------------- frames
def test_default_frame_is_640x480_rgb_uint8():
    env = gym.make("QuadSLAM-EKF-v0", render_mode="rgb_array", **SHORT)
    _fly(env, 30)
    frame = env.render()
    assert frame.shape == (480, 640, 3) and frame.dtype == np.uint8
    assert len(np.unique(frame.reshape(-1, 3), axis=0)) > 20  # drawn, not blank


def test_frame_size_from_make_kwarg_and_scenario_section():
    env = gym.make(
        "QuadSLAM-Oracle-v0", render_mode="rgb_array", render={"width_px": 800, "height_px": 450}
    )
    env.reset(seed=0)
    assert env.render().shape == (450, 800, 3)


@pytest.mark.parametrize(
    ("override", "key"),
    [
        ({"width_px": 100}, "render.width_px"),
        ({"height_px": 480.5}, "render.height_px"),
        ({"fps": 0}, "render.fps"),
        ({"colour": "red"}, "render.colour"),
    ],
)
def test_bad_render_settings_name_the_key(override, key):
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        gym.make("QuadSLAM-Oracle-v0", render=override)


def test_frame_changes_as_the_vehicle_moves_and_is_held_between_frame_times():
    env = gym.make("QuadSLAM-EKF-v0", render_mode="rgb_array", **SHORT)
    obs = _fly(env, 50)
    first = env.render()
    assert env.render() is first  # no time has passed: the same frame
    assert not first.flags.writeable
    obs = _fly(env, 5, obs)  # 0.05 s < 1 / render.fps
    assert env.render() is first
    _fly(env, 50, obs)
    moved = env.render()
    assert moved is not first
    assert np.count_nonzero(np.any(moved != first, axis=2)) > 1000


def test_fps_null_draws_on_every_call():
    env = gym.make("QuadSLAM-Oracle-v0", render_mode="rgb_array", render={"fps": None})
    obs = _fly(env, 10)
    first = env.render()
    _fly(env, 1, obs)
    assert env.render() is not first


def test_render_fps_metadata_is_the_control_rate():
    env = gym.make("QuadSLAM-Oracle-v0", episode={"control_hz": 50.0})
    assert env.unwrapped.metadata["render_fps"] == 50
    assert gym.make("QuadSLAM-Oracle-v0").unwrapped.metadata["render_fps"] == 100


def test_rendering_does_not_change_the_rollout():
    """The renderer reads truth and estimate; it must not feed anything back (or draw RNG)."""
    plain = gym.make("QuadSLAM-EKF-v0", **SHORT)
    drawn = gym.make("QuadSLAM-EKF-v0", render_mode="rgb_array", **SHORT)
    policy = DFLQRPolicy.from_env(plain)
    a, _ = plain.reset(seed=5)
    b, _ = drawn.reset(seed=5)
    for _ in range(60):
        drawn.render()
        a, *_ = plain.step(policy.predict(a)[0])
        b, *_ = drawn.step(policy.predict(b)[0])
    np.testing.assert_array_equal(a, b)


def test_fastslam_frame_draws_a_particle_subsample():
    env = gym.make("QuadSLAM-FastSLAM-v0", render_mode="rgb_array", render={"max_particles": 50})
    _fly(env, 20)
    renderer = env.unwrapped._renderer
    from quadslam_env.render.scene import gather

    scene = gather(env.unwrapped.core, 0, renderer.history, 10.0, 50)
    assert scene.n_particles == 500
    assert scene.particles is not None and 0 < scene.particles.shape[0] <= 50
    assert env.render().shape == (480, 640, 3)


def test_env_without_render_mode_imports_and_records_nothing():
    code = (
        "import sys, gymnasium as gym, numpy as np, quadslam_env\n"
        "env = gym.make('QuadSLAM-EKF-v0', episode={'duration_s': 1.0})\n"
        "env.reset(seed=0)\n"
        "for _ in range(20): env.step(np.zeros(4, dtype=np.float32))\n"
        "mode = 'vector_entry_point'\n"
        "vec = gym.make_vec('QuadSLAM-EKF-v0', num_envs=2, vectorization_mode=mode)\n"
        "vec.reset(seed=0); vec.step(np.zeros((2, 4), dtype=np.float32))\n"
        "assert env.render() is None and vec.render() is None\n"
        "assert env.unwrapped._renderer is None and vec.unwrapped._renderer is None\n"
        "names = ('matplotlib', 'quadslam_env.render')\n"
        "print(sorted(m for m in sys.modules if m.startswith(names)))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, check=True
    )
    assert out.stdout.strip() == "[]"


def test_vector_env_renders_lane_0_as_the_scalar_env():
    vec = gym.make_vec(
        "QuadSLAM-EKF-v0", num_envs=2, vectorization_mode="vector_entry_point",
        render_mode="rgb_array", **SHORT,
    )  # fmt: skip
    env = gym.make("QuadSLAM-EKF-v0", render_mode="rgb_array", **SHORT)
    policy = DFLQRPolicy.from_env(env)
    obs_v, _ = vec.reset(seed=7)  # lane 0 seeded 7, lane 1 seeded 8
    obs_s, _ = env.reset(seed=7)
    for _ in range(40):
        obs_v, *_ = vec.step(policy.predict(obs_v)[0])
        obs_s, *_ = env.step(policy.predict(obs_s)[0])
    np.testing.assert_array_equal(vec.render(), env.render())
    vec.close()


# ----------------------------------------------------------------------------- pieces
def test_ellipse_outline_reaches_three_sigma_on_the_axes():
    cov = np.array([[[4.0, 0.0], [0.0, 0.25]]])  # σx = 2, σy = 0.5
    x, y = ellipse_lines(np.array([[1.0, -1.0]]), cov)
    assert math.isnan(x[-1]) and math.isnan(y[-1])  # separator after each outline
    assert np.nanmax(x) == pytest.approx(1.0 + 6.0) and np.nanmin(x) == pytest.approx(1.0 - 6.0)
    assert np.nanmax(y) == pytest.approx(-1.0 + 1.5, rel=1e-3)


def test_plane_cov_flips_the_cross_term_for_altitude():
    cov = np.array([[1.0, 0.1, 0.2], [0.1, 2.0, 0.3], [0.2, 0.3, 3.0]])
    np.testing.assert_array_equal(plane_cov(cov, (1, 0)), [[2.0, 0.1], [0.1, 1.0]])
    np.testing.assert_array_equal(plane_cov(cov, (1, 2)), [[2.0, -0.3], [-0.3, 3.0]])


def test_nice_ceil_is_one_two_five():
    assert [nice_ceil(v) for v in (0.013, 0.2, 0.21, 3.0, 7.0)] == [0.02, 0.2, 0.5, 5.0, 10.0]


def test_history_ring_keeps_the_newest_rows_in_order():
    env = gym.make("QuadSLAM-Oracle-v0")
    env.reset(seed=0)
    core = env.unwrapped.core
    hist = LaneHistory(capacity=5)
    hist.record(core, 0)
    for _ in range(7):
        env.step(np.zeros(4, dtype=np.float32))
        hist.record(core, 0)
        hist.record(core, 0)  # same step again: ignored
    t = hist.rows()[:, 0]
    np.testing.assert_allclose(t, np.arange(3, 8) * core.dt)
    env.reset(seed=1)
    hist.record(core, 0)
    assert len(hist) == 1 and hist.episode == 2


# ----------------------------------------------------------------------------- videos
def test_run_video_writes_a_readable_gif(tmp_path, capsys):
    path = tmp_path / "sub" / "flight.gif"
    assert main(["run", "--duration", "1", "--no-plots", "--video", str(path)]) == 0
    assert "video:" in capsys.readouterr().out
    with Image.open(path) as gif:
        assert gif.size == (640, 480)
        assert gif.n_frames == 11  # t = 0, 0.1, ..., 1.0 s at render.fps = 10
        assert gif.info["duration"] == 100


@pytest.mark.skipif(
    importlib.util.find_spec("imageio_ffmpeg") is None, reason="imageio-ffmpeg not installed"
)
def test_evaluate_video_writes_a_readable_mp4(tmp_path):
    import imageio_ffmpeg

    path = tmp_path / "eval.mp4"
    argv = ["evaluate", "--policy", "dflqr", "--episodes", "2", "--duration", "1"]
    assert main([*argv, "--video", str(path)]) == 0
    reader = imageio_ffmpeg.read_frames(str(path))
    meta = next(reader)
    assert meta["size"] == (640, 480) and meta["fps"] == 10
    assert sum(1 for _ in reader) == 11


@pytest.mark.parametrize(
    ("name", "expected"),
    [("clip.avi", "allowed: a file name ending in .gif or .mp4"), ("folder", "is a folder")],
)
def test_bad_video_path_is_one_line_and_flies_nothing(tmp_path, capsys, name, expected):
    (tmp_path / "folder.gif").mkdir()
    path = tmp_path / ("folder.gif" if name == "folder" else name)
    code = main(["run", "--duration", "1", "--no-plots", "--video", str(path)])
    captured = capsys.readouterr()
    assert code == 2
    assert captured.err.strip().count("\n") == 0 and expected in captured.err
    assert captured.out == ""  # no results table: nothing was flown


def test_video_under_a_file_is_rejected(tmp_path, capsys):
    (tmp_path / "plain").write_text("")
    code = main(["run", "--no-plots", "--video", str(tmp_path / "plain" / "x.gif")])
    assert code == 2 and "--video" in capsys.readouterr().err


@pytest.mark.skipif(importlib.util.find_spec("moviepy") is None, reason="moviepy not installed")
def test_record_video_wrapper_writes_an_mp4(tmp_path):
    from gymnasium.wrappers import RecordVideo

    env = gym.make("QuadSLAM-Oracle-v0", render_mode="rgb_array", episode={"duration_s": 0.5})
    env = RecordVideo(env, str(tmp_path / "videos"), episode_trigger=lambda _: True)
    _fly(env, 50)
    env.close()
    assert len(list((tmp_path / "videos").glob("*.mp4"))) == 1
