"""A network camera for the tests: JPEG images served as MJPEG over HTTP (one
``multipart/x-mixed-replace`` response per client, as IP cameras do), from the standard
library's HTTP server on 127.0.0.1. It can be stopped (every connection closed, the port
freed) and started again on the same port, or frozen (connections kept open, nothing
sent), as a camera that is unplugged or hangs."""

from __future__ import annotations

import contextlib
import http.server
import threading
import time
from collections.abc import Iterator

BOUNDARY = b"ovisframe"


class _Handler(http.server.BaseHTTPRequestHandler):
    server: _Server

    def do_GET(self) -> None:
        self.send_response(200)
        self.send_header("Content-Type", f"multipart/x-mixed-replace; boundary={BOUNDARY.decode()}")
        self.send_header("Cache-Control", "no-cache")
        self.end_headers()
        camera = self.server.camera
        with contextlib.suppress(OSError):  # the client went away
            while camera.send_next(self.wfile):
                pass

    def log_message(self, format: str, *args: object) -> None:
        pass


class _Server(http.server.ThreadingHTTPServer):
    daemon_threads = True
    allow_reuse_address = True
    camera: MjpegCamera


class MjpegCamera:
    """Serves ``jpegs`` in a loop at ``fps`` on ``http://127.0.0.1:PORT/stream``."""

    def __init__(self, jpegs: list[bytes], port: int, fps: float = 20.0) -> None:
        self.jpegs = jpegs
        self.port = port
        self.period_s = 1.0 / fps
        self.url = f"http://127.0.0.1:{port}/stream"
        self.sent = 0  # frames sent, over every connection
        self._index = 0
        self._lock = threading.Lock()
        self._on = threading.Event()  # cleared: every connection ends
        self._flowing = threading.Event()  # cleared: frozen
        self._server: _Server | None = None
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        server = _Server(("127.0.0.1", self.port), _Handler)
        server.camera = self
        self._on.set()
        self._flowing.set()
        self._server = server
        self._thread = threading.Thread(target=server.serve_forever, daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Close every connection and free the port (a camera switched off)."""
        self._on.clear()
        self._flowing.set()  # wake frozen handlers so that they end
        if self._server is not None:
            self._server.shutdown()
            self._server.server_close()
            self._server = None
        if self._thread is not None:
            self._thread.join(5)
            self._thread = None

    def freeze(self) -> None:
        """Keep the connections open but send nothing (a camera that hangs)."""
        self._flowing.clear()

    def thaw(self) -> None:
        self._flowing.set()

    def send_next(self, out) -> bool:
        """Write the next part to ``out``; False when the camera is off."""
        self._flowing.wait()
        if not self._on.is_set():
            return False
        with self._lock:
            jpeg = self.jpegs[self._index % len(self.jpegs)]
            self._index += 1
            self.sent += 1
        head = b"--%s\r\nContent-Type: image/jpeg\r\nContent-Length: %d\r\n\r\n"
        out.write(head % (BOUNDARY, len(jpeg)) + jpeg + b"\r\n")
        out.flush()
        time.sleep(self.period_s)
        return self._on.is_set()


@contextlib.contextmanager
def mjpeg_camera(jpegs: list[bytes], port: int, fps: float = 20.0) -> Iterator[MjpegCamera]:
    """A started :class:`MjpegCamera`, stopped on exit."""
    camera = MjpegCamera(jpegs, port, fps)
    camera.start()
    try:
        yield camera
    finally:
        camera.stop()
