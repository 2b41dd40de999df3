"""The PLC adapter as the tests run it: a pymodbus client, `monitor bridge plc` as a
process, and stopping it."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
from pathlib import Path

from pymodbus.client import ModbusTcpClient

from monitor.adapters import modbus_map as mm
from tests.helpers import WAIT_CEILING, wait_for

CELL = "plc"


TTL_MS = 300


ROOT = Path(__file__).resolve().parents[1]


def _env() -> dict:
    return {**os.environ, "PYTHONPATH": str(ROOT)}


class Plc:
    """A pymodbus client as a PLC would use it: read the map, write the watchdog."""

    def __init__(self, port: int) -> None:
        self.client = ModbusTcpClient("127.0.0.1", port=port, timeout=2, retries=0)
        self.client.connect()

    def read(self) -> list[int] | None:
        try:
            r = self.client.read_holding_registers(0, count=mm.SIZE, device_id=1)
        except Exception:
            self.client.connect()
            return None
        return None if r.isError() else list(r.registers)

    def write(self, address: int, *values: int):
        if len(values) == 1:
            return self.client.write_register(address, values[0], device_id=1)
        return self.client.write_registers(address, list(values), device_id=1)

    def wait(self, cond, timeout: float = WAIT_CEILING) -> list[int] | None:
        return wait_for(lambda: (r := self.read()) is not None and cond(r) and r, timeout)

    def close(self) -> None:
        self.client.close()


def start_adapter(zport: int, mport: int, pub: Path, *extra: str) -> subprocess.Popen:
    proc = subprocess.Popen(
        [sys.executable, "-m", "monitor", "bridge", "plc", "--connect",
         f"tcp/127.0.0.1:{zport}", "--cell", CELL, "--monitor-key", str(pub),
         "--ttl-ms", str(TTL_MS), "--modbus-listen", f"127.0.0.1:{mport}", "--zone", "P",
         "--zone", "W", "--camera", "cam0", *extra],
        cwd=ROOT, env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)

    def up() -> bool:
        if proc.poll() is not None:
            raise AssertionError(f"the adapter exited: {proc.communicate()[1]}")
        with socket.socket() as s:
            return s.connect_ex(("127.0.0.1", mport)) == 0

    assert wait_for(up, 30.0), "the adapter's Modbus server did not come up"
    return proc


def stop_process(proc: subprocess.Popen) -> str:
    if proc.poll() is None:
        proc.send_signal(signal.SIGCONT)
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)
    return proc.stderr.read() if proc.stderr else ""
