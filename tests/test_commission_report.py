"""`monitor commission report` on the demo cell: the same inputs and key give the same bytes, a
changed byte is found by `commission verify`, the report renders in headless chromium with
every section and picture, and `monitor status` of a running service names the commissioned
report and whether the running configuration still matches. (Signatures, forged records and
the fingerprint's files: tests/test_commission_signed.py.)"""

from __future__ import annotations

import base64
import hashlib
import io
import re
import shutil
from pathlib import Path

import pytest
import yaml

from monitor.cli import main
from monitor.commission.open_warnings import Facts, open_warnings, separation
from monitor.commission.report import SECTIONS, verify
from monitor.config import CameraConfig, MonitorConfig, demo_cell_path
from monitor.service.commissioned import RECORD_NAME, read_record, status_of
from monitor.wire.signing import load_operators, new_key_pair
from tests.helpers import commissioner_key, one_error_line
from tests.processes import Service, wait_for

CHROMIUM = Path("/usr/bin/chromium")
CHROMEDRIVER = Path(shutil.which("chromedriver") or "/usr/bin/chromedriver")


KEYS: dict[str, Path] = {}


def _report(out: Path, *args: str, by: str = "anna") -> str:
    key = args[args.index("--key") + 1] if "--key" in args else None
    if key is None:
        if "--config" in args:  # a config's commissioner is listed beside it
            key = str(commissioner_key(Path(args[args.index("--config") + 1]).parent, by))
        else:
            key = str(KEYS.get(by) or KEYS.setdefault(by, commissioner_key(out.parent, by)))
        args = (*args, "--key", key)
    assert main(["commission", "report", "--out", str(out), "--by", by, *args]) == 0
    return out.read_text()


@pytest.fixture(scope="module")
def demo_report(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("report") / "demo.html"
    with pytest.MonkeyPatch.context() as mp:  # the model cache of every other test (conftest)
        mp.setenv("WORKCELL_MONITOR_HOME", str(tmp_path_factory.getbasetemp() / "monitor-home"))
        _report(out)
    return out


def test_the_same_inputs_give_the_same_report(demo_report, tmp_path, capsys):
    again = _report(tmp_path / "again.html")
    first = demo_report.read_text()
    assert again == first  # Ed25519 signatures are deterministic: the same bytes
    opened = verify(demo_report.read_bytes())
    assert opened.valid and opened.key_text in first
    assert "signed by anna" in capsys.readouterr().out
    # what makes it: the zone set, the model, the changed settings and the sign-off
    assert "demo-cell.yaml" in first and "bus.allow_unsigned_resets" in first
    assert "anna" in first and _report(tmp_path / "other.html", by="bob") != first


def test_a_changed_report_fails_verification(demo_report, tmp_path, capsys):
    assert main(["commission", "verify", str(demo_report)]) == 0
    changed = tmp_path / "changed.html"
    changed.write_text(demo_report.read_text().replace("robot-protective", "robot-protectiv", 1))
    assert main(["commission", "verify", str(changed)]) == 1
    assert "CHANGED" in capsys.readouterr().out


def test_the_record_beside_the_config_and_the_status_field(tmp_path, synthetic_model):
    config = tmp_path / "monitor.toml"
    config.write_text(f'[camera]\nsource = "synthetic:demo"\n[model]\npath = "{synthetic_model}"\n'
                      '[policy]\nclear_time = 1.5\n[service]\ncommissioners_file = '
                      '"commissioners"\n')
    html = _report(tmp_path / "report.html", "--config", str(config))
    record, by, _ = read_record(tmp_path / RECORD_NAME,
                                load_operators(tmp_path / "commissioners"))
    assert record["report_sha256"] == hashlib.sha256((tmp_path / "report.html").read_bytes()
                                                     ).hexdigest()
    assert by == "anna" and record["by"] == "anna"
    assert "policy.clear_time" in html
    running = {k: record[k] for k in ("zones_hash", "model_sha256", "settings_sha256",
                                      "files")}
    assert status_of(config, running)["matches"] is True
    changed = status_of(config, {**running, "zones_hash": "0" * 16})
    assert changed["matches"] is False and changed["differs"] == ["zones"]
    assert changed["checksum"] == record["report_sha256"]
    assert "not commissioned: zones differs" in changed["reason"]
    other = tmp_path / "other" / "monitor.toml"
    other.parent.mkdir()
    gone = status_of(other, running)
    assert gone["checksum"] is None and not gone["matches"] and "not commissioned" in \
        gone["reason"]


def test_a_real_camera_without_a_reference_is_an_open_warning(tmp_path, synthetic_model):
    """Glare and the image conditions of a camera without a reference are judged by the model
    envelope's absolute limits only: the report says so (the demo's synthetic camera not)."""
    config = tmp_path / "monitor.toml"
    config.write_text('[camera]\nid = "cam0"\nsource = "rtsp://127.0.0.1:8554/cam0"\n'
                      f'[model]\npath = "{synthetic_model}"\n')
    html = _report(tmp_path / "report.html", "--config", str(config))
    warnings = html[html.index("Open warnings"):]
    assert "camera cam0: no reference image: glare" in warnings
    assert "no reference image" not in demo_report_text(tmp_path)


def demo_report_text(tmp_path: Path) -> str:
    (tmp_path / "demo").mkdir(exist_ok=True)  # its own commissioner's key beside it
    config = tmp_path / "demo" / "demo.toml"
    config.write_text('[camera]\nsource = "synthetic:demo"\n')
    return _report(tmp_path / "demo" / "demo.html", "--config", str(config))


@pytest.mark.slow
def test_status_names_the_commissioned_checksum(tmp_path, synthetic_model):
    svc = Service(tmp_path, synthetic_model, "synthetic:demo",
                  'commissioners_file = "commissioners"\n')
    html = _report(tmp_path / "report.html", "--config", str(svc.config))
    checksum = hashlib.sha256((tmp_path / "report.html").read_bytes()).hexdigest()
    assert "tester" in html  # the operators file's operator and key fingerprint
    with svc:
        # the first answers: once the monitor has decided (its status queryable is routed)
        wait_for(lambda: svc.commands, 60, "a command", svc)
        status = wait_for(lambda: (s := svc.status()).get("commissioned") and s, 30,
                          "the commissioned field in the status", svc)
    assert status["commissioned"]["checksum"] == checksum
    assert status["commissioned"]["matches"] is True and status["commissioned"]["differs"] == []


@pytest.mark.slow
@pytest.mark.skipif(not CHROMIUM.exists(), reason="/usr/bin/chromium missing (apt-get install "
                    "chromium chromium-driver; .ci/run installs it)")
def test_the_report_renders_in_headless_chromium(demo_report, tmp_path):
    import pypdf
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service as DriverService
    from selenium.webdriver.common.by import By

    opts = webdriver.ChromeOptions()
    opts.binary_location = str(CHROMIUM)
    for flag in ("--headless", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                 "--disable-background-networking", "--no-first-run",
                 f"--user-data-dir={tmp_path / 'profile'}", "--window-size=1200,900"):
        opts.add_argument(flag)
    driver = webdriver.Chrome(options=opts, service=DriverService(str(CHROMEDRIVER)))
    try:
        driver.set_page_load_timeout(30)
        driver.get(demo_report.as_uri())
        for sid in SECTIONS:
            section = driver.find_element(By.ID, sid)
            assert section.find_element(By.TAG_NAME, "h2").text, sid
        images = driver.execute_script(
            "return Array.from(document.images).map(i => [i.alt, i.complete, i.naturalWidth])")
        assert {alt for alt, _, _ in images} >= {"floor plan", "camera cam0"}
        assert all(done and width > 0 for _, done, width in images), images
        key = driver.find_element(By.ID, "signature-key").text
        assert key == verify(demo_report.read_bytes()).key_text
        driver.save_screenshot(str(tmp_path / "report.png"))
        # printable on A4: Chrome's own print to PDF with the report's @page size
        pdf = base64.b64decode(driver.execute_cdp_cmd(
            "Page.printToPDF", {"preferCSSPageSize": True})["data"])
        boxes = set(re.findall(rb"/MediaBox\s*\[0 0 ([\d.]+) ([\d.]+)\]", pdf))
        assert {(round(float(w)), round(float(h))) for w, h in boxes} == {(595, 842)}, boxes
        pages = [p.extract_text() for p in pypdf.PdfReader(io.BytesIO(pdf)).pages]
        assert len(pages) >= 3, pages  # the first page, the details, the sign-off
        for n, text in enumerate(pages, start=1):
            assert f"page {n} of {len(pages)}" in text, text[:200]
        assert "Verdict" in pages[0] and "Open warnings" in pages[0]
        assert "Identity" not in pages[0] and "Identity" in pages[1]
        assert "Sign-o" in pages[-1] and not any("Sign-o" in t for t in pages[:-1])
    finally:
        driver.quit()


@pytest.mark.parametrize(("args", "needle"), [
    pytest.param(["--status", "{missing}"], "no such status file", id="no-status"),
    pytest.param(["--status", "{bad}"],
                 "status file is not JSON (save it with `monitor status --json", id="bad-status"),
    pytest.param(["--walk", "{tmp}"], "no walk result here", id="no-walk"),
])
def test_bad_inputs_are_one_line(tmp_path, capsys, args, needle):
    (tmp_path / "bad.json").write_text("{not json")
    paths = {"missing": tmp_path / "none.json", "bad": tmp_path / "bad.json", "tmp": tmp_path}
    argv = [a.format(**paths) for a in args]
    assert main(["commission", "report", "--out", str(tmp_path / "r.html"), *argv,
                 "--key", str(commissioner_key(tmp_path))]) == 2
    assert needle in one_error_line(capsys)
    assert not (tmp_path / "r.html").exists()


def test_the_report_lists_mute_rules_zone_sets_and_the_s_p_warning(tmp_path, synthetic_model,
                                                                  capsys):
    """A cell with a protective zone an operator may mute for 120 s and two zone sets: the
    report names both (with who may mute, who may select), each zone's corners in numbers, and
    warns that S_p is larger than the 1 m station; the verdict and warnings come first."""
    data = yaml.safe_load(demo_cell_path().read_text())
    data["zones"] = [
        {"id": "station-a", "kind": "protective", "shape": "box",
         "min_m": [-2.0, -1.0, 0.0], "max_m": [-1.0, 0.0, 2.2],
         "mute": {"max_s": 120.0, "operators": ["anna"]}},
        {"id": "station-b", "kind": "protective", "shape": "box",
         "min_m": [1.0, -1.0, 0.0], "max_m": [2.0, 0.0, 2.2]},
    ]
    data["sets"] = [{"id": "A", "zones": ["station-a"]}, {"id": "B", "zones": ["station-b"]}]
    data["default_set"] = "A"
    (tmp_path / "cell.yaml").write_text(yaml.safe_dump(data))
    _, _, plc = new_key_pair(tmp_path / "plc.key")
    (tmp_path / "selectors").write_text(f"plc {plc}\n")
    config = tmp_path / "monitor.toml"
    config.write_text(f'[camera]\nsource = "synthetic:demo"\n[model]\npath = "{synthetic_model}"\n'
                      '[zones]\nfile = "cell.yaml"\n[bus]\nselectors_file = "selectors"\n'
                      '[service]\ncommissioners_file = "commissioners"\n')
    html = _report(tmp_path / "report.html", "--config", str(config))
    zones = html[html.index('<section id="zones"'):html.index('<section id="zone-sets"')]
    assert "up to 120 s as warning, by anna" in zones
    assert "Protective zones an operator may mute: station-a." in zones
    assert "corners (-2, -1), (-1, -1), (-1, 0), (-2, 0) m; height 0 to 2.2 m" in zones
    sets = html[html.index('<section id="zone-sets"'):html.index('<section id="pictures"')]
    assert "<td>A</td>" in sets and "<td>B</td>" in sets and "<td>plc</td>" in sets
    assert "<td>station-a</td>" in sets and "default" in sets
    warnings = html[html.index('<section id="warnings"'):html.index('<div class="details">')]
    assert "is larger than the extent of protective zone station-a (1 m)" in warnings
    assert "is larger than the extent of protective zone station-b (1 m)" in warnings
    # (its camera is synthetic:demo: no reference warning, that is for real cameras)
    assert html.index('id="summary"') < html.index('id="warnings"') < html.index('id="zones"')
    assert html.rindex('id="signoff"') > html.rindex('id="not-tested"')
    out = capsys.readouterr().out
    assert "FAIL protective zone station-a: no walk test was given" in out


def test_the_s_p_warning_only_where_s_p_exceeds_the_zone():
    zones = [{"id": "small", "kind": "protective", "enabled": True, "extent_m": 1.0},
             {"id": "large", "kind": "protective", "enabled": True, "extent_m": 20.0},
             {"id": "slow", "kind": "warning", "enabled": True, "extent_m": 1.0}]
    facts = Facts(MonitorConfig(), None, None, [], Path("m.onnx"), False,
                  {"s_p_configured_m": 14.2, "measured": {}}, zones)
    assert separation(facts) == [
        "S_p 14.20 m is larger than the extent of protective zone small (1 m): a person "
        "entering at its edge is nearer the robot than it can stop in (enlarge the zone, or "
        "lower T_r or the programmed speed)"]


def test_the_test_model_on_a_live_camera_and_missing_references_are_warned(tmp_path):
    config = MonitorConfig(cameras=(CameraConfig(id="cam0", source="rtsp://127.0.0.1/x"),
                                    CameraConfig(id="cam1", source="synthetic:demo",
                                                 reference=str(tmp_path / "gone.png"))))
    facts = Facts(config, None, None, [], Path("m.onnx"), True,
                  {"s_p_configured_m": 1.0, "measured": {}}, [])
    lines = open_warnings(facts)
    assert any(w.startswith("the synthetic TEST model watches live camera cam0") for w in lines)
    assert any(w.startswith("camera cam0: no reference image") for w in lines)
    assert f"camera cam1: its reference image {tmp_path / 'gone.png'} is missing" in lines
    assert not any("TEST model" in w for w in open_warnings(
        Facts(config, None, None, [], Path("m.onnx"), False, facts.reaction, [])))
