"""Videos of evaluation episodes: each episode rendered off-screen and written as one MP4 file.

``ilcsan evaluate RUN --video DIR`` plays the same deterministic episodes as without ``--video`` (rendering reads
the simulator's state, it does not change it) and writes the episode reset with seed S to
``DIR/<task>-seed<S>.mp4``, so a file's name says which episode ``--seed S --episodes 1`` replays.

- Frames: Gymnasium's ``render_mode="rgb_array"``, at the task's own frame rate (``metadata["render_fps"]``:
  125 for Hopper, whose control step is 8 ms), so a video plays in real time.
- OpenGL: MuJoCo tasks render through it. On a machine without a display it takes EGL (a GPU's, or Mesa's
  software one) or OSMesa; :func:`prepare_rendering` picks ``MUJOCO_GL=egl`` when neither ``MUJOCO_GL`` nor a
  display is set. Box2D and classic-control tasks draw with pygame and need neither.
- Encoder: ffmpeg from the ``imageio-ffmpeg`` wheel (``pip install 'ilcsan[video]'``; ``scripts/setup``
  installs it), H.264 in an MP4 container.
- Nothing half-written: a video is encoded into a temporary file beside its target and renamed when its episode
  ends (:func:`ilcsan.files.replacing`); an episode that does not end (an interrupted evaluation) leaves no file.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Generator
from pathlib import Path

import gymnasium
import numpy as np

from ..errors import UserError
from ..files import replacing
from .tasks import RENDERING_FIX, one_line, task_file_name

INSTALL_HINT = "pip install 'ilcsan[video]' (scripts/setup installs it)"
"""How to get the encoder when it is missing."""


class EpisodeAbandoned(Exception):
    """Thrown into an episode's writer whose episode did not end: its temporary file is removed."""


def prepare_rendering() -> None:
    """On a machine without a display, render off-screen: MuJoCo through EGL when the user chose no ``MUJOCO_GL``
    (else MuJoCo tries GLFW, which needs a display, and fails), pygame (Box2D and classic-control tasks) through
    SDL's dummy video driver (else SDL complains on the console that it has no display). Call before the first
    environment renders."""
    if os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"):
        return
    if "MUJOCO_GL" not in os.environ:
        os.environ["MUJOCO_GL"] = "egl"
        os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
    os.environ.setdefault("SDL_VIDEODRIVER", "dummy")


def ffmpeg():
    """The ``imageio_ffmpeg`` module, or a one-line error that says how to install it."""
    try:
        import imageio_ffmpeg
    except ModuleNotFoundError:
        raise UserError(f"--video needs ffmpeg from the imageio-ffmpeg package: {INSTALL_HINT}") from None
    return imageio_ffmpeg


def video_path(folder: Path, task: str, seed: int) -> Path:
    """Where the episode of ``task`` reset with ``seed`` is written."""
    return Path(folder) / f"{task_file_name(task)}-seed{seed}.mp4"


SHADOW_MAP_SIZE = 1024
"""Side of MuJoCo's shadow map in videos (MuJoCo's tasks ask for 4096)."""
TRACKING_CAMERA = "track"
"""The camera that Gymnasium's MuJoCo models define to follow the body's centre of mass."""


def _prepare_mujoco_rendering(env) -> None:
    """Before a MuJoCo task's first frame:

    - the camera follows the body: the model's own ``track`` camera (side view, centre of mass tracked) where the
      task has one, as every locomotion task of the paper does. Gymnasium's default free camera stays where the
      episode began, and a hopper that learned to hop leaves its frame within seconds.
    - no multisample anti-aliasing and a smaller shadow map: at 480 × 480 the frames look the same, and software
      OpenGL (Mesa's llvmpipe, what a machine without a GPU has) renders them several times faster.

    Only the rendering reads these settings; the physics does not."""
    import mujoco

    unwrapped = env.unwrapped
    model, renderer = getattr(unwrapped, "model", None), getattr(unwrapped, "mujoco_renderer", None)
    if not isinstance(model, mujoco.MjModel) or renderer is None:
        return
    model.vis.quality.offsamples = 0
    model.vis.quality.shadowsize = min(model.vis.quality.shadowsize, SHADOW_MAP_SIZE)
    tracking = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, TRACKING_CAMERA)
    if tracking >= 0:
        renderer.camera_id = tracking


def _episode_writer(path: Path, first_frame: np.ndarray, fps: float) -> Generator[None, np.ndarray, None]:
    """A coroutine that encodes the frames sent to it into ``path``: ``close()`` after the last frame finishes the
    file and renames it into place; throwing :class:`EpisodeAbandoned` in removes the temporary file."""
    height, width = first_frame.shape[:2]
    encoder = ffmpeg()
    try:
        with replacing(path) as temporary:
            frames = encoder.write_frames(temporary, (width, height), fps=fps, macro_block_size=2,
                                          ffmpeg_log_level="error", output_params=["-f", "mp4"])
            frames.send(None)
            try:
                frame = first_frame
                while True:
                    frames.send(np.ascontiguousarray(frame, dtype=np.uint8))
                    frame = yield
            except GeneratorExit:
                pass
            finally:
                frames.close()
    except (OSError, ValueError) as error:  # a folder that cannot be written or named, a full disk, ffmpeg stopping
        cause = (str(error).strip().splitlines() or [type(error).__name__])[0]
        raise UserError(f"cannot write the video {path}: {cause}") from None


class EpisodeVideo(gymnasium.Wrapper):
    """Records every episode of the wrapped environment (made with ``render_mode="rgb_array"``) to
    :func:`video_path` ``(folder, task, seed)``, the seed being the one its reset was given."""

    def __init__(self, env, folder: Path, task: str):
        super().__init__(env)
        self.folder, self.task = Path(folder), task
        self.fps = float(env.metadata.get("render_fps") or 30)
        _prepare_mujoco_rendering(env)
        self._writer: Generator[None, np.ndarray, None] | None = None

    def reset(self, *, seed: int | None = None, options=None):
        if seed is None:
            raise ValueError("EpisodeVideo names each video by its episode's seed: reset it with one")
        self._abandon()
        result = self.env.reset(seed=seed, options=options)
        self._writer = _episode_writer(video_path(self.folder, self.task, seed), self._frame(), self.fps)
        next(self._writer)
        return result

    def step(self, action):
        result = self.env.step(action)
        if self._writer is not None:
            self._writer.send(self._frame())
            if result[2] or result[3]:  # terminated or truncated: the episode's video is complete
                self._writer.close()
                self._writer = None
        return result

    def close(self):
        self._abandon()
        super().close()

    def _frame(self) -> np.ndarray:
        try:
            frame = self.env.render()
        except Exception as error:  # noqa: BLE001 - every rendering failure is reported in one line
            cause = one_line(str(error)) or type(error).__name__
            raise UserError(f"task {self.task!r} cannot be rendered on this machine: {cause}; {RENDERING_FIX}"
                            ) from None
        if not isinstance(frame, np.ndarray) or frame.ndim != 3:
            raise UserError(f"task {self.task!r} renders no RGB frames, so it cannot be recorded")
        return frame

    def _abandon(self) -> None:
        """Drop the video of an episode that did not end."""
        if self._writer is not None:
            writer, self._writer = self._writer, None
            with contextlib.suppress(EpisodeAbandoned, StopIteration):
                writer.throw(EpisodeAbandoned())
