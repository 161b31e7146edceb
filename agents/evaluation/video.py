"""Videos of a flight: ``quadslam run --video FILE`` and ``quadslam evaluate --video FILE``.

The frames are the env's ``rgb_array`` frames (:mod:`quadslam_env.render`) of lane 0 of the
vector env that flies the episodes (the first seed), drawn ``render.fps`` times per simulated
second and played back at that rate, so the video runs in real time. Formats by extension:

- ``.gif``: Pillow (installed with matplotlib); each frame quantised to 128 colours.
- ``.mp4``: H.264 through the ffmpeg binary that ``imageio-ffmpeg`` ships (the ``video`` extra:
  ``pip install "quadslam[video]"``).
"""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path
from typing import Any

import numpy as np

from agents.io.outputs import Saver
from agents.io.paths import check_output_file

FORMATS = (".gif", ".mp4")
NEEDS = {
    ".gif": (("matplotlib", "matplotlib", "plots"),),
    ".mp4": (("matplotlib", "matplotlib", "plots"), ("imageio_ffmpeg", "imageio-ffmpeg", "video")),
}
"""What each file type needs, as (module, package, the ``quadslam[...]`` extra that brings it):
the frames are the renderer's (matplotlib; a GIF is written with its Pillow), an MP4 is encoded
by the ffmpeg of imageio-ffmpeg."""


def check_video_path(path: Path) -> None:
    """Fail early (before anything is flown) on a video path that cannot be written.

    Missing parent folders are created, as for ``--json``; the folder must accept a new file
    (see :func:`agents.io.paths.check_output_file`).

    Raises:
        ValueError: One-line message: an extension other than :data:`FORMATS`, a folder at
            ``path``, a folder that cannot be created or written.
        quadslam_env.extras.MissingExtraError: What the file type needs is not installed
            (:data:`NEEDS`); the one line names the extras that bring it.
    """
    suffix = path.suffix.lower()
    if suffix not in FORMATS:
        raise ValueError(
            f"--video: got {str(path)!r}; allowed: a file name ending in {' or '.join(FORMATS)}"
        )
    missing = [(name, extra) for module, name, extra in NEEDS[suffix] if not _installed(module)]
    if missing:
        from quadslam_env.extras import MissingExtraError

        raise MissingExtraError(_missing_line(suffix, missing))
    check_output_file(path, "--video")


def _installed(module: str) -> bool:
    return importlib.util.find_spec(module) is not None


def _missing_line(suffix: str, missing: list[tuple[str, str]]) -> str:
    """The one line naming what a ``suffix`` video needs and is ``missing`` (package, extra)."""
    names = " and ".join(name for name, _ in missing)
    extras = ",".join(extra for _, extra in missing)
    are, them = ("is", "it") if len(missing) == 1 else ("are", "them")
    line = (
        f"--video: writing {suffix} needs {names}, which {are} not installed; install {them} "
        f"with: pip install 'quadslam[{extras}]'"
    )
    gif_works = all(name != "matplotlib" for name, _ in missing)
    return line + ("; or give a .gif file name" if suffix != ".gif" and gif_works else "")


class VideoWriter:
    """Frames (H, W, 3) uint8 appended one by one to a GIF or MP4 file.

    Args:
        path: Output file; the format follows the extension (see :func:`check_video_path`).
        fps: Frames per second of playback.
    """

    def __init__(self, path: Path, fps: float) -> None:
        check_video_path(path)
        self.path = path
        self.fps = float(fps)
        self.frames = 0
        self._gif: list[Any] = []
        self._mp4: Any = None
        self._mp4_tmp: Path | None = None

    def append(self, frame: np.ndarray) -> None:
        """Add one frame (all frames must have the same size)."""
        if self.path.suffix.lower() == ".gif":
            from PIL import Image

            image = Image.fromarray(np.ascontiguousarray(frame))
            self._gif.append(
                image.quantize(128, method=Image.Quantize.FASTOCTREE, dither=Image.Dither.NONE)
            )
        else:
            if self._mp4 is None:
                import imageio_ffmpeg

                height, width = frame.shape[:2]
                # Streamed under a temporary name beside the file, renamed at close().
                self._mp4_tmp = self.path.with_name(f".{self.path.stem}.tmp-video.mp4")
                self._mp4 = imageio_ffmpeg.write_frames(
                    str(self._mp4_tmp),
                    (width, height),
                    fps=self.fps,
                    codec="libx264",
                    quality=7,
                    pix_fmt_out="yuv420p",
                    macro_block_size=2,
                )
                self._mp4.send(None)
            self._mp4.send(np.ascontiguousarray(frame))
        self.frames += 1

    def close(self, saver: Saver | None = None) -> Path:
        """Finish the file: a GIF is written here, an MP4 stream is flushed; both are moved
        into place atomically.

        Args:
            saver: Records a failed write (the video then goes to a fallback place, see
                :class:`agents.io.outputs.Saver`); without one, a failure raises at once.

        Returns:
            Where the video was written.

        Raises:
            agents.io.outputs.OutputWriteError: Without ``saver``, when the file could not be
                written where asked.
        """
        own = saver is None
        saver = saver or Saver()
        where = self.path
        if self._gif:
            frames, self._gif = self._gif, []
            duration = round(1000.0 / self.fps)

            def produce(target: Path) -> None:
                frames[0].save(
                    target,
                    format="GIF",
                    save_all=True,
                    append_images=frames[1:],
                    duration=duration,
                    loop=0,
                )

            where = saver.produce(self.path, "--video", produce)
        if self._mp4 is not None and self._mp4_tmp is not None:
            self._mp4.close()
            self._mp4 = None
            tmp, self._mp4_tmp = self._mp4_tmp, None
            try:
                os.replace(tmp, self.path)
            except OSError as exc:  # the finished stream stays under its temporary name
                saver.record("--video", self.path, exc, tmp)
                where = tmp
        if own:
            saver.check()
        return where


class LaneVideo:
    """Records one lane of a :class:`~quadslam_env.core.SimCore` into a :class:`VideoWriter`.

    Call :meth:`attach` after the core's reset, :meth:`record` after every step while the lane
    flies its episode, and :meth:`close` at the end.

    Args:
        path: Output file (``.gif`` or ``.mp4``).
    """

    def __init__(self, path: Path) -> None:
        check_video_path(path)
        self.path = path
        self.writer: VideoWriter | None = None
        self.renderer: Any = None
        self._last: np.ndarray | None = None

    def attach(self, core: Any, lane: int = 0, info: dict[str, Any] | None = None) -> None:
        """Follow lane ``lane`` of ``core`` (just reset; ``info`` is the reset's info)."""
        from quadslam_env.render.renderer import LaneRenderer

        self.renderer = LaneRenderer(core, lane)
        fps = core.scenario.render.fps
        rate = 1.0 / core.dt if fps is None else min(fps, 1.0 / core.dt)
        self.writer = VideoWriter(self.path, rate)
        self.record(info)

    def record(self, info: dict[str, Any] | None = None) -> None:
        """Record the lane's current step and write a frame when one is due."""
        if self.renderer is None or self.writer is None:
            return
        self.renderer.record(info)
        frame = self.renderer.frame()
        if frame is not self._last:  # a new drawing (the renderer caps the rate at fps)
            self.writer.append(frame)
            self._last = frame

    @property
    def frames(self) -> int:
        """Frames written so far."""
        return 0 if self.writer is None else self.writer.frames

    def close(self, saver: Saver | None = None) -> Path:
        """Write the file (see :meth:`VideoWriter.close`); returns where it went."""
        if self.writer is not None:
            return self.writer.close(saver)
        return self.path
