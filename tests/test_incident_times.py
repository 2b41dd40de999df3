"""Times in incidents (issue 32): the live service's incidents name the moment in local
wall-clock time (their description, their events and the clip's header), as its log does; a
replay's keep the video's seconds, where annotated.mp4 shows them. The real policy makes the
commands, the real recorder writes the record and the H.264 clip, PyAV decodes it."""

from __future__ import annotations

import json
from datetime import datetime
from pathlib import Path

import av
import numpy as np
import pytest

from monitor.driver import Step
from monitor.frames import Frame
from monitor.incidents import RecorderConfig
from monitor.incidents.recorder import IncidentRecorder
from monitor.incidents.store import RECORD
from monitor.pipeline import StepResult
from monitor.policy import PolicyConfig, step
from monitor.records.annotate import HEADER_PX, annotate
from monitor.timetext import wall_iso
from monitor.types import FrameInfo
from tests.policy_kit import frame, prot, warmed

ENTRY = 100.0  # the person walks into the protective zone at 100.0 on the monotonic clock ...
ENTRY_WALL = datetime(2024, 5, 6, 12, 0, 3).timestamp()  # ... which is 12:00:03 local time
LIVE = wall_iso(lambda: ENTRY + 5.0, lambda: ENTRY_WALL + 5.0)


def _steps() -> list[Step]:
    """A person in Z1 from 100.0 to 100.2, then gone; real policy commands, 10 frames/s."""
    state, last = warmed(until=99.0)
    image = np.full((240, 320, 3), 70, np.uint8)
    steps = []
    for k in range(-5, 16):
        t = round(ENTRY + k / 10, 3)
        hits = (prot("Z1", person=1),) if 0 <= k <= 2 else ()
        state, cmd = step(state, frame(t, *hits), t, PolicyConfig())
        info = FrameInfo("cam0", k + 5, t, 320, 240)
        steps.append(Step(StepResult(t, cmd, not cmd.same_as(last), frame=info),
                          Frame(image, info), k + 5))
        last = cmd
    return steps


def _record(tmp: Path, when) -> tuple[dict, Path]:
    recorder = IncidentRecorder(RecorderConfig(enabled=True, pre_s=0.3, post_s=0.5,
                                               max_fps=10.0), tmp, ["cam0"], lossless=True,
                                when=when)
    try:
        for s in _steps():
            recorder.on_step(s)
    finally:
        recorder.close(timeout=None)
    assert recorder.stopped is None, recorder.stopped
    folder = next(p for p in tmp.iterdir() if (p / RECORD).exists())
    return json.loads((folder / RECORD).read_text()), folder


def _texts(record: dict) -> list[str]:
    return [record["describe"], *(e["describe"] for e in record["events"] if "describe" in e)]


def test_live_incidents_name_the_wall_clock_time_replays_the_video_seconds(tmp_path):
    live, _ = _record(tmp_path / "live", LIVE)
    assert live["describe"] == ("STOP latched by person 1 in Z1 at 2024-05-06 12:00:03; "
                                "holding now: person 1 in Z1; no reset until they clear")
    assert all("of the video" not in text for text in _texts(live))
    left = next(e for e in live["events"] if e["type"] == "command" and e["reset_possible"])
    assert "at 2024-05-06 12:00:03; no STOP cause now" in left["describe"]

    replayed, _ = _record(tmp_path / "replay", None)
    assert replayed["describe"].startswith("STOP latched by person 1 in Z1 at 100.0 s of the "
                                           "video;")
    assert all("2024-05-06" not in text for text in _texts(replayed))


def _first_frame(clip: Path) -> np.ndarray:
    with av.open(str(clip)) as container:
        return next(container.decode(video=0)).to_ndarray(format="bgr24")


def test_the_clip_header_shows_local_time_live_and_video_seconds_in_replay(tmp_path):
    steps = _steps()
    first = next(s for s in steps if s.result.now == pytest.approx(ENTRY - 0.3))
    drawn = {name: annotate(first.frame.image, first.result, None, "cam0", [], when=when)
             for name, when in (("live", LIVE), ("replay", None))}
    assert drawn["live"][1].header.startswith("2024-05-06 12:00:02   frame 2   camera cam0")
    assert drawn["replay"][1].header.startswith("t 99.70 s   frame 2   camera cam0")

    for name, when in (("live", LIVE), ("replay", None)):
        _, folder = _record(tmp_path / name, when)
        got = _first_frame(folder / "cam0.mp4")[:HEADER_PX].astype(float)

        def off(expected: np.ndarray, got=got) -> float:
            return float(np.abs(got - expected[:HEADER_PX].astype(float)).mean())

        other = "replay" if name == "live" else "live"
        # the clip's header is the one drawn with its own clock (H.264 blurs it a little)
        assert off(drawn[name][0]) < 0.5 * off(drawn[other][0]), name
