"""The ``render`` section of ``quadslam bench``: frame rate and the cost of recording videos.

* ``frames_per_s/<estimator>``: ``env.render()`` of ``gymnasium.make(id,
  render_mode="rgb_array")`` on the paper EKF-SLAM scenario and the FastSLAM helix (default
  640×480 frame), DF-LQR flying; between two timed frames the env steps 0.1 s (untimed), so
  every call draws a new frame. Frames/s = frames / time spent in ``render()``; the map has
  been filling for ``warmup_s``.
* ``episode_render_s``: a whole episode (paper EKF-SLAM, 50 s in the full plan, 3 s in the
  quick one) with ``render()`` called after every step, as ``gymnasium.wrappers.RecordVideo``
  does: the seconds spent in ``render()`` (frames are drawn ``render.fps`` = 10 times per
  simulated second, the calls in between return the last frame).
* ``record_video_wall_s`` / ``record_video_render_s`` (only with moviepy installed, e.g.
  ``pip install "quadslam[video]"``): the same episode through ``RecordVideo`` — wall time of
  the whole recorded episode (steps, frames and moviepy's MP4 encoding) and the part of it
  spent in ``render()``.
"""

from __future__ import annotations

import importlib.util
import tempfile
import time
from typing import Any

import gymnasium as gym

from agents.lab.bench.plan import Plan, Results

# Per plan: (timed frames per sample, warm-up s, episode s, episode repeats).
SIZES = {"tiny": (4, 0.5, 2.0, 1), "quick": (5, 2.0, 3.0, 1), "full": (100, 10.0, 50.0, 3)}
FRAME_CASES: tuple[tuple[str, str, dict[str, Any]], ...] = (
    ("ekf_slam", "QuadSLAM-EKF-v0", {}),
    ("fastslam", "QuadSLAM-FastSLAM-v0", {}),
)
STEPS_PER_FRAME_S = 0.1  # simulated time between two timed frames


class RenderTimer(gym.Wrapper):
    """Passes everything through and adds up the wall time spent in ``render()``."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.render_s = 0.0
        self.calls = 0

    def render(self) -> Any:
        """The wrapped env's frame, timed."""
        tic = time.perf_counter()
        frame = self.env.render()
        self.render_s += time.perf_counter() - tic
        self.calls += 1
        return frame


def _fly(env: Any, policy: Any, obs: Any, seconds: float) -> Any:
    """Step ``env`` with ``policy`` for ``seconds`` of simulated time; the last observation."""
    for _ in range(round(seconds / env.unwrapped.dt)):
        obs, _, terminated, truncated, _ = env.step(policy.predict(obs)[0])
        if terminated or truncated:
            obs, _ = env.reset()
    return obs


def frame_rates(
    env_id: str, kwargs: dict[str, Any], frames: int, warmup_s: float, repeats: int
) -> list[float]:
    """Frames/s samples of ``env.render()``, each over ``frames`` new frames."""
    from agents.control.dflqr import DFLQRPolicy

    env = gym.make(env_id, render_mode="rgb_array", **kwargs)
    policy = DFLQRPolicy.from_env(env)
    obs, _ = env.reset(seed=0)
    obs = _fly(env, policy, obs, warmup_s)
    env.render()  # builds the figure
    samples = []
    for _ in range(repeats):
        spent = 0.0
        for _ in range(frames):
            obs = _fly(env, policy, obs, STEPS_PER_FRAME_S)
            tic = time.perf_counter()
            env.render()
            spent += time.perf_counter() - tic
        samples.append(frames / spent)
    env.close()
    return samples


def episode_render(duration_s: float, record: bool) -> tuple[float, float, int]:
    """Fly one paper EKF-SLAM episode calling ``render()`` after every step.

    Args:
        duration_s: Episode length in s.
        record: Wrap the env in ``gymnasium.wrappers.RecordVideo`` (needs moviepy).

    Returns:
        ``(wall s of the episode, s spent in render(), render() calls)``; with ``record`` the
        wall time includes writing the MP4 when the wrapper is closed.
    """
    from gymnasium.wrappers import RecordVideo

    from agents.control.dflqr import DFLQRPolicy

    base = gym.make("QuadSLAM-EKF-v0", render_mode="rgb_array", episode={"duration_s": duration_s})
    timer = RenderTimer(base)
    with tempfile.TemporaryDirectory() as folder:
        video_folder = f"{folder}/videos"  # a new folder (RecordVideo warns on an existing one)
        env: Any = (
            RecordVideo(timer, video_folder, episode_trigger=lambda _: True) if record else timer
        )
        policy = DFLQRPolicy.from_env(base)
        tic = time.perf_counter()
        obs, _ = env.reset(seed=0)
        if not record:
            env.render()
        while True:
            obs, _, terminated, truncated, _ = env.step(policy.predict(obs)[0])
            if not record:
                env.render()
            if terminated or truncated:
                break
        env.close()
        wall = time.perf_counter() - tic
    return wall, timer.render_s, timer.calls


def bench_render(results: Results, plan: Plan) -> None:
    """Frames/s of ``render()`` and the time to record a video of an episode."""
    import quadslam_env  # noqa: F401

    frames, warmup_s, duration_s, repeats = SIZES.get(plan.name, SIZES["quick"])
    for label, env_id, kwargs in FRAME_CASES:
        results.add(
            "render",
            f"frames_per_s/{label}",
            frame_rates(env_id, kwargs, frames, warmup_s, plan.repeats),
            "frames/s",
            note=f"render() of a new frame every {STEPS_PER_FRAME_S} s of flight, 640x480",
            estimator=label,
            frames=frames,
            warmup_s=warmup_s,
        )
    runs = [episode_render(duration_s, record=False) for _ in range(repeats)]
    results.add(
        "render",
        "episode_render_s",
        [r[1] for r in runs],
        "s",
        note="time in render() over an episode with render() after every step (10 frames "
        f"drawn per simulated second); target < 30 s for 50 s (this episode: {duration_s:g} s)",
        episode_s=duration_s,
        calls=runs[0][2],
    )
    if importlib.util.find_spec("moviepy") is None:
        print(
            "bench render: RecordVideo skipped (moviepy is not installed; "
            "pip install 'quadslam[video]')"
        )
        return
    runs = [episode_render(duration_s, record=True) for _ in range(repeats)]
    results.add(
        "render",
        "record_video_wall_s",
        [r[0] for r in runs],
        "s",
        note="gymnasium.wrappers.RecordVideo, whole episode: steps, frames, MP4 encoding",
        episode_s=duration_s,
    )
    results.add(
        "render",
        "record_video_render_s",
        [r[1] for r in runs],
        "s",
        note="the part of record_video_wall_s spent in render()",
        episode_s=duration_s,
    )
