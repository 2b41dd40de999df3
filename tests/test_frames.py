"""Frame sources on real files, real HTTP on loopback, and the grabber on real threads."""

from __future__ import annotations

import functools
import http.server
import socket
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from monitor.errors import InputError
from monitor.frames import (
    Backoff,
    Frame,
    FrameSource,
    ImageSource,
    LatestFrameGrabber,
    PacedSource,
    SyntheticSource,
    TruncatedVideoError,
    VideoFileReader,
    check_frame_size,
    frame_time_s,
    open_source,
    redact_url,
    source_kind,
)
from monitor.scene import DemoScene
from monitor.types import FrameInfo
from tests.helpers import assert_one_line, wait_for
from tests.videos import faststart

W, H = 160, 120


# --- factories ----------------------------------------------------------------------------------

def numbered(i: int, size: tuple[int, int] = (W, H)) -> np.ndarray:
    """A frame whose mean brightness tells its index (survives lossy coding)."""
    img = np.full((size[1], size[0], 3), (i * 10) % 256, np.uint8)
    return img


def write_video(path: Path, n: int, fps: float = 10.0, fourcc: str = "mp4v",
                size: tuple[int, int] = (W, H)) -> Path:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), fps, size)
    if not writer.isOpened():
        raise RuntimeError(f"cannot write {path}")
    for i in range(n):
        writer.write(numbered(i, size))
    writer.release()
    return path








# --- pure helpers -------------------------------------------------------------------------------

@pytest.mark.parametrize(("spec", "kind"), [
    pytest.param(0, "camera", id="int"),
    pytest.param("2", "camera", id="digit-string"),
    pytest.param("rtsp://user:pw@10.0.0.5:554/stream", "url", id="rtsp"),
    pytest.param("http://127.0.0.1:8080/video.mjpg", "url", id="http"),
    pytest.param("synthetic:demo", "synthetic", id="synthetic"),
    pytest.param("cell.mp4", "file", id="video"),
    pytest.param("still.PNG", "image", id="image"),
])
def test_source_kind(spec, kind):
    assert source_kind(spec) == kind


def test_redact_url_hides_the_password_only():
    assert redact_url("rtsp://op:secret@10.0.0.5:554/s") == "rtsp://op:***@10.0.0.5:554/s"
    assert redact_url("http://10.0.0.5/s") == "http://10.0.0.5/s"


def test_frame_time_prefers_container_timestamps_and_falls_back_to_index_over_fps():
    assert frame_time_s(0.0, 0, 10.0, None) == 0.0
    assert frame_time_s(250.0, 3, 10.0, 0.2) == 0.25
    assert frame_time_s(0.0, 3, 10.0, 0.2) == pytest.approx(0.3)  # missing: index / fps
    assert frame_time_s(float("nan"), 4, 10.0, 0.3) == pytest.approx(0.4)
    assert frame_time_s(100.0, 4, 10.0, 0.3) == pytest.approx(0.4)  # not after previous
    with pytest.raises(InputError):
        frame_time_s(0.0, 2, None, 0.1)


def test_backoff_grows_exponentially_and_is_bounded():
    b = Backoff(initial_s=0.1, max_s=1.0, factor=2.0)
    assert [b.delay(k) for k in range(6)] == pytest.approx([0.1, 0.2, 0.4, 0.8, 1.0, 1.0])
    assert b.delay(10_000) == 1.0
    with pytest.raises(ValueError):
        Backoff(initial_s=2.0, max_s=1.0)


def test_check_frame_size_message():
    check_frame_size(W, H, (W, H), "x")
    check_frame_size(W, H, None, "x")
    with pytest.raises(InputError) as err:
        check_frame_size(640, 480, (1280, 720), "cam0")
    assert_one_line(err.value, "cam0", "640x480", "1280x720")


# --- video files --------------------------------------------------------------------------------

def test_video_reader_gives_the_videos_own_timestamps(tmp_path):
    path = write_video(tmp_path / "v.mp4", 20, fps=10.0)
    with VideoFileReader(path, "cam0") as reader:
        assert (reader.fps, reader.frame_count, reader.width, reader.height) == (10.0, 20, W, H)
        frames = list(reader)
    assert len(frames) == 20
    assert [f.info.seq for f in frames] == list(range(20))
    assert [f.info.capture_time for f in frames] == pytest.approx([i / 10 for i in range(20)])
    assert all(f.info.camera_id == "cam0" and (f.info.width, f.info.height) == (W, H)
               for f in frames)
    assert all(f.image.shape == (H, W, 3) and f.image.dtype == np.uint8 for f in frames)
    brightness = [float(f.image.mean()) for f in frames]
    assert brightness == pytest.approx([(i * 10) % 256 for i in range(20)], abs=5)
    assert reader.truncation is None


def test_video_reader_loop_keeps_time_increasing(tmp_path):
    path = write_video(tmp_path / "v.avi", 5, fps=10.0, fourcc="MJPG")
    reader = VideoFileReader(path, "cam0", loop=True)
    reader.open()
    times = [reader.read().info.capture_time for _ in range(12)]
    reader.close()
    assert times == pytest.approx([i / 10 for i in range(12)])


def _text_as_mp4(tmp_path: Path) -> Path:
    path = tmp_path / "notes.mp4"
    path.write_text("this is not a video\n" * 20)
    return path


def _zero_frames(suffix: str, fourcc: str):
    def make(tmp_path: Path) -> Path:
        return write_video(tmp_path / f"empty{suffix}", 0, fourcc=fourcc)
    return make


def _cut_mp4_without_index(tmp_path: Path) -> Path:
    """The common real truncation: the writer died before writing 'moov' at the end."""
    path = write_video(tmp_path / "cut.mp4", 30)
    data = path.read_bytes()
    path.write_bytes(data[:len(data) // 2])
    return path


@pytest.mark.parametrize(("make", "needle"), [
    pytest.param(lambda p: p / "missing.mp4", "no such file", id="missing"),
    pytest.param(lambda p: p, "directory", id="directory"),
    pytest.param(_text_as_mp4, "not a video", id="text-renamed-mp4"),
    pytest.param(_zero_frames(".mp4", "mp4v"), "no frames", id="zero-frames-mp4"),
    pytest.param(_zero_frames(".avi", "MJPG"), "no frames", id="zero-frames-avi"),
    pytest.param(_cut_mp4_without_index, "truncated", id="cut-before-index"),
])
def test_bad_video_gives_one_line_input_error(tmp_path, make, needle):
    path = make(tmp_path)
    with pytest.raises(InputError) as err:
        VideoFileReader(path).open()
    assert_one_line(err.value, str(path), needle)


def test_frame_size_mismatch_is_refused_at_open(tmp_path):
    path = write_video(tmp_path / "v.mp4", 3)
    with pytest.raises(InputError) as err:
        VideoFileReader(path, expected_size=(1280, 720)).open()
    assert_one_line(err.value, str(path), f"{W}x{H}", "1280x720")
    with VideoFileReader(path, expected_size=(W, H)) as reader:
        assert len(list(reader)) == 3


def _truncated_mp4(tmp_path: Path) -> Path:
    path = faststart(write_video(tmp_path / "cut.mp4", 30, fps=10.0))
    data = path.read_bytes()
    path.write_bytes(data[:int(len(data) * 0.6)])
    return path


def test_truncated_video_yields_frames_then_says_where_it_broke(tmp_path):
    path = _truncated_mp4(tmp_path)
    seen: list[Frame] = []
    with pytest.raises(TruncatedVideoError) as err, VideoFileReader(path, "cam0") as reader:
        for frame in reader:
            seen.append(frame)  # the caller processes every readable frame first
    assert 0 < len(seen) < 30
    exc = err.value
    assert isinstance(exc, InputError)
    assert (exc.frame_index, exc.frames_expected) == (len(seen), 30)
    assert exc.time_s == pytest.approx(len(seen) / 10)
    assert_one_line(exc, str(path), "truncated", f"frame {len(seen)}", f"t={len(seen) / 10:.3f} s")
    assert [f.info.capture_time for f in seen] == pytest.approx([i / 10 for i in range(len(seen))])


def test_truncated_video_non_strict_ends_and_reports(tmp_path):
    path = _truncated_mp4(tmp_path)
    with VideoFileReader(path, strict=False) as reader:
        n = sum(1 for _ in reader)
    assert reader.truncation is not None and reader.truncation.frame_index == n
    assert 0 < n < 30


# --- other sources ------------------------------------------------------------------------------

def test_synthetic_demo_source_plays_the_scene_with_its_time():
    source = open_source("synthetic:demo", "cam0", realtime=False)
    frames = [source.read() for _ in range(3)]
    source.close()
    assert [f.info.capture_time for f in frames] == pytest.approx([0, 1 / 15, 2 / 15])
    assert all(f.image.shape == (720, 1280, 3) and f.info.camera_id == "cam0" for f in frames)


def test_synthetic_source_loops_forever_when_asked():
    scene = DemoScene(duration_s=0.2, fps=10.0)  # 2 frames
    source = SyntheticSource(scene, "cam0", loop=True)
    source.open()
    times = [source.read().info.capture_time for _ in range(5)]
    assert times == pytest.approx([0.0, 0.1, 0.2, 0.3, 0.4])
    assert source.last_truth is not None


def test_unknown_synthetic_scene_and_missing_camera_are_one_line_errors():
    with pytest.raises(InputError) as err:
        open_source("synthetic:nope", "cam0")
    assert_one_line(err.value, "nope", "demo")
    with pytest.raises(InputError) as err:
        open_source(97, "cam9")
    assert_one_line(err.value, "camera 97", "cannot open")


def test_image_source_repeats_a_still_when_looping(tmp_path):
    path = tmp_path / "still.png"
    cv2.imwrite(str(path), numbered(5))
    source = open_source(str(path), "cam0", realtime=False)
    assert isinstance(source, ImageSource) and source.read() is not None
    assert source.read() is None  # once without loop
    looping = ImageSource(path, "cam0", fps=4.0, loop=True)
    looping.open()
    assert [looping.read().info.capture_time for _ in range(3)] == [0.0, 0.25, 0.5]
    (tmp_path / "bad.png").write_text("no image")
    with pytest.raises(InputError) as err:
        open_source(str(tmp_path / "bad.png"), "cam0")
    assert_one_line(err.value, "bad.png", "not a readable image")


@pytest.fixture
def http_dir(tmp_path):
    """A real HTTP server on 127.0.0.1 serving tmp_path."""
    class Quiet(http.server.SimpleHTTPRequestHandler):
        def log_message(self, *args):
            pass

    server = http.server.ThreadingHTTPServer(
        ("127.0.0.1", 0), functools.partial(Quiet, directory=str(tmp_path)))
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{server.server_address[1]}", tmp_path
    server.shutdown()
    server.server_close()
    thread.join(2)


def test_http_url_source_reads_frames_and_reports_loss(http_dir):
    base, root = http_dir
    write_video(root / "cam.mp4", 4)
    source = open_source(f"{base}/cam.mp4", "cam0", realtime=False)
    frames = [source.read() for _ in range(4)]
    assert all(f.image.shape == (H, W, 3) for f in frames)
    with pytest.raises(InputError) as err:  # the stream ran out: for a live source that is loss
        source.read()
    assert_one_line(err.value, "cam.mp4", "stream lost")
    source.close()


def test_unreachable_url_is_a_one_line_error_without_the_password():
    port = closed_port()
    with pytest.raises(InputError) as err:
        open_source(f"rtsp://op:secret@127.0.0.1:{port}/s", "cam0")
    assert_one_line(err.value, "cannot open stream", "op:***@")
    assert "secret" not in str(err.value)


def closed_port() -> int:
    """A loopback port nothing listens on (bound, then released)."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def test_paced_source_waits_for_the_video_time():
    clock = [100.0]
    sleeps: list[float] = []

    def sleep(s: float) -> None:
        sleeps.append(s)
        clock[0] += s

    scene = DemoScene(duration_s=0.4, fps=10.0)
    paced = PacedSource(SyntheticSource(scene, "cam0"), clock=lambda: clock[0], sleep=sleep,
                        speed=2.0)
    paced.open()
    got = [paced.read() for _ in range(4)]
    assert [f.info.capture_time for f in got] == pytest.approx([0, 0.1, 0.2, 0.3])
    assert sleeps == pytest.approx([0.05, 0.05, 0.05])  # half the frame interval at speed 2
    assert paced.read() is None


# --- grabber ------------------------------------------------------------------------------------

class GatedSource(FrameSource):
    """A source of our protocol whose frames the test releases one by one. It fails (raises
    InputError) after ``fail_after`` frames, and cannot be reopened while ``down`` is set."""

    def __init__(self, size=(W, H), fail_after: int | None = None):
        self.camera_id = "cam0"
        self.description = "gated test source"
        self.fps = None
        self.size = size
        self.fail_after = fail_after
        self.gate = threading.Semaphore(0)
        self.down = threading.Event()
        self.stop = threading.Event()  # shared with the grabber: a read returns within 20 ms
        self.opens = 0
        self.served = 0
        self._open = False

    @property
    def is_open(self) -> bool:
        return self._open

    def open(self) -> None:
        self.opens += 1
        if self.down.is_set():
            raise InputError("gated test source: camera gone")
        self._open = True

    def read(self) -> Frame | None:
        while not self.gate.acquire(timeout=0.02):
            if self.stop.is_set():
                raise InputError("gated test source: stopped")
        if self.fail_after is not None and self.served == self.fail_after:
            self.fail_after = None
            self.down.set()
            raise InputError("gated test source: read failed")
        self.served += 1
        img = numbered(self.served, self.size)
        return Frame(img, FrameInfo("cam0", self.served - 1, 0.0, self.size[0], self.size[1]))

    def close(self) -> None:
        self._open = False


def test_grabber_hands_out_the_newest_frame_and_counts_dropped():
    ticks = iter(range(1000, 2000))
    source = GatedSource()
    with LatestFrameGrabber(source, stop=source.stop,
                            clock=lambda: float(next(ticks))) as grabber:
        for _ in range(5):
            source.gate.release()
        assert wait_for(lambda: grabber.grabbed == 5)
        frame = grabber.get(timeout=1)
        assert frame.info.seq == 4 and frame.info.capture_time == 1004.0
        assert frame.image.mean() == pytest.approx(50)  # the 5th frame served
        assert grabber.dropped == 4 and grabber.last_frame_time == 1004.0
        assert grabber.get(timeout=0.05) is None  # no frame is handed out twice
        source.gate.release()
        frame = grabber.get(timeout=2)
        assert frame.info.seq == 5 and grabber.dropped == 4
        status = grabber.status()
        assert status.connected and status.grabbed == 6 and status.losses == 0


def test_grabber_reconnects_with_backoff_after_a_loss_and_reports_it():
    source = GatedSource(fail_after=2)
    stop = source.stop
    grabber = LatestFrameGrabber(source, stop=stop, backoff=Backoff(0.01, 0.05)).start()
    try:
        for _ in range(3):
            source.gate.release()
        assert wait_for(lambda: grabber.losses == 1)
        assert not grabber.connected
        assert grabber.last_error == "gated test source: read failed"
        assert wait_for(lambda: source.opens >= 4)  # retried while the camera is gone
        assert grabber.last_error == "gated test source: camera gone"
        assert grabber.reconnects == 0 and grabber.losses == 1  # one loss episode
        assert grabber.get(timeout=0.5).info.seq == 1  # newest before the loss, stamped then
        assert grabber.get(timeout=0.05) is None
        source.down.clear()  # the camera is back
        source.gate.release()
        frame = grabber.get(timeout=3)
        assert frame is not None and frame.info.seq == 2  # seq continues across reconnects
        assert grabber.connected and grabber.reconnects == 1 and grabber.losses == 1
    finally:
        assert grabber.stop(timeout=2)
    assert stop.is_set() and not grabber.connected


def test_grabber_refuses_frames_of_the_wrong_size():
    source = GatedSource(size=(32, 24))
    with LatestFrameGrabber(source, stop=source.stop, expected_size=(W, H),
                            backoff=Backoff(0.01, 0.02)) as grabber:
        source.gate.release()
        assert wait_for(lambda: grabber.losses == 1)
        assert grabber.get(timeout=0.05) is None and not grabber.connected
        assert_one_line(grabber.last_error, "32x24", f"{W}x{H}")


def test_grabber_plays_a_file_to_its_end(tmp_path):
    path = write_video(tmp_path / "v.mp4", 5)
    source = open_source(str(path), "cam0", realtime=False)
    grabber = LatestFrameGrabber(source).start()
    assert wait_for(lambda: grabber.ended)
    assert grabber.join(2) and grabber.grabbed == 5 and not grabber.connected
    last = grabber.get(timeout=0.1)
    assert last is not None and last.info.seq == 4  # the last frame is still handed out
    assert grabber.get(timeout=0.1) is None
    assert "end of stream" in grabber.last_error


def test_grabber_with_paced_synthetic_source_stamps_monotonic_time():
    stop = threading.Event()
    source = open_source("synthetic:demo", "cam0", realtime=True, stop=stop)
    with LatestFrameGrabber(source, stop=stop) as grabber:
        before = time.monotonic()
        frames = [grabber.get(timeout=2) for _ in range(3)]
    assert all(f is not None for f in frames)
    times = [f.info.capture_time for f in frames]
    assert times == sorted(times) and times[0] >= before - 0.2
    assert [f.info.seq for f in frames] == sorted(f.info.seq for f in frames)


def test_stop_is_bounded_while_waiting_for_a_long_backoff():
    source = GatedSource()
    source.down.set()  # never opens: the grabber waits 30 s between tries
    grabber = LatestFrameGrabber(source, stop=source.stop, backoff=Backoff(30.0, 60.0)).start()
    assert wait_for(lambda: source.opens == 1)
    t0 = time.monotonic()
    assert grabber.stop(timeout=2)
    assert time.monotonic() - t0 < 2
    assert grabber.get(timeout=0.1) is None and "camera gone" in grabber.last_error


def test_stop_is_bounded_when_a_read_hangs():
    release = threading.Event()

    class Hanging(GatedSource):
        def read(self):
            release.wait(10)  # a driver call that does not return
            return None

    grabber = LatestFrameGrabber(Hanging()).start()
    time.sleep(0.05)
    t0 = time.monotonic()
    assert not grabber.stop(timeout=0.2)  # reports that the thread is still in the read
    assert time.monotonic() - t0 < 1.5
    release.set()
    assert grabber.join(2)
