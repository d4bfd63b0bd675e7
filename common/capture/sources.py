"""Frame sources for the capture service: the simulated arena, a folder of images, a
video file, or a camera (OpenCV index or device path).

Every source returns uint8 frames (grey or BGR) one at a time; a source that cannot be
opened raises :class:`SourceError` with what to check, and the capture service retries.
"""

from __future__ import annotations

from pathlib import Path
from typing import Protocol

import cv2
import numpy as np
from numpy.typing import NDArray

from ovis.common.config import OvisConfig
from ovis.common.sim.arena import Arena, FrameTruth

__all__ = [
    "IMAGE_SUFFIXES",
    "CameraSource",
    "FolderSource",
    "FrameSource",
    "SimSource",
    "SourceError",
    "VideoSource",
    "open_source",
]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm")


class SourceError(RuntimeError):
    """A source that cannot deliver frames (missing camera, unreadable file, ended)."""


class FrameSource(Protocol):
    description: str

    def read(self) -> tuple[NDArray[np.uint8], FrameTruth | None]:
        """The next frame and, for simulated frames, its ground truth."""
        ...

    def close(self) -> None: ...


class SimSource:
    """The simulated arena: renders the current state, then advances one step.

    With ``prerender`` = N > 0 (default ``config.service.prerender``), the first N frames
    are rendered once, here, and then replayed in a loop, so that reading a frame costs
    nothing and the renderer cannot be the bottleneck of whatever consumes the frames.
    The frames are read-only arrays shared between loops.
    """

    def __init__(self, config: OvisConfig, seed: int, prerender: int | None = None) -> None:
        self.arena = Arena(config, seed)
        n = config.service.prerender if prerender is None else int(prerender)
        if n < 0:
            raise ValueError(f"prerender must be 0 (live) or a number of frames, got {n}")
        self._frames: list[tuple[NDArray[np.uint8], FrameTruth]] = []
        for _ in range(n):
            image, truth = self.arena.render()
            image.setflags(write=False)
            self._frames.append((image, truth))
            self.arena.step()
        self._next = 0
        replay = f", replaying {n} pre-rendered frames" if n else ""
        self.description = f"simulated arena (seed {seed}{replay})"

    def read(self) -> tuple[NDArray[np.uint8], FrameTruth | None]:
        if self._frames:
            frame = self._frames[self._next]
            self._next = (self._next + 1) % len(self._frames)
            return frame
        image, truth = self.arena.render()
        self.arena.step()
        return image, truth

    def close(self) -> None:
        pass


def _as_uint8(image: NDArray) -> NDArray[np.uint8]:
    if image.dtype == np.uint16:
        return (image >> 8).astype(np.uint8)
    return image


class FolderSource:
    """The images of a folder in name order, looping when ``loop`` is set."""

    def __init__(self, folder: Path, loop: bool = True) -> None:
        self.files = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        if not self.files:
            raise SourceError(f"folder {folder} holds no images ({', '.join(IMAGE_SUFFIXES)})")
        self.loop = loop
        self.index = 0
        self.description = f"folder {folder} ({len(self.files)} images)"

    def read(self) -> tuple[NDArray[np.uint8], FrameTruth | None]:
        if self.index >= len(self.files):
            if not self.loop:
                raise SourceError(f"{self.description}: all images sent")
            self.index = 0
        path = self.files[self.index]
        self.index += 1
        image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if image is None:
            raise SourceError(f"cannot read {path} as an image")
        return _as_uint8(image), None

    def close(self) -> None:
        pass


class _CaptureSource:
    def __init__(self, target: int | str, description: str, loop: bool) -> None:
        self.target = target
        self.loop = loop
        self.description = description
        self.cap = cv2.VideoCapture(target)
        if not self.cap.isOpened():
            raise SourceError(self._cannot_open())

    def _cannot_open(self) -> str:
        return f"cannot open {self.description}"

    def read(self) -> tuple[NDArray[np.uint8], FrameTruth | None]:
        ok, image = self.cap.read()
        if not ok and self.loop and isinstance(self.target, str):
            self.cap.set(cv2.CAP_PROP_POS_FRAMES, 0)
            ok, image = self.cap.read()
        if not ok or image is None:
            raise SourceError(f"{self.description} delivered no frame (ended or unplugged)")
        return _as_uint8(image), None

    def close(self) -> None:
        self.cap.release()


class VideoSource(_CaptureSource):
    """A video file, looping when ``loop`` is set."""

    def __init__(self, path: Path, loop: bool = True) -> None:
        super().__init__(str(path), f"video {path}", loop)


class CameraSource(_CaptureSource):
    """A camera by OpenCV index (``camera:0``) or device path (``/dev/video0``)."""

    def __init__(self, target: int | str) -> None:
        super().__init__(target, f"camera {target}", loop=False)

    def _cannot_open(self) -> str:
        return (
            f"cannot open camera {self.target}: check that it is connected, that no other "
            "program holds it, and the index/path (try `ls /dev/video*`)"
        )


def open_source(spec: str, config: OvisConfig, *, loop: bool | None = None) -> FrameSource:
    """Open ``spec``: "sim", "camera:N", a device path, a folder, or a video file.

    ``loop`` (default ``config.service.loop``): replay a folder or video when it ends."""
    loop = config.service.loop if loop is None else loop
    if spec == "sim":
        return SimSource(config, config.service.seed)
    if spec.startswith("camera:"):
        index = spec.split(":", 1)[1]
        if not index.isdigit():
            raise SourceError(f"camera index must be a number, as in camera:0, got {spec!r}")
        return CameraSource(int(index))
    if spec.startswith("/dev/"):
        return CameraSource(spec)
    path = Path(spec)
    if path.is_dir():
        return FolderSource(path, loop)
    if path.is_file():
        return VideoSource(path, loop)
    raise SourceError(
        f"source {spec!r} is not 'sim', 'camera:N', a device, a folder or a video file"
    )
