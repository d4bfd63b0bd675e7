"""Frame sources for the capture service: the simulated arena (the light simulator's, or
the physical world rendered live, :mod:`ovis.common.capture.physical`), a folder of
images, a video file, a camera (OpenCV index or device path) or a network stream (RTSP
or MJPEG over HTTP, through OpenCV's FFmpeg backend).

Every source returns uint8 frames (grey or BGR) one at a time; a source that cannot be
opened raises :class:`SourceError` with what to check, and the capture service retries.
A camera, stream or video file that stops delivering (unplugged, network lost, file
gone) raises :class:`SourceError` once and reconnects on a later read, when it is back;
a stream that hangs is given up after :data:`STREAM_READ_TIMEOUT_S`. A folder or video
that ends with looping off raises :class:`SourceEndedError`: it is lost for good.
"""

from __future__ import annotations

import os
import time
import urllib.parse
from collections.abc import Callable
from pathlib import Path

import cv2
import msgspec
import numpy as np
from numpy.typing import NDArray

from ovis.common.capture.frame_source import (
    FrameSource,
    NoFrameError,
    SourceEndedError,
    SourceError,
)
from ovis.common.config import OvisConfig
from ovis.common.sim.arena import Arena, FrameTruth
from ovis.common.vision.imageio import to_uint8

__all__ = [
    "IMAGE_SUFFIXES",
    "STREAM_OPEN_TIMEOUT_S",
    "STREAM_READ_TIMEOUT_S",
    "CameraSource",
    "FolderSource",
    "FrameSource",
    "GridSource",
    "NoFrameError",
    "SimSource",
    "SourceEndedError",
    "SourceError",
    "StreamSource",
    "VideoSource",
    "capture_settings",
    "open_source",
]

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm")


#: Seconds a network stream may take to answer when it is opened …
STREAM_OPEN_TIMEOUT_S = 3.0
#: … and to deliver each frame, before it counts as lost.
STREAM_READ_TIMEOUT_S = 1.0


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


def physical_source(config: OvisConfig) -> FrameSource:
    """The physical world rendered live (:mod:`ovis.common.capture.physical`), or a
    :class:`SourceError` saying why it cannot be (no off-screen OpenGL, no room)."""
    from ovis.common.physical.availability import why_unavailable

    why = why_unavailable()
    if why is not None:
        raise SourceError(f"the physical world cannot render here: {why}")
    from ovis.common.capture.physical import PhysicalSource

    try:
        return PhysicalSource(config, config.service.seed)
    except ValueError as exc:
        raise SourceError(f"the physical world: {exc}") from None


def physical_grid_camera(config: OvisConfig, nx: int, ny: int, name: str):
    """Camera ``name`` of the grid over the physical world
    (:mod:`ovis.common.physical.grid`), or a :class:`SourceError` saying why it cannot
    render."""
    from ovis.common.physical.availability import why_unavailable

    why = why_unavailable()
    if why is not None:
        raise SourceError(f"the physical world cannot render here: {why}")
    from ovis.common.physical.grid import PhysicalGridCamera

    return PhysicalGridCamera(config, nx, ny, name, config.service.seed)


def grid_cache_dir() -> Path:
    """Where the simulated grid's prerendered frames are kept between runs:
    ``$OVIS_CACHE`` or ``$XDG_CACHE_HOME/ovis`` (default ``~/.cache/ovis``), ``grid/``."""
    root = (
        os.environ.get("OVIS_CACHE")
        or Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "ovis"
    )
    return Path(root) / "grid"


class GridSource:
    """Camera ``name`` of the simulated camera grid (``grid:2x2:cam01``,
    :mod:`ovis.common.sim.gridview`): one period of the shared periodic scene rendered
    once (``progress(done, total)`` meanwhile), then replayed on a trigger shared by
    every camera of the grid, even in other processes: at ``fps`` a read waits for the
    next multiple of 1/fps of the wall clock and shows the scene frame of that instant
    (its index modulo the period), stamped with it. So all the grid's cameras expose
    the same instant with the same stamp, as cameras on one hardware trigger do (on
    several hosts: as well as their clocks agree)."""

    def __init__(
        self,
        config: OvisConfig,
        spec: str,
        progress: Callable[[int, int], None] | None = None,
    ) -> None:
        from ovis.common.sim.gridview import GridCamera, parse_grid_source

        physical = config.simulator.world == "physical"
        try:
            nx, ny, name = parse_grid_source(spec)
            if physical:
                camera = physical_grid_camera(config, nx, ny, name)
            else:
                camera = GridCamera(config, nx, ny, name, config.service.seed)
        except ValueError as exc:
            raise SourceError(str(exc)) from None
        self._frames = camera.render_period(progress, grid_cache_dir())
        fps = config.service.fps
        self._period_ns = round(1e9 / fps) if fps > 0 else 0
        self._next = 0  # frame index when running free (fps 0)
        world = "the physical world, " if physical else ""
        self.description = (
            f"simulated camera {name} of a {nx}x{ny} grid ({world}seed {config.service.seed}, "
            f"{len(self._frames)} frames looped)"
        )

    def read(self) -> tuple[NDArray[np.uint8], FrameTruth | None]:
        if not self._period_ns:
            image, truth = self._frames[self._next % len(self._frames)]
            self._next += 1
            return image, truth
        tick = -(-time.time_ns() // self._period_ns)  # the next trigger
        stamp = tick * self._period_ns
        time.sleep(max(0.0, (stamp - time.time_ns()) / 1e9))
        image, truth = self._frames[tick % len(self._frames)]
        return image, msgspec.structs.replace(truth, stamp_ns=stamp)

    def close(self) -> None:
        pass


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
                raise SourceEndedError(f"ended: {self.description}: all images sent (loop is off)")
            self.index = 0
        path = self.files[self.index]
        self.index += 1
        image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if image is None:
            raise SourceError(f"cannot read {path} as an image")
        return to_uint8(image), None

    def close(self) -> None:
        pass


class _CaptureSource:
    """An OpenCV ``VideoCapture`` that reconnects: after a failed read the next read
    reopens the target (raising :class:`SourceError` while it is still missing)."""

    def __init__(
        self,
        target: int | str,
        description: str,
        loop: bool,
        settings: dict[int, float] | None = None,
    ) -> None:
        self.target = target
        self.loop = loop
        self.description = description
        self.settings = settings or {}
        self.cap: cv2.VideoCapture | None = None
        self._open()

    def _capture(self) -> cv2.VideoCapture:
        """A new ``VideoCapture`` of the target."""
        return cv2.VideoCapture(self.target)

    def _open(self) -> None:
        cap = self._capture()
        if not cap.isOpened():
            cap.release()
            raise SourceError(self._cannot_open())
        for prop, value in self.settings.items():
            cap.set(prop, value)
        self.cap = cap

    def _cannot_open(self) -> str:
        return f"cannot open {self.description}"

    def read(self) -> tuple[NDArray[np.uint8], FrameTruth | None]:
        if self.cap is None:
            self._open()  # reconnect (SourceError while the device is still away)
        assert self.cap is not None
        ok, image = self.cap.read()
        if not ok and self.loop and isinstance(self.target, str):
            self.cap.set(cv2.CAP_PROP_POS_FRAMES, 0)
            ok, image = self.cap.read()
        if not ok or image is None:
            self.close()
            raise self._no_frame()
        return to_uint8(image), None

    def _no_frame(self) -> SourceError:
        """Why a read gave no frame."""
        return SourceError(
            f"{self.description} delivered no frame (unplugged or disconnected); reconnecting"
        )

    def close(self) -> None:
        if self.cap is not None:
            self.cap.release()
            self.cap = None


class VideoSource(_CaptureSource):
    """A video file, looping when ``loop`` is set."""

    def __init__(self, path: Path, loop: bool = True) -> None:
        super().__init__(str(path), f"video {path}", loop)

    def _no_frame(self) -> SourceError:
        if not self.loop and Path(str(self.target)).is_file():
            return SourceEndedError(f"ended: {self.description}: all frames sent (loop is off)")
        return SourceError(f"{self.description} delivered no frame (file gone?); reconnecting")


class CameraSource(_CaptureSource):
    """A camera by OpenCV index (``camera:0``) or device path (``/dev/video0``), with
    optional width, height, fps and exposure (OpenCV capture properties)."""

    def __init__(self, target: int | str, settings: dict[int, float] | None = None) -> None:
        super().__init__(target, f"camera {target}", loop=False, settings=settings)

    def _cannot_open(self) -> str:
        return (
            f"cannot open camera {self.target}: check that it is connected, that no other "
            "program holds it, and the index/path (try `ls /dev/video*`)"
        )


class StreamSource(_CaptureSource):
    """A network stream (RTSP, MJPEG over HTTP/HTTPS, …) read by OpenCV's FFmpeg
    backend, which gives up on a stream that does not answer within
    :data:`STREAM_OPEN_TIMEOUT_S` or stops delivering for :data:`STREAM_READ_TIMEOUT_S`.
    A password in the URL is kept out of the description (logs, status, health)."""

    def __init__(self, url: str, settings: dict[int, float] | None = None) -> None:
        super().__init__(url, f"stream {without_password(url)}", loop=False, settings=settings)

    def _capture(self) -> cv2.VideoCapture:
        timeouts = [
            cv2.CAP_PROP_OPEN_TIMEOUT_MSEC,
            round(STREAM_OPEN_TIMEOUT_S * 1000),
            cv2.CAP_PROP_READ_TIMEOUT_MSEC,
            round(STREAM_READ_TIMEOUT_S * 1000),
        ]
        return cv2.VideoCapture(str(self.target), cv2.CAP_FFMPEG, timeouts)

    def _cannot_open(self) -> str:
        return (
            f"cannot open {self.description}: check the URL, that the camera is on the "
            "network and answers within "
            f"{STREAM_OPEN_TIMEOUT_S:g} s, and that this build of OpenCV has FFmpeg"
        )

    def _no_frame(self) -> SourceError:
        return SourceError(
            f"{self.description} delivered no frame for {STREAM_READ_TIMEOUT_S:g} s or "
            "closed (camera off, network down); reconnecting"
        )


def without_password(url: str) -> str:
    """``url`` with the password of its ``user:password@`` part replaced by ``***``."""
    parts = urllib.parse.urlsplit(url)
    if parts.password is None:
        return url
    host = parts.netloc.rsplit("@", 1)[1]
    return urllib.parse.urlunsplit(parts._replace(netloc=f"{parts.username}:***@{host}"))


STREAM_SCHEMES = ("rtsp://", "rtsps://", "http://", "https://")


def capture_settings(config: OvisConfig) -> dict[int, float]:
    """The OpenCV capture properties asked for by ``[service] camera_*``."""
    s = config.service
    props = {
        cv2.CAP_PROP_FRAME_WIDTH: s.camera_width,
        cv2.CAP_PROP_FRAME_HEIGHT: s.camera_height,
        cv2.CAP_PROP_FPS: s.camera_fps,
    }
    out = {k: float(v) for k, v in props.items() if v is not None}
    if s.camera_exposure is not None:
        out[cv2.CAP_PROP_AUTO_EXPOSURE] = 1.0  # V4L2: manual exposure
        out[cv2.CAP_PROP_EXPOSURE] = float(s.camera_exposure)
    return out


def open_source(
    spec: str,
    config: OvisConfig,
    *,
    loop: bool | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> FrameSource:
    """Open ``spec``: "sim", "grid:NxM:camIJ", "camera:N", a device path, a stream URL
    (``rtsp://``, ``rtsps://``, ``http://``, ``https://``), a folder, or a video file.

    ``loop`` (default ``config.service.loop``): replay a folder or video when it ends;
    ``progress(done, total)``: called while a simulated grid camera prerenders."""
    loop = config.service.loop if loop is None else loop
    if spec == "sim" and config.simulator.world == "physical":
        return physical_source(config)
    if spec == "sim":
        return SimSource(config, config.service.seed)
    if spec.startswith("grid:"):
        return GridSource(config, spec, progress)
    if spec.startswith("camera:"):
        index = spec.split(":", 1)[1]
        if not index.isdigit():
            raise SourceError(f"camera index must be a number, as in camera:0, got {spec!r}")
        return CameraSource(int(index), capture_settings(config))
    if spec.startswith("/dev/"):
        return CameraSource(spec, capture_settings(config))
    if spec.lower().startswith(STREAM_SCHEMES):
        return StreamSource(spec, capture_settings(config))
    path = Path(spec)
    if path.is_dir():
        return FolderSource(path, loop)
    if path.is_file():
        return VideoSource(path, loop)
    raise SourceError(
        f"source {spec!r} is not 'sim', 'grid:2x2:cam00', 'camera:N', a device, a stream "
        "URL, a folder or an existing video file"
    )
