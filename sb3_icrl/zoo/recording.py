"""
Rendering without a display, and videos written as they are recorded.

:func:`configure_headless_rendering` picks an off-screen OpenGL backend for MuJoCo (``MUJOCO_GL=egl``, else
``osmesa``) when there is no display and ``MUJOCO_GL`` is unset. :func:`open_frame_writer` writes the frames of each
episode to its own file as they come: an mp4 streamed through imageio's ffmpeg writer when ``imageio-ffmpeg`` is
installed, a GIF per episode (Pillow; only that episode's frames are held, as gymnasium's ``RecordVideo`` holds
them), or PNG files written one by one (matplotlib).
"""

import ctypes.util
import importlib.util
import os
import sys
from collections.abc import Callable, MutableMapping
from typing import Any

import numpy as np

from sb3_icrl.common.utils import atomic_write

#: Off-screen OpenGL backends of MuJoCo, in the order tried, with the library each needs
HEADLESS_BACKENDS = (("egl", "EGL"), ("osmesa", "OSMesa"))
#: How ``--record`` can write, best first: ``(backend, module it needs, what it writes)``
RECORDING_BACKENDS = (
    ("ffmpeg", "imageio_ffmpeg", "mp4"),
    ("pillow", "PIL", "GIF"),
    ("matplotlib", "matplotlib", "PNG frames"),
)


def has_display(environ: MutableMapping[str, str] | None = None, platform: str | None = None) -> bool:
    """
    :param environ: The environment (default: ``os.environ``)
    :param platform: ``sys.platform`` (default: this one)
    :return: Whether windows can be opened: always on macOS and Windows, with ``DISPLAY`` or ``WAYLAND_DISPLAY`` else
    """
    environ = os.environ if environ is None else environ
    platform = sys.platform if platform is None else platform
    if not platform.startswith("linux"):
        return True
    return bool(environ.get("DISPLAY") or environ.get("WAYLAND_DISPLAY"))


def configure_headless_rendering(
    environ: MutableMapping[str, str] | None = None,
    platform: str | None = None,
    find_library: Callable[[str], str | None] = ctypes.util.find_library,
) -> str | None:
    """
    Without a display and with ``MUJOCO_GL`` unset, choose MuJoCo's off-screen backend: ``egl`` when libEGL is found,
    else ``osmesa`` when libOSMesa is; ``PYOPENGL_PLATFORM`` follows unless set. Call it before the first env renders
    (gymnasium reads ``MUJOCO_GL`` when it opens the renderer).

    :param environ: The environment to read and set (default: ``os.environ``)
    :param platform: ``sys.platform`` (default: this one)
    :param find_library: Finds a shared library by name (``ctypes.util.find_library``)
    :return: The backend chosen, or ``None`` when nothing was set (a display, ``MUJOCO_GL`` already set, or neither
        library found)
    """
    environ = os.environ if environ is None else environ
    if "MUJOCO_GL" in environ or has_display(environ, platform):
        return None
    for backend, library in HEADLESS_BACKENDS:
        if find_library(library):
            environ["MUJOCO_GL"] = backend
            environ.setdefault("PYOPENGL_PLATFORM", backend)
            return backend
    return None


def recording_backend() -> str | None:
    """How ``--record`` writes: ``"ffmpeg"`` (mp4), ``"pillow"`` (GIF), ``"matplotlib"`` (PNGs); ``None``: no way."""
    for backend, module, _ in RECORDING_BACKENDS:
        if importlib.util.find_spec(module) is not None and (module != "imageio_ffmpeg" or _has("imageio")):
            return backend
    return None


def _has(module: str) -> bool:
    return importlib.util.find_spec(module) is not None


class FrameWriter:
    """
    Writes rendered frames, one file (or PNG folder) per episode, ``<folder>/<stem>-episode-<k>.<ext>``: an mp4 is
    streamed to disk frame by frame, PNG frames are written one by one, a GIF is written when its episode ends (only
    that episode's frames are held). Files appear whole: each is written to a temporary name and renamed.

    :param backend: ``"ffmpeg"``, ``"pillow"`` or ``"matplotlib"`` (see :func:`recording_backend`)
    :param folder: Output folder (created)
    :param stem: File name stem
    :param fps: Frames per second of the videos
    """

    def __init__(self, backend: str, folder: str, stem: str, fps: float):
        if backend not in {name for name, _, _ in RECORDING_BACKENDS}:
            raise ValueError(f"Unknown recording backend {backend!r}: use one of {[b for b, _, _ in RECORDING_BACKENDS]}.")
        self.backend, self.folder, self.stem, self.fps = backend, folder, stem, float(fps)
        os.makedirs(folder, exist_ok=True)
        #: Files (or PNG folders) written so far
        self.paths: list[str] = []
        #: Frames written so far, over all episodes
        self.n_frames = 0
        self._episode = 0
        self._frames: list[Any] = []  # GIF: the current episode's frames, as palette images
        self._writer: Any = None  # mp4: the open ffmpeg writer
        self._episode_frames = 0

    def _episode_path(self, extension: str = "") -> str:
        return os.path.join(self.folder, f"{self.stem}-episode-{self._episode}{extension}")

    def append(self, frame: np.ndarray) -> None:
        """
        Write (or, for a GIF, keep) one frame of the current episode.

        :param frame: ``(height, width, 3)`` RGB, uint8
        """
        image = np.asarray(frame, dtype=np.uint8)
        if image.ndim != 3 or image.shape[-1] not in (3, 4):
            raise ValueError(f"Expected an RGB(A) frame of shape (height, width, 3), got shape {image.shape}.")
        if self.backend == "ffmpeg":
            if self._writer is None:
                import imageio

                self._temporary = os.path.join(self.folder, f".{self.stem}-episode-{self._episode}.tmp.mp4")
                self._writer = imageio.get_writer(self._temporary, fps=self.fps, macro_block_size=1)
            self._writer.append_data(image[..., :3])
        elif self.backend == "pillow":
            from PIL import Image

            self._frames.append(Image.fromarray(image[..., :3]).quantize(colors=256))
        else:
            import matplotlib.pyplot as plt

            folder = self._episode_path()
            os.makedirs(folder, exist_ok=True)
            path = os.path.join(folder, f"frame_{self._episode_frames:05d}.png")
            atomic_write(path, lambda file: plt.imsave(file, image, format="png"))  # type: ignore[arg-type]
            if self._episode_frames == 0:
                self.paths.append(folder)
        self._episode_frames += 1
        self.n_frames += 1

    def end_episode(self) -> None:
        """Close the current episode's file; the next frame starts a new one."""
        if self._episode_frames == 0:
            return
        if self.backend == "ffmpeg":
            self._writer.close()
            self._writer = None
            path = self._episode_path(".mp4")
            os.replace(self._temporary, path)
            self.paths.append(path)
        elif self.backend == "pillow":
            path = self._episode_path(".gif")
            first, *rest = self._frames
            options = dict(format="GIF", save_all=True, append_images=rest, duration=int(1000 / max(self.fps, 1)), loop=0)
            atomic_write(path, lambda file: first.save(file, **options))
            self.paths.append(path)
            self._frames = []
        self._episode += 1
        self._episode_frames = 0

    def close(self) -> list[str]:
        """
        Write the last (unfinished) episode's file.

        :return: The files and PNG folders written
        """
        self.end_episode()
        return self.paths
