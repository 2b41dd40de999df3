"""Incident rows name the alert kind (issue 32: 177 incidents in 45 minutes, mostly "alert" rows
that never said which alert, so a mute looked like every other row). The real recorder writes
the incidents; `monitor incidents list`, the export and the console's list read them back."""

from __future__ import annotations

import csv
import io
import json

import numpy as np
import pytest

from monitor.cli import main
from monitor.console.incidents import IncidentFilters, RecorderIncidents
from monitor.driver import Step
from monitor.frames import Frame
from monitor.incidents import IncidentIndex, RecorderConfig
from monitor.incidents.export import to_csv
from monitor.incidents.recorder import IncidentRecorder
from monitor.pipeline import StepResult
from monitor.policy import Command, Reason
from monitor.types import Alert, FrameInfo

RUN = Command("RUN", 1.0)
STOP = Command("STOP", 0.0, (Reason("protective_zone", "person 1 in Z1", zone_id="Z1"),),
               latched=True)


def _alert(kind: str, t: float) -> Alert:
    return Alert(kind, "warning", f"{kind} at {t}", "muting" if "mute" in kind else "cam0", t)


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory):
    """A mute, a scene change with a second alert, a STOP and an unmute, 2 s apart."""
    out = tmp_path_factory.mktemp("kinds")
    image = np.full((48, 64, 3), 80, np.uint8)
    plan = {10: ((_alert("zone_muted", 1.0),), RUN),
            30: ((_alert("scene_change", 3.0), _alert("camera_moved", 3.0)), RUN),
            50: ((), STOP), 70: ((_alert("zone_unmuted", 7.0),), STOP)}
    recorder = IncidentRecorder(RecorderConfig(enabled=True, pre_s=0.2, post_s=0.2,
                                               max_fps=10.0), out, ["cam0"], lossless=True)
    try:
        command = RUN
        for k in range(90):
            t = k / 10
            alerts, now_command = plan.get(k, ((), command))
            info = FrameInfo("cam0", k, t, 64, 48)
            recorder.on_step(Step(StepResult(t, now_command, now_command is not command,
                                             frame=info, alerts=alerts), Frame(image, info), k))
            command = now_command
    finally:
        recorder.close(timeout=None)
    assert recorder.stopped is None, recorder.stopped
    return out


def test_each_alert_row_names_its_kind(data_dir):
    rows = sorted(IncidentIndex(data_dir).list(), key=lambda i: i.time_s)
    assert [i.cause_text() for i in rows] == [
        "alert(zone_muted)", "alert(scene_change,camera_moved)", "stop,latch",
        "alert(zone_unmuted)"]
    assert rows[0].alert_kinds == ("zone_muted",) and rows[2].alert_kinds == ()
    assert rows[0].causes == ("alert",)  # the cause itself (counters, filters) is unchanged


def test_the_kinds_come_from_the_events_for_records_written_before(data_dir):
    incident = IncidentIndex(data_dir).list(cause="zone_muted")[0]
    older = dict(incident.record)
    del older["alerts"]  # as the recorder wrote them before it kept the kinds
    assert type(incident)(**{**incident.__dict__, "record": older}).alert_kinds == (
        "zone_muted",)


def test_incidents_list_names_the_kind_and_filters_by_it(data_dir, capsys):
    assert main(["incidents", "list", "--dir", str(data_dir)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 4
    assert "alert(zone_unmuted)" in lines[0] and "alert(zone_muted)" in lines[3]
    assert "alert(scene_change,camera_moved)" in lines[2]
    assert main(["incidents", "list", "--dir", str(data_dir), "--cause", "zone_muted"]) == 0
    only = capsys.readouterr().out.splitlines()
    assert len(only) == 1 and "alert(zone_muted)" in only[0]
    assert main(["incidents", "list", "--dir", str(data_dir), "--cause", "alert"]) == 0
    assert len(capsys.readouterr().out.splitlines()) == 3
    assert main(["incidents", "list", "--dir", str(data_dir), "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert [r["alerts"] for r in rows] == ["zone_unmuted", "", "scene_change,camera_moved",
                                           "zone_muted"]


def test_the_export_and_the_consoles_list_name_the_kind(data_dir):
    incidents = IncidentIndex(data_dir).list()
    exported = list(csv.DictReader(io.StringIO(to_csv(incidents))))
    assert exported[-1]["causes"] == "alert" and exported[-1]["alerts"] == "zone_muted"
    console = RecorderIncidents(data_dir).list(IncidentFilters())
    assert [r["cause"] for r in console] == [
        "alert(zone_unmuted)", "stop,latch", "alert(scene_change,camera_moved)",
        "alert(zone_muted)"]
