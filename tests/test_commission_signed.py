"""Signed, whole-file evidence (issue 47): the commissioning report and commissioned.json are
signed over every byte with a commissioner's Ed25519 key, `commission verify` names the signer
and fails on any change (a line with id="checksum" too), a record that is forged, changed or
signed by a key that is not a commissioner's is refused, the fingerprint names every file the
config points to, and a running monitor takes a new signed record without a restart."""

from __future__ import annotations

import json
import os
from pathlib import Path

import cv2
import numpy as np
import pytest

from monitor.cli import main
from monitor.commission.report import REPORT_LAYOUT, verify
from monitor.config import load_config
from monitor.service.commissioned import (
    RECORD_LAYOUT,
    RECORD_NAME,
    fingerprint,
    record_bytes,
    status_of,
    write_record,
)
from monitor.service.setup import zones_file_of
from monitor.wire.evidence import Layout, NotSigned, open_signed, sign
from monitor.wire.signing import load_private_key, new_key_pair
from monitor.zones import load_cell
from tests.helpers import commissioner_key
from tests.processes import Service, wait_for

SMALL = Layout("test", b"<k>", b"</k><s>", b"</s>\n")


def _opened_or_refused(data: bytes, layout: Layout) -> bool:
    """True when ``data`` opens with a valid signature."""
    try:
        return open_signed(data, layout).valid
    except NotSigned:
        return False


def test_every_byte_of_a_signed_file_is_covered(tmp_path):
    signer = load_private_key(new_key_pair(tmp_path / "k")[0])
    data = sign(b"<p>zone A: protective</p>\n", SMALL, signer)
    assert _opened_or_refused(data, SMALL)
    for i in range(len(data)):  # each byte changed, removed, and a byte added before it
        flipped = data[:i] + bytes([data[i] ^ 0x01]) + data[i + 1:]
        assert not _opened_or_refused(flipped, SMALL), i
        assert not _opened_or_refused(data[:i] + data[i + 1:], SMALL), i
        assert not _opened_or_refused(data[:i] + b"x" + data[i:], SMALL), i
    assert not _opened_or_refused(data + b"\n", SMALL)
    # the signature of one purpose is not valid for another (a report's as a record's)
    other = Layout("other", SMALL.key_open, SMALL.mid, SMALL.tail)
    assert not _opened_or_refused(data, other)


@pytest.fixture(scope="module")
def cell_dir(tmp_path_factory, synthetic_model):
    """A config with every kind of file the fingerprint covers, its commissioner, a report and
    its record."""
    tmp = tmp_path_factory.mktemp("signed")
    image = np.full((240, 320, 3), 80, np.uint8)
    cv2.imwrite(str(tmp / "ref.png"), image)
    (tmp / "zenoh.json5").write_text("{}\n")
    _, _, op = new_key_pair(tmp / "anna.key")
    (tmp / "operators").write_text(f"anna {op}\n")
    _, _, sel = new_key_pair(tmp / "plc.key")
    (tmp / "selectors").write_text(f"plc {sel}\n")
    new_key_pair(tmp / "monitor.key")
    key = commissioner_key(tmp, "carla")
    (tmp / "monitor.toml").write_text(
        f'[camera]\nsource = "synthetic:demo"\nreference = "ref.png"\n'
        f'[model]\npath = "{synthetic_model}"\n'
        '[bus]\noperators_file = "operators"\nselectors_file = "selectors"\n'
        'signing_key = "monitor.key"\nzenoh_config_file = "zenoh.json5"\n'
        '[service]\ncommissioners_file = "commissioners"\n')
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("WORKCELL_MONITOR_HOME", str(tmp_path_factory.getbasetemp() / "monitor-home"))
        assert main(["commission", "report", "--config", str(tmp / "monitor.toml"), "--key",
                     str(key), "--out", str(tmp / "report.html")]) == 0
    return tmp, key


def _running(folder: Path, synthetic_model) -> dict:
    config = load_config(folder / "monitor.toml")
    zones = zones_file_of(config)
    cell = load_cell(zones) if zones else None
    return fingerprint(config, cell.config_hash if cell else "", synthetic_model, cell)


def test_verify_names_the_signer_and_fails_on_any_change(cell_dir, tmp_path, capsys):
    folder, key = cell_dir
    report = folder / "report.html"
    config = folder / "monitor.toml"
    assert main(["commission", "verify", str(report), "--config", str(config)]) == 0
    assert "signed by commissioner carla" in capsys.readouterr().out
    assert main(["commission", "verify", str(report), "--key", f"{key}.pub"]) == 0
    assert "signed by carla" in capsys.readouterr().out
    html = report.read_bytes()
    # the attacks of the last trial, and more: every one fails
    forged = {
        "hide-warnings": html.replace(b"<head>", b'<head>\n<style id="checksum">#warnings li'
                                      b"{display:none}</style>", 1),
        "passed-line": html.replace(b"<body>", b'<body>\n<p id="checksum">Walk test PASSED'
                                    b"</p>", 1),
        "removed-line": html.replace(b"<h2>Sign-off</h2>\n", b"", 1),
        "changed-byte": html.replace(b"protective", b"protectivE", 1),
        "appended": html + b"<p>ok</p>\n",
        "cut": html[:-1],
    }
    for name, data in forged.items():
        assert data != html, name
        path = tmp_path / f"{name}.html"
        path.write_bytes(data)
        assert main(["commission", "verify", str(path)]) == 1, name
        assert "CHANGED" in capsys.readouterr().out, name
    # re-signed by someone else: intact, but not the commissioner's
    rogue = load_private_key(new_key_pair(tmp_path / "rogue.key")[0])
    opened = verify(html)
    resigned = tmp_path / "resigned.html"
    resigned.write_bytes(sign(opened.body.replace(b"protective", b"protectivE", 1),
                              REPORT_LAYOUT, rogue))
    assert main(["commission", "verify", str(resigned)]) == 0  # only intact, says so
    assert "pass --key PUB or --config" in capsys.readouterr().out
    assert main(["commission", "verify", str(resigned), "--config", str(config)]) == 1
    assert "NOT A COMMISSIONER" in capsys.readouterr().out
    assert main(["commission", "verify", str(resigned), "--key", f"{key}.pub"]) == 1
    assert "OTHER KEY" in capsys.readouterr().out


def test_a_forged_or_foreign_record_is_refused(cell_dir, tmp_path, synthetic_model):
    folder, _ = cell_dir
    running = _running(folder, synthetic_model)
    config = folder / "monitor.toml"
    ok = status_of(config, running)
    assert ok["matches"] is True and ok["by"] == "carla", ok
    record = folder / RECORD_NAME
    original = record.read_bytes()
    try:
        # the trial's forgery: zones_hash edited to the running one -> signature fails
        body = json.loads(original)
        record.write_bytes(original.replace(body["record"]["zones_hash"].encode(), b"0" * 16))
        forged = status_of(config, running)
        assert forged["matches"] is False and "changed after it was signed" in forged["reason"]
        # signed properly, but by a key that is not in the commissioners file
        rogue = load_private_key(new_key_pair(tmp_path / "rogue.key")[0])
        write_record(record, record_bytes(b"report", "report.html", "carla", running, rogue))
        foreign = status_of(config, running)
        assert foreign["matches"] is False and "not listed in the commissioners" in \
            foreign["reason"]
        # an unsigned record (the old format) is not accepted either
        record.write_text(json.dumps({"checksum": "x", "by": "anna", **running}))
        assert "not signed" in status_of(config, running)["reason"]
    finally:
        record.write_bytes(original)
    assert open_signed(original, RECORD_LAYOUT).valid
    json.loads(original)  # and it is plain JSON to read


@pytest.mark.parametrize("name, label", [
    ("operators", "bus.operators_file"),
    ("selectors", "bus.selectors_file"),
    ("monitor.key", "bus.signing_key"),
    ("zenoh.json5", "bus.zenoh_config_file"),
    ("ref.png", "camera[cam0].reference"),
    ("commissioners", "service.commissioners_file"),
])
def test_a_changed_file_the_config_names_is_not_commissioned(cell_dir, synthetic_model, name,
                                                             label):
    folder, _ = cell_dir
    path = folder / name
    original = path.read_bytes()
    try:
        if name == "ref.png":
            cv2.imwrite(str(path), np.full((240, 320, 3), 81, np.uint8))
        else:
            path.write_bytes(original + b"# added\n" if name != "monitor.key" else
                             original.replace(b"-----END", b"\n-----END"))
        os.chmod(path, 0o600 if name == "monitor.key" else 0o644)
        status = status_of(folder / "monitor.toml", _running(folder, synthetic_model))
        assert status["matches"] is False and status["differs"] == [label], status
        assert f"not commissioned: {label} differs" in status["reason"]
    finally:
        path.write_bytes(original)
    assert status_of(folder / "monitor.toml", _running(folder, synthetic_model))["matches"]


def test_keys_new_commissioner_prints_the_commissioners_line(tmp_path, capsys):
    assert main(["keys", "new", str(tmp_path / "c.key"), "--commissioner", "carla"]) == 0
    out = capsys.readouterr().out
    assert "commissioners file ([service] commissioners_file)" in out
    assert "carla ed25519:" in out
    assert main(["keys", "new", str(tmp_path / "d.key"), "--commissioner", "c",
                 "--operator", "o"]) == 2


@pytest.mark.slow
def test_a_running_monitor_takes_a_new_record_and_refuses_a_foreign_one(tmp_path,
                                                                       synthetic_model):
    svc = Service(tmp_path, synthetic_model, "synthetic:demo",
                  'commissioners_file = "commissioners"\n')
    key = commissioner_key(tmp_path, "carla")
    rogue = tmp_path / "rogue.key"
    new_key_pair(rogue)

    def report(with_key: Path) -> None:
        assert main(["commission", "report", "--config", str(svc.config), "--key",
                     str(with_key), "--out", str(tmp_path / "report.html")]) == 0

    # a record signed by a key that is no commissioner's: refused at start
    (tmp_path / "commissioners.real").write_bytes((tmp_path / "commissioners").read_bytes())
    (tmp_path / "commissioners").write_text(f"rogue {(tmp_path / 'rogue.key.pub').read_text()}")
    report(rogue)
    (tmp_path / "commissioners").write_bytes((tmp_path / "commissioners.real").read_bytes())
    with svc:
        wait_for(lambda: svc.commands, 60, "a command", svc)
        first = wait_for(lambda: (s := svc.status()).get("commissioned") and s, 30,
                         "the commissioned field", svc)["commissioned"]
        assert first["matches"] is False and "not listed in the commissioners" in \
            first["reason"], first
        assert "not commissioned" in svc.stderr_path.read_text()
        # the commissioner signs a new record: in force without a restart
        report(key)
        now = wait_for(lambda: (c := svc.status()["commissioned"]).get("matches") and c, 30,
                       "the new record in force", svc)
        assert now["by"] == "carla"
        assert '"event": "commissioned"' in svc.stderr_path.read_text()  # logged as it came
        # an operator added while it runs: not commissioned, naming the file
        with (tmp_path / "operators").open("a") as fh:
            fh.write(f"eve {new_key_pair(tmp_path / 'eve.key')[2]}\n")
        changed = wait_for(lambda: not (c := svc.status()["commissioned"]).get("matches")
                           and c, 30, "the operators file change seen", svc)
        assert changed["differs"] == ["bus.operators_file"], changed


def test_verify_takes_the_record_and_checks_the_report_it_names(cell_dir, tmp_path, capsys):
    folder, _ = cell_dir
    record = folder / RECORD_NAME
    assert main(["commission", "verify", str(record), "--config",
                 str(folder / "monitor.toml")]) == 0
    out = capsys.readouterr().out
    assert "the report report.html beside it is the one it names" in out
    assert "signed by commissioner carla" in out
    copy = tmp_path / RECORD_NAME
    copy.write_bytes(record.read_bytes())
    (tmp_path / "report.html").write_bytes((folder / "report.html").read_bytes() + b" ")
    assert main(["commission", "verify", str(copy)]) == 1
    assert "is not the report this record names" in capsys.readouterr().out
    copy.write_bytes(record.read_bytes().replace(b'"by": "carla"', b'"by": "eve"'))
    assert main(["commission", "verify", str(copy)]) == 1
    assert "CHANGED" in capsys.readouterr().out
