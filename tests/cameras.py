"""Cameras for the tests: an MJPEG camera on loopback that a test takes down and brings back,
and the demo cell's frames as JPEG."""

from __future__ import annotations

import http.server
import multiprocessing
import time

import cv2

from monitor.scene import DemoScene
from tests.helpers import free_port

FPS = 15  # the camera's frame rate


def _serve(frames: list[bytes], port: int, online, ready) -> None:
    """The camera's own process: the stream never waits for the test process's threads."""

    class Handler(http.server.BaseHTTPRequestHandler):
        def log_message(self, *args):
            pass

        def do_GET(self):
            if not online.is_set():
                self.send_error(503)
                return
            self.send_response(200)
            self.send_header("Content-Type", "multipart/x-mixed-replace; boundary=frame")
            self.end_headers()
            k = 0
            start = time.monotonic()
            try:
                while online.is_set():
                    jpeg = frames[k % len(frames)]
                    self.wfile.write(b"--frame\r\nContent-Type: image/jpeg\r\n"
                                     b"Content-Length: %d\r\n\r\n" % len(jpeg) + jpeg + b"\r\n")
                    k += 1
                    # on a fixed schedule, as a camera's sensor clock: a late frame on a loaded
                    # host is followed by the next one on time, not a whole period later
                    time.sleep(max(0.0, start + k / FPS - time.monotonic()))
            except OSError:  # the service closed the stream
                pass

    server = http.server.ThreadingHTTPServer(("127.0.0.1", port), Handler)
    server.daemon_threads = True
    ready.set()
    server.serve_forever()


class MjpegCamera:
    """An HTTP MJPEG camera (multipart/x-mixed-replace, 15 fps) on 127.0.0.1, in a process of
    its own (a busy test process must not starve the stream). ``online.clear()`` closes the
    open streams and answers new requests with 503 until ``online.set()``."""

    def __init__(self, frames: list[bytes]) -> None:
        ctx = multiprocessing.get_context("spawn")
        self.online = ctx.Event()
        self.online.set()
        self._ready = ctx.Event()
        port = free_port()
        self.url = f"http://127.0.0.1:{port}/cam.mjpg"
        self.process = ctx.Process(target=_serve, args=(frames, port, self.online, self._ready),
                                   daemon=True)

    def __enter__(self) -> MjpegCamera:
        self.process.start()
        if not self._ready.wait(30):
            raise RuntimeError("the MJPEG camera process did not start")
        return self

    def __exit__(self, *exc) -> None:
        self.online.clear()
        self.process.terminate()
        self.process.join(5)


def demo_jpegs(n: int = 10) -> list[bytes]:
    """The demo cell without anyone in it (a person enters later), at 640x360."""
    out = []
    for _, (img, truth) in zip(range(n), DemoScene().frames(), strict=False):
        assert not truth.persons
        out.append(cv2.imencode(".jpg", cv2.resize(img, (640, 360)))[1].tobytes())
    return out
