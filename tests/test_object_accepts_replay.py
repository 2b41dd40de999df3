"""`monitor replay --accept-at SECONDS:ZONE`: the acceptance of an object since commissioning
replayed as a user does, on an OpenCV-written video of the crate scene; the audit in
events.jsonl (who, where, when), bad input one line."""

from __future__ import annotations

import json

import cv2
import pytest
import yaml

from monitor.replay import scenarios as sc
from monitor.scene import write_video
from tests.helpers import run_monitor


@pytest.fixture(scope="module")
def crate_files(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("crate-replay")
    scenario = sc.select(["crate-after-reference"], 5.0)[0]
    cv2.imwrite(str(tmp / "ref.png"), scenario.scene.reference())
    (tmp / "cell.yaml").write_text(yaml.safe_dump(scenario.zone_data()))
    write_video(tmp / "crate.mp4", scenario.scene.frames(), 5.0)
    return tmp


def _replay(tmp, out: str, *args: str):
    return run_monitor("replay", tmp / "crate.mp4", "--zones", tmp / "cell.yaml",
                       "--reference", tmp / "ref.png", "--out", tmp / out, "--no-video",
                       *args, timeout=600)


def _events(tmp, out: str) -> list[dict]:
    return [json.loads(line) for line in (tmp / out / "events.jsonl").read_text().splitlines()]


@pytest.mark.slow
def test_a_replayed_acceptance_is_in_the_events_and_ends_the_fault(crate_files):
    proc = _replay(crate_files, "accepted", "--accept-at", "9:robot-protective",
                   "--accept-at", "10:nowhere", "--reset-at", "4,11")
    assert proc.returncode == 0, proc.stderr
    events = _events(crate_files, "accepted")
    kinds = [e.get("kind") for e in events if e["type"] == "alert"]
    assert "object_placed" in kinds and "object_in_zone_cleared" in kinds
    (accepted,) = [e for e in events if e.get("kind") == "object_accepted"]
    assert 9.0 <= accepted["time_s"] < 9.3
    assert "accepted by replay" in accepted["message"] and "robot-protective" in \
        accepted["message"] and " at x 0." in accepted["message"]
    (refused,) = [e for e in events if e.get("kind") == "object_accept_refused"]
    assert "unknown zone 'nowhere'" in refused["message"]
    # the person crouching behind the accepted crate is still held: both resets refused
    resets = [e for e in events if e["type"] == "command" and e.get("reset")]
    assert resets and not any(e["reset"]["accepted"] for e in resets), resets
    # without --accept-at the fault holds to the end (the test above can fail)
    proc = _replay(crate_files, "plain", "--reset-at", "4,11")
    kinds = [e.get("kind") for e in _events(crate_files, "plain") if e["type"] == "alert"]
    assert "object_accepted" not in kinds and "object_in_zone_cleared" not in kinds


def test_an_acceptance_time_past_the_end_is_one_line(crate_files):
    proc = _replay(crate_files, "late", "--accept-at", "99:robot-protective")
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert "--accept-at 99: past the end of crate.mp4" in proc.stderr
    bad = _replay(crate_files, "bad", "--accept-at", "robot-protective")
    assert bad.returncode == 2 and "give SECONDS:ZONE" in bad.stderr
