"""`commission walk --record` (issue 47): the reader never encodes (frames go to a writer
thread), so a walk recorded from an HTTP camera on a loaded host keeps its frames; a recording
with too many repeated or missing slots is refused with the measured figures."""

from __future__ import annotations

import multiprocessing as mp
import os
import threading
from pathlib import Path

import cv2
import numpy as np
import pytest

from monitor.cli import main
from monitor.commission.recording import MAX_MISSING, Recorded, check, record_walk
from monitor.errors import InputError
from monitor.frames import SourceOptions, open_source
from monitor.frames.base import Frame
from monitor.scene import DemoScene
from monitor.types import FrameInfo
from tests.cameras import MjpegCamera

LOAD = 8  # the trial's "load 8 on 2 cores": busy processes added until the load is this


def _spin(stop) -> None:
    while not stop.is_set():
        sum(range(10_000))


def test_a_recording_of_repeated_frames_is_refused_with_its_figures():
    # the trial's walk: 7 distinct frames of 400 at 10 fps, the stream gave 9.6 fps
    rec = Recorded(Path("walk.mp4"), 400, 393, 0, "H.264", slots=400, camera_frames=385,
                   camera_fps=9.6, reader_waited_s=0.0)
    with pytest.raises(InputError) as err:
        check(rec, 10.0)
    text = str(err.value)
    assert "recording refused: 393 of 400 slots repeated or missing (98 % > 5 %" in text
    assert "7 distinct frames" in text and "the camera gave 9.6 fps against --fps 10" in text
    assert "record at --fps 8 or less" in text and "\n" not in text
    check(Recorded(Path("w.mp4"), 400, 20, 0, "", slots=400, camera_fps=10.0), 10.0)  # 5 %
    cut = Recorded(Path("w.mp4"), 300, 0, 0, "", slots=400, camera_fps=10.0)  # ended early
    with pytest.raises(InputError, match="100 of 400 slots repeated or missing"):
        check(cut, 10.0)
    assert MAX_MISSING == 0.05


class _ArrivalSource:
    """A camera whose frames arrive at the given times (an HTTP camera on a loaded host: two
    frames in one 100 ms slot, then none in the next), each frame a flat grey of its own."""

    description = "the jittered camera"

    def __init__(self, times: list[float]) -> None:
        self.frames = [Frame(np.full((72, 128, 3), 40 + 40 * k, np.uint8),
                             FrameInfo("cam0", k, t, 128, 72)) for k, t in enumerate(times)]

    def read(self) -> Frame | None:
        return self.frames.pop(0) if self.frames else None


def test_a_frame_that_came_early_fills_the_empty_slot_after_it_as_a_distinct_frame(tmp_path):
    """Frames 0 and 1 share slot 0, slot 1 gets none, frame 2 comes in slot 2: frame 1 fills
    slot 1 (at most one slot late); the recording has 4 distinct frames of 4 slots and is not
    refused (before, slot 1 counted as a repeated slot: 25 % missing, refused)."""
    rec = record_walk(_ArrivalSource([0.0, 0.05, 0.21, 0.25, 0.31]), tmp_path / "w.mp4", 0.4,
                      10.0)
    assert (rec.frames, rec.repeated, rec.dropped, rec.camera_frames) == (4, 0, 1, 5), rec
    check(rec, 10.0)
    cap = cv2.VideoCapture(str(tmp_path / "w.mp4"))
    greys = []
    while (got := cap.read())[0]:
        greys.append(round(float(got[1].mean()) / 40) * 40)
    cap.release()
    assert greys == [40, 80, 120, 200], greys  # frames 0, 1, 2, 4 (3 came early, no gap after)


def _jpegs(n: int = 10) -> list[bytes]:
    """The demo cell at 1280x720 (the trial's cameras): a frame the encoder needs time for."""
    out = []
    for _, (img, _truth) in zip(range(n), DemoScene().frames(), strict=False):
        out.append(cv2.imencode(".jpg", cv2.resize(img, (1280, 720)))[1].tobytes())
    return out


@pytest.mark.slow
def test_a_walk_recorded_from_an_http_camera_at_load_keeps_its_frames(tmp_path):
    ctx = mp.get_context("spawn")
    stop = ctx.Event()
    # a shared CI host may be there already: add only what is missing to a load of LOAD
    missing = max(0, LOAD - int(os.getloadavg()[0]))
    hogs = [ctx.Process(target=_spin, args=(stop,), daemon=True) for _ in range(missing)]
    with MjpegCamera(_jpegs()) as camera:
        for h in hogs:
            h.start()
        try:
            source = open_source(camera.url, "cam0", options=SourceOptions(),
                                 stop=threading.Event())
            try:
                rec = record_walk(source, tmp_path / "walk.mp4", 8.0, 10.0)
            finally:
                source.close()
            load = os.getloadavg()[0]
        finally:
            stop.set()
            for h in hogs:
                h.join(10)
    figures = f"{rec.to_dict()}, load {load:.1f} ({missing} busy processes added)"
    assert rec.slots == 80 and rec.frames == 80, figures
    assert rec.reader_waited_s == 0, figures  # the reader never waited for the encoder
    assert rec.distinct_share >= 0.95, figures
    check(rec, 10.0)  # not refused
    cap = cv2.VideoCapture(str(tmp_path / "walk.mp4"))
    n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    cap.release()
    assert n == 80, figures


def test_walk_record_refuses_a_camera_slower_than_its_fps(tmp_path, capsys):
    """The demo camera gives 15 fps; recorded at --fps 30 half the slots repeat: refused with
    the figures (exit 2), nothing analysed, the video kept."""
    (tmp_path / "monitor.toml").write_text('[camera]\nsource = "synthetic:demo"\n')
    out = tmp_path / "walk"
    assert main(["commission", "walk", "--record", "2", "--fps", "30", "--config",
                 str(tmp_path / "monitor.toml"), "--out", str(out), "--no-video"]) == 2
    err = capsys.readouterr().err.splitlines()
    errors = [line for line in err if line.startswith("monitor: error: ")]
    assert len(errors) == 1 and "Traceback" not in "\n".join(err), err
    error = errors[0]
    assert "recording refused:" in error and "slots repeated or missing" in error
    assert "against --fps 30" in error and "record at --fps" in error
    assert (out / "walk.mp4").is_file() and not (out / "walk.json").exists()
