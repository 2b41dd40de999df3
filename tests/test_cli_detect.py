"""`monitor detect` and `monitor model` as real subprocesses."""

from __future__ import annotations

import json
import subprocess
import sys

import cv2
import numpy as np
import pytest

from monitor.scene import Figure, draw_figure
from tests.helpers import run_monitor

run = run_monitor


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
    assert "16:9 at 416x288" in info.stdout  # the rectangular input (docs/models.md)


@pytest.mark.parametrize("case", ["missing-model", "corrupt-model", "unknown-layout",
                                  "missing-input", "bad-image", "bad-video"])
def test_bad_input_gives_one_line_error(tmp_path, person_image, synthetic_model, case):
    from tests.onnx_models import const_model

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


# ----------------------------------------------------------------------------- CLI-wide behaviour


def _clip(path, frames: int) -> None:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 10, (320, 240))
    for i in range(frames):
        frame = np.full((240, 320, 3), 120, np.uint8)
        draw_figure(frame, Figure((60.0 + 4 * i, 220.0), 120.0))
        writer.write(frame)
    writer.release()


@pytest.mark.slow
def test_broken_pipe_is_quiet(tmp_path, synthetic_model):
    """`monitor detect clip.mp4 | head -1`: the reader goes away; no traceback, no noise."""
    clip = tmp_path / "clip.mp4"
    _clip(clip, 60)
    proc = subprocess.Popen([sys.executable, "-m", "monitor", "detect", str(clip), "--model",
                             str(synthetic_model)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    first = proc.stdout.readline()
    proc.stdout.close()  # like head -1 exiting
    _, err = proc.communicate(timeout=120)
    assert json.loads(first)["frame"] == 0
    assert proc.returncode == 0
    assert err == ""


def test_debug_works_before_and_after_the_subcommand(tmp_path):
    missing = str(tmp_path / "nothing.png")
    for args in (["--debug", "detect", missing], ["detect", missing, "--debug"]):
        proc = run(*args)
        assert proc.returncode != 0
        assert "Traceback" in proc.stderr and "InputError" in proc.stderr, args
    assert "no such file" in one_line_error(run("detect", missing))


def test_os_errors_are_told_in_words_without_exception_names(tmp_path):
    blocker = tmp_path / "file.txt"
    blocker.write_text("a file where a directory is needed")
    line = one_line_error(run("model", "build", "--out", str(blocker / "m.onnx")))
    assert line == f"monitor: error: {blocker}: already exists"


def test_unexpected_errors_hide_exception_names_and_installation_paths():
    from monitor.cli import user_message

    exc = RuntimeError("bad value in /usr/lib/python3.12/site-packages/onnx/checker.py:88")
    text = user_message(exc)
    assert "RuntimeError" not in text and "site-packages" not in text
    assert text.startswith("unexpected problem: bad value in <internal>")
    assert "--debug" in text
    assert user_message(PermissionError(13, "Permission denied", "/etc/x")) == \
        "/etc/x: permission denied"


def _all_parsers(parser):
    import argparse

    yield parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                yield from _all_parsers(sub)


def test_every_option_with_a_default_shows_it_in_help():
    """Across every subcommand (other modules' too): the parser class adds the default."""
    import argparse

    from monitor.cli import HelpFormatter, _has_default, build_parser

    checked = 0
    for parser in _all_parsers(build_parser()):
        formatter = HelpFormatter(parser.prog)
        for action in parser._actions:
            if not _has_default(action) or action.help == argparse.SUPPRESS:
                continue
            checked += 1
            text = formatter._get_help_string(action)
            assert "default" in text.lower(), (parser.prog, action.dest)
            if "%(default)" in text:
                assert str(action.default) in formatter._expand_help(action), (parser.prog,
                                                                               action.dest)
    assert checked > 20


def test_detect_and_model_options_all_have_help_text():
    import argparse

    from monitor.cli import build_parser

    for parser in _all_parsers(build_parser()):
        if not parser.prog.startswith(("monitor detect", "monitor model")):
            continue
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                continue
            assert action.help and not action.help.startswith("default:"), \
                (parser.prog, action.dest)
            assert "seeds" not in action.help


def test_nan_model_is_a_one_line_error_never_nan_json(tmp_path, person_image):
    from tests.onnx_models import const_model

    heads = {f"h{i}": np.full((1, 255, g, g), np.nan, np.float32) for i, g in ((0, 13), (1, 26))}
    model = const_model(tmp_path / "nan.onnx", heads, inputs={"images": [1, 3, 416, 416]})
    proc = run("detect", str(person_image), "--model", str(model))
    assert "NaN or infinite" in one_line_error(proc)
    assert "NaN" not in proc.stdout and "Infinity" not in proc.stdout


@pytest.mark.slow
def test_person_classes_option(tmp_path, person_image):
    from tests.onnx_models import two_class_model

    model = str(two_class_model(tmp_path / "fall.onnx"))
    default = run("detect", str(person_image), "--model", model)
    assert default.returncode == 0 and "set detector.person_classes" in default.stderr
    both = run("detect", str(person_image), "--model", model, "--person-classes", "Normal,Fall")
    assert both.returncode == 0 and both.stderr == ""
    assert len(json.loads(both.stdout)["persons"]) == 2
    assert len(json.loads(default.stdout)["persons"]) == 1
