"""The incident review page in a real headless chromium against a real ``monitor console``
process: the timeline marks every listed incident, three mutes within a minute are one row
"3× zone_muted cam0" that expands, the kind filter narrows list and timeline, a click on a mark
selects its row, an operator marks an incident reviewed (kept across a console restart), and
the page's scripts run under the console's content security policy (no inline script)."""

from __future__ import annotations

import contextlib
import json
import os
import subprocess
import sys
import tempfile
import urllib.request
from pathlib import Path

import pytest

from tests.console_kit import (
    CHROMIUM,
    OPERATOR,
    PASSWORD,
    ROOT,
    chromium,
    incident_dir,
    passwords,
    review_incidents,
    wait_http,
    zone_file,
)
from tests.helpers import free_port

SHOTS = ROOT / "docs" / "console" if os.environ.get("UPDATE_CONSOLE_SHOTS") == "1" else \
    Path(tempfile.gettempdir()) / "console-shots"

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(not CHROMIUM.exists(),
                       reason="/usr/bin/chromium missing (apt-get install chromium "
                       "chromium-driver; .ci/run installs it)"),
]


@contextlib.contextmanager
def console_process(tmp: Path, args: list[str], port: int):
    log_path = tmp / f"console-{port}.log"
    with log_path.open("w") as log:
        proc = subprocess.Popen(
            [sys.executable, "-m", "monitor", "console", *args, "--listen",
             f"127.0.0.1:{port}"], stdout=log, stderr=subprocess.STDOUT, cwd=tmp,
            env={**os.environ, "PYTHONPATH": str(ROOT)})
        try:
            wait_http(f"http://127.0.0.1:{port}/api/state", proc, log_path)
            yield f"http://127.0.0.1:{port}"
        finally:
            proc.terminate()
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=10)


def _wait(driver, cond, what: str, timeout: float = 30.0):
    from selenium.common.exceptions import StaleElementReferenceException
    from selenium.webdriver.support.ui import WebDriverWait

    # the page replaces its rows and marks when it reloads the list: retried mid-swap
    return WebDriverWait(driver, timeout, poll_frequency=0.1,
                         ignored_exceptions=(StaleElementReferenceException,)).until(
        lambda d: cond(d), message=what)


def test_review_page_timeline_groups_filters_and_marks(tmp_path):
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import Select

    data = incident_dir(tmp_path)
    ids = review_incidents(data)
    args = ["--cell", "web", "--unauthenticated", "--connect",
            f"tcp/127.0.0.1:{free_port()}", "--zones", str(zone_file(tmp_path)),
            "--incidents", str(data), "--passwords", str(passwords(tmp_path))]
    with console_process(tmp_path, args, free_port()) as url, \
            chromium(tmp_path / "profile") as d:
        d.get(url + "/incidents")
        marks = lambda: d.find_elements(By.CSS_SELECTOR, "#timeline rect.mark")  # noqa: E731
        _wait(d, lambda _: len(marks()) == 7, "7 timeline marks")
        group = _wait(d, lambda _: d.find_elements(By.CSS_SELECTOR, "#rows tr.group"),
                      "the grouped row")
        assert len(group) == 1 and "3× zone_muted cam0" in group[0].text
        assert "0 of 3" in group[0].text
        assert d.find_element(By.ID, "count").text == "7 incident(s) in 5 row(s)"
        # the marks are coloured by kind: the STOP red (safety), the alerts amber
        stop_mark = d.find_element(By.CSS_SELECTOR, f"#timeline [data-id='{ids['stop']}']")
        assert "safety" in stop_mark.get_attribute("class")
        assert d.execute_script("return getComputedStyle(arguments[0]).fill", stop_mark) == \
            "rgb(198, 40, 40)"

        # the kind filter: offered from the data; narrows the list and the timeline
        kinds = [o.get_attribute("value") for o in
                 Select(d.find_element(By.ID, "f-kind")).options]
        assert kinds == ["", "alert", "camera_moved", "latch", "scene_change", "stop",
                         "zone_muted"]
        assert [o.get_attribute("value") for o in
                Select(d.find_element(By.ID, "f-camera")).options] == ["", "cam0", "cam1"]
        Select(d.find_element(By.ID, "f-kind")).select_by_value("zone_muted")
        d.find_element(By.CSS_SELECTOR, "#filters button[type=submit]").click()
        _wait(d, lambda _: len(marks()) == 4, "4 marks after the kind filter")
        _wait(d, lambda _: d.find_element(By.ID, "count").text ==
              "4 incident(s) in 2 row(s)", "the filtered count")
        assert "kind=zone_muted" in d.find_element(By.ID, "csv").get_attribute("href")

        # a click on a mark of the group selects its row, expanding the group
        members = d.find_elements(By.CSS_SELECTOR, "#rows tr.member")
        assert len(members) == 3 and not any(m.is_displayed() for m in members)
        d.find_element(By.CSS_SELECTOR, f"#timeline [data-id='{ids['mute2']}']").click()
        row = d.find_element(By.CSS_SELECTOR, f"#rows tr[data-id='{ids['mute2']}']")
        _wait(d, lambda _: row.is_displayed() and "sel" in row.get_attribute("class"),
              "the clicked mark's row selected")
        assert all(m.is_displayed() for m in members)

        # mark it reviewed with the operator's password (the page sets the Basic header)
        d.find_element(By.ID, "operator").send_keys(OPERATOR)
        d.find_element(By.ID, "password").send_keys(PASSWORD)
        row.find_element(By.CSS_SELECTOR, "button.mark-reviewed").click()
        _wait(d, lambda _: f"by {OPERATOR}" in d.find_element(
            By.CSS_SELECTOR, f"#rows tr[data-id='{ids['mute2']}']").text, "shown reviewed")
        assert "marked reviewed by anna" in d.find_element(By.ID, "message").text
        _wait(d, lambda _: "1 of 3" in d.find_element(By.CSS_SELECTOR, "#rows tr.group").text,
              "the group counts the reviewed one")
        SHOTS.mkdir(parents=True, exist_ok=True)
        d.save_screenshot(str(SHOTS / "incidents-review.png"))
        # the page ran its own scripts only: no policy violation was logged
        logs = d.get_log("browser")
        assert not [e for e in logs if "Content Security Policy" in e["message"]], logs

    # a console started anew over the same data dir still shows the mark
    with console_process(tmp_path, args, free_port()) as url:
        listed = json.loads(urllib.request.urlopen(url + "/api/incidents?reviewed=1",
                                                   timeout=10).read())["incidents"]
    assert [(i["id"], i["review"]["operator"]) for i in listed] == [(ids["mute2"], OPERATOR)]
