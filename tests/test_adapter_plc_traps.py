"""Small traps of `monitor bridge plc`: the `[plc]` extra missing is one line at once (not a
thread traceback and a listen timeout); pymodbus's raw frame dumps stay out of the log; RUN
reads reason 0 with the notes every command carries (the test model, a muted zone)."""

from __future__ import annotations

import subprocess
import sys
import time

from tests.helpers import assert_one_line_error, free_port
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
