"""Cameras for the tests: an MJPEG camera on loopback that a test takes down and brings back,
and the demo cell's frames as JPEG."""

from __future__ import annotations

import http.server
import threading
import time

import cv2

from monitor.scene import DemoScene


class MjpegCamera:
    """An HTTP MJPEG camera (multipart/x-mixed-replace, 15 fps) on 127.0.0.1. ``down()`` closes
    the open streams and answers new requests with 503 until ``up()``."""

    def __init__(self, frames: list[bytes]) -> None:
        self.frames = frames
        self.online = threading.Event()
        self.online.set()
        camera = self

        class Handler(http.server.BaseHTTPRequestHandler):
            def log_message(self, *args):
                pass

            def do_GET(self):
                if not camera.online.is_set():
                    self.send_error(503)
                    return
                self.send_response(200)
                self.send_header("Content-Type", "multipart/x-mixed-replace; boundary=frame")
                self.end_headers()
                k = 0
                try:
                    while camera.online.is_set():
                        jpeg = camera.frames[k % len(camera.frames)]
                        self.wfile.write(b"--frame\r\nContent-Type: image/jpeg\r\n"
                                         b"Content-Length: %d\r\n\r\n" % len(jpeg) + jpeg
                                         + b"\r\n")
                        k += 1
                        time.sleep(1 / 15)
                except OSError:  # the service closed the stream
                    pass

        self.server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.server.daemon_threads = True
        self.url = f"http://127.0.0.1:{self.server.server_address[1]}/cam.mjpg"
        self.thread = threading.Thread(target=self.server.serve_forever, daemon=True)

    def __enter__(self) -> MjpegCamera:
        self.thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self.online.clear()
        self.server.shutdown()
        self.server.server_close()


def demo_jpegs(n: int = 10) -> list[bytes]:
    """The demo cell without anyone in it (a person enters later), at 640x360."""
    out = []
    for _, (img, truth) in zip(range(n), DemoScene().frames(), strict=False):
        assert not truth.persons
        out.append(cv2.imencode(".jpg", cv2.resize(img, (640, 360)))[1].tobytes())
    return out
