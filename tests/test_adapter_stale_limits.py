"""The adapters' own stale limits at both sides of the bound (pure): a snapshot just younger
than the limit shows the verdict, one just older shows STOP. The Modbus map (docs/plc.md:
`snapshot_age_ms` > `--stale-ms` reads STOP, reason 6, status bit 0) and the OPC UA server
(no snapshot for `--stale-ms`: STOP, `adapter_stale`). Twice the documented limit passed every
other test (tests/test_adapters_plc.py checks only that a frozen loop reads STOP at some time)."""

from __future__ import annotations

import time

import pytest

from monitor.adapters import modbus_map as mm
from monitor.adapters.opcua import initial_values, next_values, stale
from monitor.adapters.snapshot import SafetySnapshot, snapshot_of
from monitor.wire.consumer import Verdict

NOW = 1000.0
MARGIN = 0.002  # s either side of the limit: far above float error, far below the limit


def run_snapshot(age_s: float) -> SafetySnapshot:
    """A verified RUN whose snapshot was made ``age_s`` before ``NOW``."""
    made = NOW - age_s
    cmd = {"state": "RUN", "speed_scale": 1.0, "reasons": []}
    return snapshot_of(Verdict("RUN", 1.0, "", 5, cmd), made, time.time(), 7, made - 0.01)


@pytest.mark.parametrize("stale_s", [0.05, 0.2, 1.0], ids=["50ms", "200ms-default", "1s"])
def test_the_modbus_map_reads_run_just_under_the_stale_limit_and_stop_just_over(stale_s):
    st = mm.AdapterState(stale_s=stale_s)
    fresh = mm.render(run_snapshot(stale_s - MARGIN), NOW, st)
    assert fresh[mm.ADDRESS["state"]] == 2 and fresh[mm.ADDRESS["speed_scale"]] == 1000
    assert fresh[mm.ADDRESS["reason"]] == 0 and not fresh[mm.ADDRESS["status"]] & 1
    late = mm.render(run_snapshot(stale_s + MARGIN), NOW, st)
    assert late[mm.ADDRESS["state"]] == 0 and late[mm.ADDRESS["speed_scale"]] == 0
    assert late[mm.ADDRESS["reason"]] == mm.REASON_CODES["adapter_stale"]
    assert late[mm.ADDRESS["status"]] & 1
    assert abs(late[mm.ADDRESS["snapshot_age_ms"]] - (stale_s + MARGIN) * 1000) <= 1
    assert late[mm.ADDRESS["heartbeat"]] == 7  # the heartbeat still says which tick it was


@pytest.mark.parametrize("stale_ms", [40.0, 250.0, 1000.0], ids=["40ms", "250ms-default", "1s"])
def test_the_opcua_server_shows_the_verdict_just_under_the_stale_limit_and_stop_just_over(
        stale_ms):
    stale_s, cams = stale_ms / 1000.0, ("cam0",)
    shown = initial_values(cams)  # STOP, no_command
    fresh = next_values(run_snapshot(stale_s - MARGIN), NOW, stale_s, shown, 6, cams)
    assert fresh is not None and fresh["State"] == 2 and fresh["ReasonCode"] == ""
    late = next_values(run_snapshot(stale_s + MARGIN), NOW, stale_s, fresh, 6, cams)
    assert late is not None and late["State"] == 0 and late["StateName"] == "STOP"
    assert late["ReasonCode"] == "adapter_stale" and late["SpeedScale"] == 0.0
    assert late["SafetyStateManagement.VisionSafetyTriggered"] is True
    assert late["Heartbeat"] == 7  # the tick it was, for a client to see it still
    # shown once per stale spell; an age that is no number is stale too
    assert next_values(run_snapshot(stale_s + MARGIN), NOW, stale_s, late, 7, cams) is None
    assert stale(run_snapshot(float("nan")), NOW, stale_s)
