"""Small traps of `monitor bridge plc`: the `[plc]` extra missing is one line at once (not a
thread traceback and a listen timeout); pymodbus's raw frame dumps stay out of the log; RUN
reads reason 0 with the notes every command carries (the test model, a muted zone)."""

from __future__ import annotations

import signal
import socket
import struct
import subprocess
import sys
import time

from tests.helpers import assert_one_line_error, free_port, wait_for
from tests.plc_kit import ROOT, _env

# pymodbus made unimportable the way a missing package is: `import pymodbus` raises ImportError
WITHOUT_PYMODBUS = ("import sys; sys.modules['pymodbus'] = None; sys.argv[0] = 'monitor'; "
                    "from monitor.cli import main; sys.exit(main(sys.argv[1:]))")


def test_without_the_plc_extra_the_bridge_says_so_in_one_line_at_once():
    start = time.monotonic()
    proc = subprocess.run(
        [sys.executable, "-c", WITHOUT_PYMODBUS, "bridge", "plc", "--unauthenticated",
         "--cell", "c1", "--connect", f"tcp/127.0.0.1:{free_port()}",
         "--modbus-listen", f"127.0.0.1:{free_port()}"],
        cwd=ROOT, env=_env(), capture_output=True, text=True, timeout=60)
    took = time.monotonic() - start
    line = assert_one_line_error(proc, "pymodbus", "workcell-monitor[plc]")
    assert "timed out" not in line and "cannot listen" not in line
    assert "following" not in proc.stderr  # it stopped before any Zenoh session or server
    print(f"\nmissing [plc] extra: exit {proc.returncode} after {took:.2f} s: {line}")


def _request(tid: int, unit: int, pdu: bytes) -> bytes:
    return struct.pack(">HHHB", tid, 0, len(pdu) + 1, unit) + pdu


def test_the_bridge_log_has_no_raw_pymodbus_frame_dumps():
    """Requests pymodbus logs as errors (a device id nobody serves: a datastore traceback plus
    its last raw frames) leave one plain line each in the bridge's log."""
    mport = free_port()
    proc = subprocess.Popen(
        [sys.executable, "-m", "monitor", "bridge", "plc", "--unauthenticated", "--cell", "c1",
         "--connect", f"tcp/127.0.0.1:{free_port()}", "--modbus-listen", f"127.0.0.1:{mport}",
         "--watchdog-ms", "0"],
        cwd=ROOT, env=_env(), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        def up() -> bool:
            assert proc.poll() is None, "the bridge exited"
            with socket.socket() as s:
                return s.connect_ex(("127.0.0.1", mport)) == 0

        assert wait_for(up, 30.0), "the bridge's Modbus server did not come up"
        with socket.create_connection(("127.0.0.1", mport), timeout=20) as s:
            for tid, unit in ((1, 9), (2, 1), (3, 200)):  # 9 and 200: nobody serves them
                s.sendall(_request(tid, unit, struct.pack(">BHH", 3, 0, 5)))
                answer = s.recv(256)
                assert answer[:2] == tid.to_bytes(2, "big"), answer  # each answered
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            _, err = proc.communicate(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            _, err = proc.communicate()
    assert "Datastore unable to fulfill request" in err  # pymodbus's error, as one line
    assert ">>>>>" not in err and "Traceback" not in err and "0x0 0x" not in err, err
