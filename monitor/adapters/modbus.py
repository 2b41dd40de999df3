"""`monitor bridge plc`: a Modbus TCP server that shows the consumer rule's verdict to a PLC.

The register map is data (``modbus_map.py``, docs/plc.md). The server (pymodbus 3.16) runs in
its own thread with its own asyncio loop; ``publish`` only stores the newest snapshot, and the
registers are rendered from it when a client reads them, so a read never waits for the
adapter's loop, and a frozen loop shows as an unchanging heartbeat and a growing
``snapshot_age_ms`` (past ``--stale-ms`` the state reads STOP). Writes are checked against the
map (read-only registers, value ranges, the client allow-list) and refused with a Modbus
exception code. The PLC's watchdog register, and (with ``--inputs``) a reset request and the
monitoring case, are the only inputs; what they cause (an alert on the bus's alert key, an
operator reset signed with the adapter's operator key, a zone set selection signed with the
adapter's selector key: docs/cases.md) runs in a worker thread, never in the server's loop.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import ipaddress
import json
import logging
import queue
import threading
import time
from collections.abc import Callable
from pathlib import Path

from monitor.adapters import modbus_map as mm
from monitor.adapters.snapshot import SafetySnapshot
from monitor.errors import ConfigError
from monitor.types import Alert

log = logging.getLogger("monitor.adapters.plc")

DEFAULT_LISTEN = "127.0.0.1:5020"  # 502 needs root; a PLC can be told any port
WRITE_CODES = frozenset({5, 6, 15, 16, 22, 23})
REGISTER_WRITES = frozenset({6, 16, 23})  # coil writes and mask write are refused

MISSING_EXTRA = ("monitor bridge plc needs pymodbus, which is not installed: pip install "
                 "'workcell-monitor[plc]'")


def _pymodbus():
    """The pymodbus parts the server needs; a one-line ConfigError naming the ``[plc]`` extra
    when it is missing (checked before any thread or Zenoh session starts)."""
    try:
        from pymodbus.simulator import DataType, SimData, SimDevice

        from monitor.adapters import modbus_server
    except ImportError:
        raise ConfigError(MISSING_EXTRA) from None
    modbus_server.quiet_pymodbus()
    return modbus_server, DataType, SimData, SimDevice


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


class ModbusOutput:
    """The Modbus TCP server as an ``Output``. ``on_alert(Alert)``, ``on_reset(peer)`` and
    ``on_case(peer, index)`` are called from the worker thread (they may block briefly: a
    Zenoh put, a reset or selection query). With ``on_case`` and ``state.case_sets`` a change
    of the monitoring case register is a zone set selection; without, it is stored only."""

    name = "plc"

    def __init__(self, host: str = "127.0.0.1", port: int = 5020, *, device_id: int = 1,
                 state: mm.AdapterState | None = None, watchdog_s: float = 1.0,
                 allow: frozenset[str] | None = None,
                 on_alert: Callable[[Alert], None] | None = None,
                 on_reset: Callable[[str], str] | None = None,
                 on_case: Callable[[str, int], str] | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.host, self.port, self.device_id = host, port, device_id
        self.st = state or mm.AdapterState()
        self.st.written = {a: 0 for a in mm.WRITABLE}
        self.watchdog_s = watchdog_s
        self.allow = allow  # None: any client may write the watchdog; inputs need a list
        self.on_alert, self.on_reset, self.on_case = on_alert, on_reset, on_case
        self.clock = clock
        self.latest: SafetySnapshot | None = None
        self.refused: dict[int, int] = {}  # exception code -> count
        self.requests = 0
        self.started = clock()
        self.watchdog_changed: float | None = None
        self._jobs: queue.Queue = queue.Queue(maxsize=16)
        self._loop: asyncio.AbstractEventLoop | None = None
        self._server = None
        self._watchdog_task: asyncio.Task | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._parts: tuple | None = None  # pymodbus, imported by start()
        self._peer: Callable[[], str] = lambda: ""  # the client of the request answered
        self._thread = threading.Thread(target=self._serve, name="plc-modbus", daemon=True)
        self._worker = threading.Thread(target=self._work, name="plc-events", daemon=True)

    # --- Output ----------------------------------------------------------------------------

    def publish(self, snapshot: SafetySnapshot) -> None:
        self.latest = snapshot  # one reference store: never blocks, rendered on read

    def start(self) -> ModbusOutput:
        self._parts = _pymodbus()  # a missing extra: one line, before the server thread
        self._thread.start()
        self._ready.wait(10.0)
        if self._error is not None or not self._ready.is_set():
            raise ConfigError(f"monitor bridge plc: cannot listen on {self.host}:{self.port}: "
                              f"{self._error or 'timed out'}")
        self._worker.start()
        return self

    def close(self) -> None:
        loop, server = self._loop, self._server
        if loop is not None and server is not None and loop.is_running():
            fut = asyncio.run_coroutine_threadsafe(self._shutdown(), loop)
            with contextlib.suppress(Exception):  # best effort; the thread is a daemon
                fut.result(timeout=1.0)
            loop.call_soon_threadsafe(loop.stop)
        self._thread.join(timeout=1.0)
        with contextlib.suppress(queue.Full):
            self._jobs.put_nowait(None)

    # --- the server's thread ---------------------------------------------------------------

    async def _shutdown(self) -> None:
        if self._watchdog_task is not None:
            self._watchdog_task.cancel()
        if self._server is not None:
            await self._server.shutdown()

    def _serve(self) -> None:
        server_module, DataType, SimData, SimDevice = self._parts
        self._peer = server_module.PEER.get
        loop = asyncio.new_event_loop()
        asyncio.set_event_loop(loop)
        self._loop = loop

        async def start() -> None:
            device = SimDevice(self.device_id, simdata=[SimData(
                0, count=mm.SIZE, values=0, datatype=DataType.REGISTERS)], action=self._action)
            self._server = server_module.PipelinedServer(context=[device],
                                                         address=(self.host, self.port))
            await self._server.serve_forever(background=True)
            self._watchdog_task = loop.create_task(self._check_watchdog())

        try:
            loop.run_until_complete(start())
        except BaseException as exc:  # reported by start(); the thread ends
            self._error = exc
            self._ready.set()
            return
        self._ready.set()
        try:
            loop.run_forever()
        finally:
            loop.close()

    async def _action(self, function_code: int, start_address: int, address: int, count: int,
                      registers: list[int], values: list[int] | list[bool] | None):
        """pymodbus calls this on every access, before it reads or writes ``registers``."""
        from pymodbus.constants import ExcCodes

        self.requests += 1
        now = self.clock()
        if values is not None and function_code in WRITE_CODES:
            code = self._write(function_code, address, [int(v) for v in values], now)
            if code is not None:
                self.refused[code] = self.refused.get(code, 0) + 1
                self.st.write_errors += 1
                if self.st.write_errors in (1, 10, 100) or self.st.write_errors % 1000 == 0:
                    log.warning("plc: write of %d value(s) at %d (function %d) from %s refused "
                                "with exception %d (%d refused so far)", len(values), address,
                                function_code, self._peer() or "?", code, self.st.write_errors)
                return ExcCodes(code)
        registers[:mm.SIZE] = mm.render(self.latest, now, self.st)
        return None

    def _write(self, function_code: int, address: int, values: list[int], now: float):
        peer = self._peer()
        if function_code not in REGISTER_WRITES:
            return mm.ILLEGAL_FUNCTION
        listed = self.allow is not None and peer in self.allow
        inputs = {mm.ADDRESS["reset_request"], mm.ADDRESS["monitoring_case"]}
        touches_inputs = any(address + i in inputs for i in range(len(values)))
        # the watchdog: any client unless there is an allow-list; the inputs: listed only
        allowed = listed if (touches_inputs or self.allow is not None) else True
        code = mm.check_write(address, values, allowed_client=allowed,
                              inputs_enabled=self.st.inputs_enabled,
                              case_limit=len(self.st.case_sets) if self.selects else None)
        if code is not None:
            if code == mm.ILLEGAL_FUNCTION:
                log.warning("plc: write to %d refused: client %s not on the allow-list",
                            address, peer or "?")
            return code
        written = self.st.written or {}
        for i, value in enumerate(values):
            a = address + i
            old = written.get(a, 0)
            written[a] = value
            if a == mm.ADDRESS["plc_watchdog"] and value != old:
                self.watchdog_changed = now
            elif a == mm.ADDRESS["reset_request"] and old == 0 and value == 1:
                self._reset_edge(peer)
            elif a == mm.ADDRESS["monitoring_case"] and self.selects and value != old:
                self._case_change(peer, old, value)
            elif a == mm.ADDRESS["monitoring_case"] and not self.selects \
                    and value != self.st.case:
                log.warning("plc: client %s set the monitoring case %d -> %d (no --case-key: "
                            "stored only)", peer, self.st.case, value)
                self.st.case = value
        return None

    @property
    def selects(self) -> bool:
        """Register 34 selects zone sets (else it is stored only)."""
        return self.on_case is not None and bool(self.st.case_sets)

    def _case_change(self, peer: str, old: int, value: int) -> None:
        if value == 0:  # "no selection": nothing to send, the monitor keeps its sets
            log.warning("plc: client %s set the monitoring case %d -> 0 (no selection: "
                        "nothing sent; the monitor keeps the set in force)", peer, old)
            return
        self.st.case_count += 1
        self.st.case_latest += 1
        self.st.case_result = mm.CASE_RESULT["pending"]
        log.warning("plc: client %s selects zone set %d (%s), was %d", peer, value,
                    self.st.case_sets[value - 1], old)
        self._submit(("case", (peer, value, self.st.case_latest)))
    def _reset_edge(self, peer: str) -> None:
        if self.st.reset_result == mm.RESET_RESULT["pending"]:
            log.warning("plc: reset request from %s ignored: the previous one is pending", peer)
            return
        self.st.reset_count += 1
        self.st.reset_result = mm.RESET_RESULT["pending"]
        log.warning("plc: reset request from client %s (an operator action)", peer)
        self._submit(("reset", peer))

    async def _check_watchdog(self) -> None:
        while True:
            await asyncio.sleep(0.05)
            if self.watchdog_s <= 0:
                continue
            since = self.watchdog_changed if self.watchdog_changed is not None else self.started
            expired = self.clock() - since > self.watchdog_s
            if expired and not self.st.watchdog_expired:
                what = "never written" if self.watchdog_changed is None else "not changed"
                self._submit(("alert", Alert(
                    "plc_watchdog", "warning", f"the PLC's watchdog register was {what} for "
                    f"{self.watchdog_s:g} s: the PLC may not be following the monitor",
                    "plc", self.clock(), details={"watchdog_s": self.watchdog_s})))
            elif not expired and self.st.watchdog_expired:
                log.warning("plc: the PLC's watchdog register changes again")
            self.st.watchdog_expired = expired

    # --- the worker thread -----------------------------------------------------------------

    def _submit(self, job) -> None:
        try:
            self._jobs.put_nowait(job)
        except queue.Full:
            log.error("plc: event queue full, dropped %s", job[0])
            if job[0] == "reset":
                self.st.reset_result = mm.RESET_RESULT["busy"]
            elif job[0] == "case":
                self.st.case_result = mm.CASE_RESULT["busy"]

    def _work(self) -> None:
        while (job := self._jobs.get()) is not None:
            kind, item = job
            try:
                if kind == "alert":
                    if self.on_alert:
                        self.on_alert(item)  # logs and publishes
                    else:
                        log.warning("plc alert %s: %s", item.kind, item.message)
                elif kind == "reset":
                    result = self.on_reset(item) if self.on_reset else "refused"
                    self.st.reset_result = mm.RESET_RESULT.get(result, 3)
                elif kind == "case":
                    self._case_answer(item, self.on_case(item[0], item[1]))
            except Exception as exc:  # a failing put or query never stops the worker
                log.error("plc: %s failed: %s", kind, exc)
                if kind == "reset":
                    self.st.reset_result = mm.RESET_RESULT["no_answer"]
                elif kind == "case":
                    self._case_answer(item, "no_answer")

    def _case_answer(self, job: tuple[str, int, int], outcome: str) -> None:
        _peer, index, number = job
        if number != self.st.case_latest:
            return  # a newer selection is on its way: its answer is the one to show
        self.st.case_result = mm.CASE_RESULT.get(outcome, mm.CASE_RESULT["refused"])
        if outcome == "accepted":
            self.st.case = index


# --- the command line ------------------------------------------------------------------------


def add_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("Modbus TCP server (docs/plc.md)")
    g.add_argument("--modbus-listen", default=DEFAULT_LISTEN, metavar="HOST:PORT",
                   help=f"address of the Modbus TCP server (default {DEFAULT_LISTEN})")
    g.add_argument("--allow-network", action="store_true",
                   help="allow a non-loopback --modbus-listen (default off: loopback only)")
    g.add_argument("--device-id", type=int, default=1,
                   help="Modbus unit / device id the map answers on (default 1)")
    g.add_argument("--zone", action="append", default=[], dest="zones", metavar="ID",
                   help="zone ids in the order of the zone register's index (repeatable)")
    g.add_argument("--stale-ms", type=float, default=200.0,
                   help="a snapshot older than this reads STOP (the adapter's loop is frozen; "
                   "default 200)")
    g.add_argument("--watchdog-ms", type=float, default=1000.0,
                   help="alert when the PLC's watchdog register has not changed for this long "
                   "(default 1000; 0 off)")
    g.add_argument("--allow-client", action="append", default=[], metavar="IP",
                   help="client address allowed to write (repeatable; default: any client may "
                   "write the watchdog, none the inputs)")
    g.add_argument("--inputs", action="store_true",
                   help="accept the reset request and monitoring case registers from "
                   "--allow-client addresses (default off)")
    g.add_argument("--reset-operator", metavar="NAME",
                   help="operator id a PLC reset is sent as (needed for the reset input)")
    g.add_argument("--reset-key", metavar="FILE",
                   help="that operator's private key (monitor keys new --operator NAME)")
    g.add_argument("--reset-timeout", type=float, default=3.0,
                   help="s to wait for the monitor's answer to a PLC reset (default 3)")
    g.add_argument("--case-key", metavar="FILE",
                   help="a selector's private key: register 34 then selects zone sets "
                   "(docs/cases.md; default: register 34 is stored only)")
    g.add_argument("--case-selector", metavar="NAME",
                   help="that selector's name, as in the monitor's selectors file")
    g.add_argument("--case-sets", metavar="A,B,C",
                   help="zone set ids in the order of register 34's index 1..n (0: no "
                   "selection)")
    g.add_argument("--case-timeout", type=float, default=3.0,
                   help="s to wait for the monitor's answer to a selection (default 3)")


def check_arguments(args: argparse.Namespace) -> None:
    """Called by `monitor bridge` before Zenoh opens: a missing ``[plc]`` extra fails at once."""
    _pymodbus()


def make_outputs(args: argparse.Namespace, session, keys) -> list:
    from monitor.pose.stream import parse_host_port

    host, port = parse_host_port(args.modbus_listen, 5020)
    if not is_loopback(host) and not args.allow_network:
        raise ConfigError(f"--modbus-listen {args.modbus_listen}: not a loopback address; "
                          "give --allow-network to serve the network")
    if not 0 <= args.device_id <= 247 or args.stale_ms <= 0 or args.watchdog_ms < 0:
        raise ConfigError("monitor bridge plc: --device-id must be 0..247, --stale-ms > 0 and "
                          "--watchdog-ms >= 0")
    if args.inputs and not args.allow_client:
        raise ConfigError("monitor bridge plc: --inputs needs --allow-client IP (the PLC's "
                          "address): inputs are never open to any client")
    for ip in args.allow_client:
        try:
            ipaddress.ip_address(ip)
        except ValueError:
            raise ConfigError(f"--allow-client {ip!r}: not an IP address") from None
    case_sets = parse_case_sets(args)
    signer = case_signer = None
    # the monitor's answers to the PLC's resets are believed only when it signed them for that
    # request (a rogue's "accepted" would read 2 in reset_result while the cell stays latched)
    monitor_keys = None
    if args.inputs:
        from monitor.wire.signing import load_private_key, load_public_key

        monitor_keys = tuple(load_public_key(k) for k in args.monitor_key) or None

        if (args.reset_operator or args.reset_key or not case_sets) \
                and (not args.reset_operator or not args.reset_key):
            raise ConfigError("monitor bridge plc: --inputs needs --reset-operator NAME and "
                              "--reset-key FILE (a PLC reset is an operator's signed reset), "
                              "or --case-key for zone set selections only")
        if args.reset_key:
            signer = load_private_key(Path(args.reset_key))
        if case_sets:
            case_signer = load_private_key(Path(args.case_key))
    alerts = AlertSender(session, keys, args.instance or "plc", getattr(args, "ttl_ms", 1000))
    cell = args.cell if not getattr(args, "prefix", None) else ""
    state = mm.AdapterState(stale_s=args.stale_ms / 1000.0, zones=tuple(args.zones),
                            cameras=tuple(args.cameras), inputs_enabled=args.inputs,
                            unauthenticated=args.unauthenticated, case_sets=case_sets)

    def reset(peer: str) -> str:
        outcome, reason = send_reset(session, keys, signer, args.reset_operator, cell, peer,
                                     args.reset_timeout, monitor_keys)
        alerts(Alert("plc_reset", "warning", f"PLC reset request from {peer} as operator "
                     f"{args.reset_operator}: {outcome}: {reason}", "plc", time.monotonic(),
                     details={"peer": peer, "operator": args.reset_operator,
                              "outcome": outcome}))
        return outcome

    selection = CaseSelection(session, case_key(keys.pose[:-len("tracker/pose")]),
                              case_signer, args.case_selector or "", cell, case_sets,
                              args.case_timeout, alerts, monitor_keys) if case_signer else None
    out = ModbusOutput(host, port, device_id=args.device_id, state=state,
                       watchdog_s=args.watchdog_ms / 1000.0,
                       allow=frozenset(args.allow_client) or None,
                       on_alert=alerts, on_reset=reset if signer else None,
                       on_case=selection)
    return [out.start()]


def parse_case_sets(args: argparse.Namespace) -> tuple[str, ...]:
    """--case-sets as register 34's table (index 1..n), checked with the other --case-*
    options: all three or none, and only with --inputs."""
    given = [args.case_key, args.case_selector, args.case_sets]
    if not any(given):
        return ()
    if not all(given):
        raise ConfigError("monitor bridge plc: --case-key FILE, --case-selector NAME and "
                          "--case-sets A,B,... go together")
    if not args.inputs:
        raise ConfigError("monitor bridge plc: --case-key needs --inputs (and --allow-client "
                          "IP): register 34 is an input")
    sets = tuple(s.strip() for s in args.case_sets.split(","))
    if not all(sets) or len(set(sets)) != len(sets) or len(sets) > 255:
        raise ConfigError(f"--case-sets {args.case_sets!r}: give 1..255 distinct, non-empty "
                          "zone set ids separated by commas")
    if not 0 < args.case_timeout <= 60:
        raise ConfigError("monitor bridge plc: --case-timeout must be in (0, 60] s")
    return sets


def case_key(prefix: str) -> str:
    from monitor.cases.receiver import case_key as key

    return key(prefix)


class CaseSelection:
    """Register 34's index -> one signed zone set selection, sent as `monitor case select`
    sends it (called in the worker thread). seq starts at the wall clock's milliseconds and
    grows by at least one per selection, so a restarted adapter's seq is above its last run's.
    A refused or unanswered selection is an alert; every outcome is logged."""

    def __init__(self, session, key: str, signer, selector: str, cell: str,
                 sets: tuple[str, ...], timeout: float, alerts: Callable[[Alert], None],
                 monitor_keys: tuple | None = None) -> None:
        self.session, self.key, self.signer, self.selector = session, key, signer, selector
        self.cell, self.sets, self.timeout, self.alerts = cell, sets, timeout, alerts
        self.monitor_keys = monitor_keys  # only the monitor's signed answer is believed
        self.seq = int(time.time() * 1000) - 1

    def __call__(self, peer: str, index: int) -> str:
        from monitor.cases.receiver import request_case
        from monitor.cases.requests import case_payload

        set_id = self.sets[index - 1]
        self.seq = max(self.seq + 1, int(time.time() * 1000))
        payload = case_payload(self.selector, set_id, self.seq, cell=self.cell)
        try:
            answer = request_case(self.session, self.key, payload,
                                  self.signer.sign(self.key, payload), self.timeout,
                                  self.monitor_keys)
        except Exception as exc:  # a closed session: no answer
            answer, why = None, f"{type(exc).__name__}: {exc}"
        else:
            why = f"no monitor answered on {self.key} within {self.timeout:g} s"
        if answer is None:
            outcome, reason = "no_answer", why
        else:
            outcome = "accepted" if answer["accepted"] else "refused"
            reason = str(answer.get("reason", ""))
        text = (f"PLC zone set selection {index} ({set_id!r}) from {peer} as selector "
                f"{self.selector} (seq {self.seq}): {outcome}: {reason}")
        if outcome == "accepted":
            log.warning("plc: %s", text)
        else:
            self.alerts(Alert("plc_case", "warning", text, "plc", time.monotonic(),
                              details={"peer": peer, "selector": self.selector,
                                       "set": set_id, "index": index, "seq": self.seq,
                                       "outcome": outcome}))
        return outcome


class AlertSender:
    """Alerts of the adapter on the bus's alert key (the envelope `monitor bridge otus` uses:
    unsigned, ``source`` "plc"); every alert is also logged."""

    def __init__(self, session, keys, instance: str, ttl_ms: float) -> None:
        self.session, self.key, self.instance, self.ttl_ms = session, keys.alert, instance, ttl_ms
        self.seq = 0
        self.lock = threading.Lock()

    def __call__(self, alert: Alert) -> None:
        from monitor.bus.session import ALERT_SCHEMA
        from monitor.wire.alerts import alert_to_dict

        log.warning("alert %s: %s", alert.kind, alert.message)
        with self.lock:
            self.seq += 1
            body = {"schema": ALERT_SCHEMA, "seq": self.seq, "mono": time.monotonic(),
                    "wall": time.time(), "ttl_ms": self.ttl_ms, "config_hash": "",
                    "instance": self.instance, "boot": str(self.session.zid()),
                    **alert_to_dict(alert)}
        self.session.put(self.key, json.dumps(body, default=str).encode())


def send_reset(session, keys, signer, operator: str, cell: str, peer: str,
               timeout: float, monitor_keys: tuple | None = None) -> tuple[str, str]:
    """An operator reset for the latch the monitor publishes now, signed with ``signer``:
    ("accepted" | "refused" | "no_answer", reason). The monitor checks it like any reset.
    ``monitor_keys`` (``--monitor-key``): only the monitor's signed answer to this request is
    believed (others are ignored, and said in the no-answer reason)."""
    from monitor.wire.answers import ignored_text
    from monitor.wire.resets import latch_of_status, request_reset, reset_payload

    status = None
    for reply in session.get(keys.status, timeout=timeout):
        if reply.ok is not None:
            try:
                status = json.loads(reply.ok.payload.to_bytes())
            except (ValueError, UnicodeDecodeError):
                continue
            if isinstance(status, dict):
                break
    if not isinstance(status, dict):
        return "no_answer", f"no monitor answered on {keys.status}"
    boot, latch = latch_of_status(status)
    if latch is None:
        return "refused", f"nothing to reset: the monitor is not latched ({status.get('state')})"
    payload = reset_payload(operator, note=f"PLC reset request from {peer} (monitor bridge plc)",
                            cell=cell, boot=boot, latch=latch)
    ignored: list[str] = []
    answer = request_reset(session, keys.reset, payload, signer.sign(keys.reset, payload),
                           timeout, monitor_keys, ignored)
    if answer is None:
        return "no_answer", f"no monitor answered on {keys.reset}" + (
            f" with an answer signed by --monitor-key; {ignored_text(ignored)}" if ignored
            else "")
    return ("accepted" if answer["accepted"] else "refused"), str(answer.get("reason", ""))
