"""Video files decode with PyAV (monitor/frames/decoding.py): the same BGR pixels and the same
container times as OpenCV's FFmpeg backend gave (what every replay figure was measured on),
for the codecs OpenCV writes; a file PyAV cannot open goes to OpenCV and its diagnosis
(tests/test_frames.py's bad videos)."""

from __future__ import annotations

import itertools
from pathlib import Path

import cv2
import numpy as np
import pytest

from monitor.frames import VideoFileReader
from monitor.frames.decoding import OpenCvDecoder, PyAvDecoder
from monitor.scene import DemoScene


def _walk(path: Path, fourcc: str, n: int = 6) -> Path:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), 10.0, (640, 360))
    for image, _ in itertools.islice(DemoScene(fps=10.0).frames(), n):
        writer.write(cv2.resize(image, (640, 360), interpolation=cv2.INTER_AREA))
    writer.release()
    return path


def _frames(decoder, path: Path) -> list[tuple[np.ndarray, float]]:
    out, got = [], decoder.open(path)
    while got is not None:
        out.append(got)
        got = decoder.read()
    decoder.close()
    return out


@pytest.mark.parametrize(("fourcc", "suffix"), [("mp4v", ".mp4"), ("MJPG", ".avi")])
def test_pyav_gives_opencvs_pixels_and_times(tmp_path, fourcc, suffix):
    path = _walk(tmp_path / f"walk{suffix}", fourcc)
    ours, theirs = _frames(PyAvDecoder(), path), _frames(OpenCvDecoder(), path)
    assert len(ours) == len(theirs) == 6
    for (a, ta), (b, tb) in zip(ours, theirs, strict=True):
        assert a.shape == b.shape == (360, 640, 3) and a.dtype == np.uint8
        assert np.array_equal(a, b)
        assert ta == pytest.approx(tb, abs=1e-6)


def test_the_reader_decodes_with_pyav_and_says_the_container_facts(tmp_path):
    path = _walk(tmp_path / "walk.mp4", "mp4v")
    with VideoFileReader(path, "cam0") as reader:
        assert reader.decoded_with == "pyav"
        assert (reader.fps, reader.frame_count, reader.codec) == (10.0, 6, "mp4v")
        times = [f.info.capture_time for f in reader]
    assert times == pytest.approx([k / 10 for k in range(6)])
