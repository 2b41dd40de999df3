"""The Modbus register map of `monitor bridge plc`, as data (docs/plc.md is checked against it).

One address space of 16-bit holding registers (function codes 3 and 4 read the same values;
6, 16 and 23 write). ``REGISTERS`` is the map; ``render`` turns the newest ``SafetySnapshot``
into the values of the read-only registers at the moment a client reads them; ``check_write``
decides whether a write is accepted (pure functions: the server in ``modbus.py`` only calls
them). Everything that cannot be trusted reads as STOP: no snapshot yet, or a snapshot older
than ``stale_s`` (the adapter's own loop is frozen: ``status`` bit 0).
"""

from __future__ import annotations

from dataclasses import dataclass

from monitor.adapters.snapshot import STATE_CODE, SafetySnapshot

MAP_VERSION = 1
U16 = 0xFFFF

# reason code -> register value (stable: PLC programs compare against these numbers)
REASON_CODES: dict[str, int] = {
    "": 0,  # a clean RUN
    # the adapter overrides the command (consumer rule, or its own loop is frozen)
    "no_command": 1, "ttl": 2, "sequence": 3, "liveliness": 4, "duplicate_monitor": 5,
    "adapter_stale": 6,
    # STOP reasons of the monitor
    "protective_zone": 10, "person_lost": 11, "separation": 12, "fault": 13,
    "detector_error": 14, "frame_timeout": 15, "frame_stale": 16, "pose_stale": 17,
    "zone_invalid": 18, "startup": 19, "shutdown": 20, "stalled": 21, "latched": 22,
    "clearing": 23,
    # SLOW reasons
    "warning_zone": 30, "separation_speed": 31,
}
REASON_OTHER = 999  # a code this map version does not know (read the monitor's docs / log)

# fault name -> bit of the ``faults`` register; bit 15: any other fault
FAULT_BITS: tuple[str, ...] = (
    "camera_lost", "camera_frozen", "camera_blinded", "camera_moved", "camera_defocused",
    "camera_waiting", "detector_error", "detector_overflow", "detector_self_test",
    "tracking_error", "zone_check_error", "zone_invalid", "pose_stale", "health_check_error",
    "duplicate_monitor",
)
FAULT_OTHER_BIT = 15

# bits of the ``status`` register: the adapter's own condition
STATUS_BITS: tuple[str, ...] = (
    "adapter_stale",  # bit 0: the snapshot is older than the stale limit: the state reads STOP
    "plc_watchdog_expired",  # bit 1: the PLC's watchdog register has not changed in time
    "inputs_enabled",  # bit 2: the reset / monitoring-case inputs are on
    "unauthenticated",  # bit 3: the adapter follows unsigned commands (a bench only)
    "no_command",  # bit 4: no verified command since the adapter started
)

RESET_RESULT = {"none": 0, "pending": 1, "accepted": 2, "refused": 3, "no_answer": 4,
                "busy": 5}
CASE_RESULT = RESET_RESULT  # the same codes for a zone set selection
CASE_SETS_OTHER_BIT = 15  # ``case_sets``: a set in force that --case-sets does not list


@dataclass(frozen=True)
class Register:
    address: int
    name: str
    access: str  # "R" read-only, "RW" a PLC writes it
    values: str
    meaning: str


REGISTERS: tuple[Register, ...] = (
    Register(0, "state", "R", "0 STOP, 1 SLOW, 2 RUN",
             "the adapter's verdict (consumer rule), never the raw command"),
    Register(1, "speed_scale", "R", "0..1000 (per mille)", "0 for STOP, 1000 for RUN"),
    Register(2, "latched", "R", "0/1", "the STOP waits for an operator reset"),
    Register(3, "reset_possible", "R", "0/1", "a reset would be accepted now"),
    Register(4, "reason", "R", "REASON_CODES", "why: the adapter's override or the command's "
             "first reason; 999 unknown"),
    Register(5, "zone", "R", "0 none, 1..n, 65535 other",
             "the first reason's zone: its 1-based position in --zone; 65535 not listed"),
    Register(6, "seq", "R", "0..65535", "the last verified command's seq (low 16 bits)"),
    Register(7, "heartbeat", "R", "0..65535, wraps",
             "+1 every adapter tick; STOP when it has not changed within your timeout"),
    Register(8, "command_age_ms", "R", "0..65535 (65535: none / saturated)",
             "age of the last verified command, grows while read (not frozen with the loop)"),
    Register(9, "faults", "R", "bitmap FAULT_BITS", "fault names among the command's reasons"),
    Register(10, "cameras_ok", "R", "bitmap, bit i = i-th --camera",
             "no fault names the camera (all 0 while overridden)"),
    Register(11, "status", "R", "bitmap STATUS_BITS", "the adapter's own condition"),
    Register(12, "snapshot_age_ms", "R", "0..65535 (saturated)",
             "how old the adapter's newest snapshot is: > stale limit reads STOP"),
    Register(13, "map_version", "R", str(MAP_VERSION), "this register map's version"),
    Register(14, "reset_result", "R", "0 none, 1 pending, 2 accepted, 3 refused, "
             "4 no answer, 5 busy", "outcome of the last PLC reset request"),
    Register(15, "reset_count", "R", "0..65535, wraps", "PLC reset requests sent"),
    Register(16, "case_echo", "R", "0 none, 1..n",
             "with --case-key: the --case-sets index the monitor last accepted; without: the "
             "value last written to 34"),
    Register(17, "write_errors", "R", "0..65535, wraps", "writes refused (any client)"),
    Register(18, "case_result", "R", "0 none, 1 pending, 2 accepted, 3 refused, 4 no answer, "
             "5 busy", "outcome of the last zone set selection sent for register 34"),
    Register(19, "case_count", "R", "0..65535, wraps", "zone set selections sent"),
    Register(20, "case_sets", "R", "bitmap, bit i-1 = i-th --case-sets set; bit 15 other",
             "the zone sets the last verified command applies (two while switching; 0 while "
             "overridden)"),
    Register(32, "plc_watchdog", "RW", "any 0..65535",
             "the PLC writes a CHANGED value at least every --watchdog-ms, else an alert"),
    Register(33, "reset_request", "RW", "0/1",
             "rising edge 0 -> 1 sends an operator reset (--inputs, allow-listed client)"),
    Register(34, "monitoring_case", "RW", "0 none, 1..n (--case-sets); 0..255 without",
             "a change selects the n-th --case-sets zone set: one signed selection (--inputs, "
             "--case-key, allow-listed client); without --case-key stored only"),
)
ADDRESS = {r.name: r.address for r in REGISTERS}
SIZE = max(r.address for r in REGISTERS) + 1  # addresses 0..SIZE-1 read (gaps read 0)
WRITABLE = {r.address: r for r in REGISTERS if r.access == "RW"}
VALUE_LIMIT = {ADDRESS["plc_watchdog"]: U16, ADDRESS["reset_request"]: 1,
               ADDRESS["monitoring_case"]: 255}


@dataclass
class AdapterState:
    """What the server knows besides the snapshot (mutated only in the server's thread)."""

    stale_s: float = 0.2
    zones: tuple[str, ...] = ()
    cameras: tuple[str, ...] = ()
    inputs_enabled: bool = False
    unauthenticated: bool = False
    watchdog_expired: bool = False
    reset_result: int = 0
    reset_count: int = 0
    case: int = 0
    case_sets: tuple[str, ...] = ()  # register 34's index 1..n -> set id; () store only
    case_result: int = 0
    case_count: int = 0
    case_latest: int = 0  # the number of the newest selection: older answers are not shown
    write_errors: int = 0
    written: dict[int, int] | None = None  # writable address -> last accepted value


def _ms(value: float) -> int:
    return int(min(U16, max(0.0, value)))


def render(snap: SafetySnapshot | None, now: float, st: AdapterState) -> list[int]:
    """The register values at ``now`` (the adapter's monotonic clock) from the newest snapshot.
    No snapshot, or one older than ``st.stale_s``, reads STOP: a frozen adapter never shows
    its last RUN as fresh."""
    regs = [0] * SIZE
    snap_age = None if snap is None else now - snap.mono
    stale = snap_age is None or snap_age > st.stale_s
    status = (1 << 2) * st.inputs_enabled | (1 << 3) * st.unauthenticated \
        | (1 << 1) * st.watchdog_expired
    if snap is None or snap.seq is None:
        status |= 1 << 4
    if stale:
        status |= 1  # bit 0
    if snap is not None and not stale:
        regs[0] = STATE_CODE[snap.state]
        regs[1] = round(snap.speed_scale * 1000) if snap.state != "STOP" else 0
        regs[4] = REASON_CODES.get(snap.reason_code, REASON_OTHER)
        regs[5] = (st.zones.index(snap.zone_id) + 1 if snap.zone_id in st.zones else U16) \
            if snap.zone_id else 0
        regs[9] = _fault_bits(snap.faults)
        regs[10] = sum(1 << i for i, c in enumerate(st.cameras[:16]) if snap.cameras.get(c))
        regs[3] = int(snap.reset_possible)
        regs[20] = _set_bits(snap.zone_sets, st.case_sets)
    else:
        regs[4] = REASON_CODES["no_command" if snap is None else "adapter_stale"]
    if snap is not None:
        regs[2] = int(snap.latched)
        regs[6] = (snap.seq or 0) & U16
        regs[7] = snap.counter & U16
        regs[8] = U16 if snap.age_ms is None else _ms(snap.age_ms + snap_age * 1000.0)
        regs[12] = _ms(snap_age * 1000.0)
    else:
        regs[8] = regs[12] = U16
    regs[11] = status
    regs[13] = MAP_VERSION
    regs[14] = st.reset_result
    regs[15] = st.reset_count & U16
    regs[16] = st.case
    regs[17] = st.write_errors & U16
    regs[18] = st.case_result
    regs[19] = st.case_count & U16
    for address, value in (st.written or {}).items():
        regs[address] = value
    return regs


def _set_bits(applied: tuple[str, ...], table: tuple[str, ...]) -> int:
    bits = 0
    for s in applied:
        bits |= 1 << (table.index(s) if s in table[:15] else CASE_SETS_OTHER_BIT)
    return bits


def _fault_bits(faults: tuple[str, ...]) -> int:
    bits = 0
    for f in faults:
        bits |= 1 << (FAULT_BITS.index(f) if f in FAULT_BITS else FAULT_OTHER_BIT)
    return bits


# Modbus exception codes the server answers with (a PLC shows them as the error number)
ILLEGAL_FUNCTION = 1  # coil writes, mask write; a write from a client not on the allow-list
ILLEGAL_ADDRESS = 2  # a write touching a read-only register (or inputs that are off)
ILLEGAL_VALUE = 3  # a value out of the register's range


def check_write(address: int, values: list[int], *, allowed_client: bool,
                inputs_enabled: bool, case_limit: int | None = None) -> int | None:
    """None when the write of ``values`` from ``address`` on is accepted, else the Modbus
    exception code. All or nothing: one bad register refuses the whole request.
    ``case_limit``: the number of --case-sets (register 34 then takes 0..that only)."""
    limits = dict(VALUE_LIMIT)
    if case_limit is not None:
        limits[ADDRESS["monitoring_case"]] = case_limit
    inputs = {ADDRESS["reset_request"], ADDRESS["monitoring_case"]}
    for i in range(len(values)):
        a = address + i
        if a not in WRITABLE or (a in inputs and not inputs_enabled):
            return ILLEGAL_ADDRESS
    if not allowed_client:
        return ILLEGAL_FUNCTION
    for i, value in enumerate(values):
        if isinstance(value, bool) or not isinstance(value, int) \
                or not 0 <= value <= limits[address + i]:
            return ILLEGAL_VALUE
    return None


def markdown_table() -> str:
    """The register map as the Markdown table of docs/plc.md (a test checks they agree)."""
    lines = ["| address | name | access | values | meaning |", "|---|---|---|---|---|"]
    lines += [f"| {r.address} | `{r.name}` | {r.access} | {r.values} | {r.meaning} |"
              for r in REGISTERS]
    return "\n".join(lines)


def reasons_table() -> str:
    """REASON_CODES as a Markdown table for docs/plc.md."""
    rows = [f"| {v} | `{k or '(clean RUN)'}` |" for k, v in REASON_CODES.items()]
    return "\n".join(["| value | reason |", "|---|---|", *rows,
                      f"| {REASON_OTHER} | any other code |"])


def bits_table() -> str:
    """FAULT_BITS and STATUS_BITS as a Markdown table for docs/plc.md."""
    rows = [f"| `faults` | {i} | `{n}` |" for i, n in enumerate(FAULT_BITS)]
    rows.append(f"| `faults` | {FAULT_OTHER_BIT} | any other fault |")
    rows += [f"| `status` | {i} | `{n}` |" for i, n in enumerate(STATUS_BITS)]
    return "\n".join(["| register | bit | meaning |", "|---|---|---|", *rows])
