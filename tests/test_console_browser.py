"""The web console in a real headless browser (Debian's chromium via selenium): a signed
monitor bus on 127.0.0.1, ``monitor console`` as its own process, and a user who watches the
state go from RUN to STOP, plays an incident clip, draws a self-intersecting polygon (refused,
file untouched), then a valid one (saved: the file ``monitor zones list`` shows). Screenshots
of each page go to the test's tmp folder; with UPDATE_CONSOLE_SHOTS=1 to docs/console/ (the
docs' pictures), so a test run never changes the checkout."""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import cv2
import pytest

from monitor.bus.session import BusConfig, SafetyBus
from monitor.incidents import IncidentIndex
from monitor.policy import Command, Reason
from monitor.types import Alert
from monitor.wire.signing import new_key_pair
from monitor.zones import load_cell
from tests.console_kit import (
    CHROMIUM,
    OPERATOR,
    PASSWORD,
    ROOT,
    chromium,
    incident_dir,
    passwords,
    reference_image,
    wait_http,
    zone_file,
)
from tests.helpers import free_port, run_monitor

DOC_SHOTS = ROOT / "docs" / "console"
SHOTS = DOC_SHOTS if os.environ.get("UPDATE_CONSOLE_SHOTS") == "1" else \
    Path(tempfile.gettempdir()) / "console-shots"

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(not CHROMIUM.exists(),
                       reason="/usr/bin/chromium missing (apt-get install chromium "
                       "chromium-driver; .ci/run installs it)"),
]


@pytest.fixture()
def browser(tmp_path):
    with chromium(tmp_path / "chromium-profile") as driver:
        yield driver


class Pipeline:
    """Stands in for the monitor's loop: hands the bus the current command every 50 ms (the
    bus itself turns a silent pipeline into a stalled STOP)."""

    def __init__(self, bus: SafetyBus) -> None:
        self.bus, self.command = bus, Command("STOP", 0.0, (Reason("startup", "starting"),))
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while not self.stop.wait(0.05):
            self.bus.publish_command(self.command)

    def close(self) -> None:
        self.stop.set()
        self.thread.join(timeout=2)


@pytest.fixture()
def cell_and_console(tmp_path):
    """A signed monitor bus (this test publishes its commands) and the console following it."""
    private, public, _ = new_key_pair(tmp_path / "monitor.key")
    zport, hport = free_port(), free_port()
    cell = zone_file(tmp_path)
    cfg = BusConfig(cell="web", instance="mon-web", listen=(f"tcp/127.0.0.1:{zport}",),
                    heartbeat_hz=20.0, ttl_ms=500, signing_key=str(private),
                    config_hash=load_cell(cell).config_hash)  # as monitor run names its zones
    log = (tmp_path / "console.log").open("w")
    with SafetyBus(cfg) as bus:
        pipeline = Pipeline(bus)
        proc = subprocess.Popen(
            [sys.executable, "-m", "monitor", "console", "--cell", "web",
             "--connect", f"tcp/127.0.0.1:{zport}", "--monitor-key", str(public),
             "--zones", str(cell), "--incidents", str(incident_dir(tmp_path)),
             "--reference", f"cam0={reference_image(tmp_path)}",
             "--passwords", str(passwords(tmp_path)), "--listen", f"127.0.0.1:{hport}"],
            stdout=log, stderr=subprocess.STDOUT, cwd=tmp_path,
            env={**os.environ, "PYTHONPATH": str(ROOT)})
        try:
            wait_http(f"http://127.0.0.1:{hport}/api/state", proc, tmp_path / "console.log")
            yield bus, pipeline, f"http://127.0.0.1:{hport}", cell
        finally:
            pipeline.close()
            proc.terminate()
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
            log.close()


def _wait(driver, cond, timeout: float = 30.0, what: str = ""):
    from selenium.common.exceptions import StaleElementReferenceException
    from selenium.webdriver.support.ui import WebDriverWait

    # the page replaces its rows and shapes as it polls: an element read mid-swap is retried
    return WebDriverWait(driver, timeout, poll_frequency=0.1,
                         ignored_exceptions=(StaleElementReferenceException,)).until(
        lambda d: cond(d), message=what)


def _shot(driver, name: str) -> None:
    SHOTS.mkdir(parents=True, exist_ok=True)
    driver.save_screenshot(str(SHOTS / name))


def _click_at(driver, svg, x: float, y: float, width: int = 1280, height: int = 720) -> None:
    """Click the editor's SVG at image pixel (x, y) (the SVG keeps the image's aspect)."""
    from selenium.webdriver.common.action_chains import ActionChains

    rect = svg.rect
    sx, sy = rect["width"] / width, rect["height"] / height
    ActionChains(driver).move_to_element_with_offset(
        svg, int(x * sx - rect["width"] / 2), int(y * sy - rect["height"] / 2)).click().perform()


def test_console_live_incidents_and_zone_editor_in_a_browser(browser, cell_and_console,
                                                               tmp_path):
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import Select

    bus, pipeline, url, cell = cell_and_console
    d = browser

    # --- live: RUN, then a person in the protective zone: STOP with its reason ------------
    pipeline.command = Command("RUN", 1.0)
    d.get(url + "/")
    banner = d.find_element(By.ID, "banner")
    _wait(d, lambda _: banner.text.startswith("RUN"), what="RUN shown")
    _wait(d, lambda _: d.execute_script(
        "const i = document.getElementById('live-cam0'); return i && i.naturalWidth > 0"),
        what="live image of cam0")
    _shot(d, "live-run.png")
    snapshot = cv2.imencode(".jpg", cv2.imread(str(reference_image(tmp_path, person=True))))[1]
    bus.publish_alert(Alert("protective_zone", "critical", "person 1 in cam0-protective",
                            "cam0", time.monotonic(), snapshot_jpeg=snapshot.tobytes()))
    pipeline.command = Command("STOP", 0.0, (Reason("protective_zone",
                                                    "person 1 in cam0-protective",
                                                    zone_id="cam0-protective"),), latched=True)
    _wait(d, lambda _: banner.text.startswith("STOP"), what="STOP shown")
    assert "person 1 in cam0-protective" in d.find_element(By.ID, "reason").text
    _wait(d, lambda _: "protective_zone" in d.find_element(By.ID, "alerts").text,
          what="the alert listed")
    time.sleep(1.0)  # the next image refresh draws the alert's snapshot
    _shot(d, "live-stop.png")

    # --- incidents: the list, and the H.264 clip plays in the browser --------------------
    # the real recorder's data dir (a replay of a walk-in): one stop,latch incident, a clip
    (entry,) = IncidentIndex(tmp_path / "incidents").list()
    d.get(url + "/incidents")
    _wait(d, lambda _: [r.get_attribute("data-id") for r in
                        d.find_elements(By.CSS_SELECTOR, "#rows tr")] == [entry.id],
          what="the recorded incident")
    _wait(d, lambda _: d.execute_script(  # its thumbnail: the clip's frame, 240 px wide
        "const i = document.querySelector('#rows img.thumb');"
        "return i && i.complete && i.naturalWidth === 240"), what="the incident's thumbnail")
    d.find_element(By.CSS_SELECTOR, f"#rows tr[data-id='{entry.id}'] button.play").click()
    played = _wait(d, lambda _: d.execute_script(
        "const v = document.getElementById('player');"
        "return v.error ? 'error ' + v.error.code : (v.currentTime > 0.5 ? 'played' : null)"),
        timeout=20, what="clip plays")
    assert played == "played"
    _shot(d, "incidents.png")
    Select(d.find_element(By.ID, "f-reviewed")).select_by_value("1")
    d.find_element(By.CSS_SELECTOR, "#filters button").click()
    _wait(d, lambda _: d.find_element(By.ID, "count").text.startswith("0 incident(s)"),
          what="filtered to the reviewed ones: none yet")

    # --- zones: a self-intersecting polygon is refused, a valid one saved ----------------
    before = cell.read_bytes()
    d.get(url + "/zones")
    svg = _wait(d, lambda _: d.find_element(By.ID, "canvas"))
    _wait(d, lambda _: d.find_elements(By.CSS_SELECTOR, "#canvas polygon.zone"),
          what="zones drawn")
    d.find_element(By.ID, "operator").send_keys(OPERATOR)
    d.find_element(By.ID, "password").send_keys(PASSWORD)
    d.find_element(By.ID, "new").click()
    for x, y in ((900, 150), (1200, 400), (1200, 150), (900, 400)):  # a bow tie
        _click_at(d, svg, x, y)
    d.find_element(By.ID, "zid").send_keys("aisle-stop")
    d.find_element(By.ID, "save").click()
    msg = d.find_element(By.ID, "message")
    _wait(d, lambda _: "refused" in msg.text, what="validation error shown")
    assert "self-intersecting polygon" in msg.text and "aisle-stop" in msg.text
    assert cell.read_bytes() == before  # nothing written
    _shot(d, "zones-invalid.png")

    d.find_element(By.ID, "new").click()
    clicked = ((900, 150), (1200, 150), (1200, 400), (900, 400))
    for x, y in clicked:
        _click_at(d, svg, x, y)
    d.find_element(By.ID, "zid").send_keys("aisle-stop")
    d.find_element(By.ID, "save").click()
    _wait(d, lambda _: msg.text.startswith("saved"), what="saved")
    _wait(d, lambda _: "aisle-stop" in d.find_element(By.ID, "zone").text, what="zone listed")
    _shot(d, "zones-saved.png")

    # the file on disk is the one `monitor zones list` shows; comments kept, old one as .bak
    text = cell.read_text()
    assert "# Demo cell for the synthetic scene" in text
    assert cell.with_name("cell.yaml.bak").read_bytes() == before
    listed = run_monitor("zones", "list", cell)
    assert listed.returncode == 0, listed.stderr
    row = next(line for line in listed.stdout.splitlines() if line.startswith("aisle-stop"))
    assert row.split()[:5] == ["aisle-stop", "protective", "yes", "polygon", "cam0"]
    saved = load_cell(cell).zone("aisle-stop")
    for (x, y), (sx, sy) in zip(clicked, saved.points_px, strict=True):
        assert abs(x - sx) <= 3 and abs(y - sy) <= 3  # where the user clicked (one px of CSS)
    assert load_cell(cell).config_hash in listed.stdout
    hash_line = hashlib.sha256(cell.read_bytes()).hexdigest()
    assert hash_line  # the audit names the change
    audit = [json.loads(line) for line in
             cell.with_name("cell.yaml.audit.jsonl").read_text().splitlines()]
    assert [a["result"] for a in audit] == ["invalid", "saved"]
    assert all(a["operator"] == OPERATOR and a["zone"] == "aisle-stop" for a in audit)
    assert audit[1]["config_hash"] == load_cell(cell).config_hash

    # the monitor still decides with the zone set it started with: the live page says so
    d.get(url + "/")
    _wait(d, lambda _: d.find_element(By.ID, "pending").is_displayed(),
          what="zone file pending shown")
    assert "monitor zones apply" in d.find_element(By.ID, "pending").text

    # every edit attempt is an incident of the recorder's data dir too (cause zone_edit)
    edits = IncidentIndex(tmp_path / "incidents").list(cause="zone_edit")
    assert [e.record["zone_edit"]["result"] for e in reversed(edits)] == ["invalid", "saved"]
    assert all(e.operator == OPERATOR and not e.clip_paths() for e in edits)
    saved_edit = edits[0].record["zone_edit"]
    assert saved_edit["new_hash"] == load_cell(cell).config_hash == audit[1]["config_hash"]
    assert saved_edit["old_hash"] == audit[1]["config_hash_before"] != saved_edit["new_hash"]
    assert "self-intersecting polygon" in edits[1].record["zone_edit"]["message"]
    d.get(url + "/incidents")
    _wait(d, lambda _: d.find_element(By.ID, "count").text.startswith("3 incident(s)"),
          what="the two zone edits listed with the recorded entry")
