"""`monitor detect` and `monitor model` as real subprocesses."""

from __future__ import annotations

import json
import subprocess
import sys

import cv2
import numpy as np
import pytest

from monitor.scene import Figure, draw_figure


def run(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "monitor", *args], capture_output=True,
                          text=True, timeout=timeout)


def one_line_error(proc: subprocess.CompletedProcess) -> str:
    assert proc.returncode != 0
    assert "Traceback" not in proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.startswith("monitor: error:")]
    assert len(lines) == 1, proc.stderr
    return lines[0]


@pytest.fixture()
def person_image(tmp_path):
    frame = np.full((720, 1280, 3), 120, np.uint8)
    draw_figure(frame, Figure((400.0, 650.0), 400.0))
    path = tmp_path / "person.png"
    cv2.imwrite(str(path), frame)
    return path


def test_detect_image_prints_json_and_writes_annotated(tmp_path, person_image, synthetic_model):
    out = tmp_path / "annotated.png"
    proc = run("detect", str(person_image), "--model", str(synthetic_model), "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    record = json.loads(proc.stdout.strip())
    assert record["frame"] == 0 and len(record["persons"]) == 1
    x1, y1, x2, y2 = record["persons"][0]["box_px"]
    assert x1 < 400 < x2 and y1 < 260 and y2 >= 649
    annotated = cv2.imread(str(out))
    assert annotated is not None and not np.array_equal(annotated, cv2.imread(str(person_image)))


@pytest.mark.slow
def test_detect_video_prints_a_line_per_frame(tmp_path, synthetic_model):
    path = tmp_path / "clip.mp4"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 10, (640, 360))
    for i in range(5):
        frame = np.full((360, 640, 3), 120, np.uint8)
        draw_figure(frame, Figure((100.0 + 40 * i, 330.0), 200.0))
        writer.write(frame)
    writer.release()
    out = tmp_path / "out.mp4"
    proc = run("detect", str(path), "--model", str(synthetic_model), "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    lines = [json.loads(ln) for ln in proc.stdout.splitlines()]
    assert [ln["frame"] for ln in lines] == list(range(5))
    assert all(len(ln["persons"]) == 1 for ln in lines)
    assert cv2.VideoCapture(str(out)).get(cv2.CAP_PROP_FRAME_COUNT) == 5


def test_model_build_and_info(tmp_path):
    out = tmp_path / "m.onnx"
    proc = run("model", "build", "--out", str(out))
    assert proc.returncode == 0 and out.is_file()
    info = run("model", "info", "--model", str(out))
    assert info.returncode == 0
    assert "darknet" in info.stdout and "8849182" in info.stdout and "416x416" in info.stdout


@pytest.mark.parametrize("case", ["missing-model", "corrupt-model", "unknown-layout",
                                  "missing-input", "bad-image", "bad-video"])
def test_bad_input_gives_one_line_error(tmp_path, person_image, synthetic_model, case):
    from tests.test_detector import const_model

    model = str(synthetic_model)
    target = str(person_image)
    if case == "missing-model":
        model = str(tmp_path / "nope.onnx")
    elif case == "corrupt-model":
        (tmp_path / "bad.onnx").write_bytes(b"\x00garbage" * 50)
        model = str(tmp_path / "bad.onnx")
    elif case == "unknown-layout":
        model = str(const_model(tmp_path / "odd.onnx", {"o": np.zeros((1, 7), np.float32)}))
    elif case == "missing-input":
        target = str(tmp_path / "nothing.png")
    elif case == "bad-image":
        (tmp_path / "broken.png").write_bytes(b"not a png")
        target = str(tmp_path / "broken.png")
    elif case == "bad-video":
        (tmp_path / "broken.mp4").write_bytes(b"not a video at all" * 100)
        target = str(tmp_path / "broken.mp4")
    line = one_line_error(run("detect", target, "--model", model))
    expected = {"missing-model": "not found", "corrupt-model": "cannot load model",
                "unknown-layout": "no known output layout", "missing-input": "no such file",
                "bad-image": "cannot read the image", "bad-video": "broken.mp4"}[case]
    assert expected in line
