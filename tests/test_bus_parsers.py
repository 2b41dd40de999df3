"""Every parser of bus input refuses hostile JSON as invalid, with a reason, and no exception
escapes: deep nesting, 1e400, 10**400, NaN, Infinity, huge strings, wrong types, in the whole
payload and in each field (monitor/wire/payload.py, the one bounded decoder they share). The
holds messages are validly signed, so the hostile body reaches the parser (as the 176 of
10,000 that raised did). A bounded property test mixes random JSON and random bytes; heavier
fuzzing is ``benchmarks/fuzz.py``."""

from __future__ import annotations

import json
from collections.abc import Callable

import pytest
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from monitor.bus.holds import HoldsGate, holds_payload
from monitor.cases.mute_requests import MuteGate, MuteRefused, mute_payload
from monitor.cases.requests import CaseGate, CasePolicy, CaseRefused, case_payload
from monitor.cases.zone_apply import ApplyGate, ApplyRefused, apply_payload
from monitor.tracking.handover import Entry
from monitor.wire import payload as pj
from monitor.wire.busconfig import BusKeys
from monitor.wire.consumer import COMMAND_SCHEMA, InvalidCommand, parse_command
from monitor.wire.resets import ResetGate, ResetPolicy, ResetRefused, reset_payload
from monitor.wire.signing import Signer

CELL, BOOT, PREFIX = "c1", "b1", "workcell/c1/"
KEYS = BusKeys.of(PREFIX)
OPERATOR = Ed25519PrivateKey.generate()
PEER = Ed25519PrivateKey.generate()
PEERS = {"anna": OPERATOR.public_key()}
WALL = 1.7e9


# ---- each parser: (base payload, run) where run(payload) -> refusal reason, or None --------

def _gate_run(check: Callable[[bytes, bytes], object], refused: type[ValueError],
              key_expr: str) -> Callable[[bytes], str | None]:
    def run(payload: bytes) -> str | None:
        try:
            check(payload, Signer(OPERATOR).sign(key_expr, payload))
        except refused as exc:
            return str(exc) or type(exc).__name__
        return None
    return run


def _command():
    body = {"schema": COMMAND_SCHEMA, "cell": CELL, "instance": "m", "boot": BOOT, "seq": 5,
            "state": "SLOW", "speed_scale": 0.5, "ttl_ms": 300, "wall": WALL}

    def run(payload: bytes) -> str | None:
        try:
            parse_command(payload)
        except InvalidCommand as exc:
            return str(exc) or "invalid"
        return None
    return json.dumps(body).encode(), run


def _reset():
    gate = ResetGate(ResetPolicy(PEERS, CELL, KEYS.reset))
    return (reset_payload("anna", cell=CELL, boot=BOOT, latch="n1", wall=WALL),
            _gate_run(lambda p, s: gate.check(p, s, 0.0, WALL, boot=BOOT, latch="n1"),
                      ResetRefused, KEYS.reset))


def _mute():
    gate = MuteGate(PEERS, CELL, KEYS.mute)
    return (mute_payload("anna", "P", 10.0, cell=CELL, boot=BOOT, wall=WALL),
            _gate_run(lambda p, s: gate.check(p, s, 0.0, WALL, boot=BOOT), MuteRefused,
                      KEYS.mute))


def _apply():
    gate = ApplyGate(PEERS, CELL, KEYS.zones_apply)
    return (apply_payload("anna", "0123abcd" * 8, cell=CELL, boot=BOOT, wall=WALL),
            _gate_run(lambda p, s: gate.check(p, s, 0.0, WALL, boot=BOOT), ApplyRefused,
                      KEYS.zones_apply))


def _case():
    gate = CaseGate(CasePolicy({"anna": OPERATOR.public_key()}, CELL, KEYS.case))
    return (case_payload("anna", "B", 1, cell=CELL, wall=WALL),
            _gate_run(lambda p, s: gate.check(p, s, WALL), CaseRefused, KEYS.case))


def _holds():
    gate = HoldsGate(CELL, PREFIX, "monitor-b", {"monitor-a": PEER.public_key()},
                     verify_per_s=1e9, cold_per_s=1e9)  # every message reaches the parser
    key_expr = BusKeys.of(PREFIX, "monitor-a").holds
    seqs = iter(range(1, 10**9))

    def run(payload: bytes) -> str | None:
        before = dict(gate.counts())
        out = gate.check(key_expr, payload, Signer(PEER).sign(key_expr, payload), 0.0, WALL)
        if out is not None:
            return None
        after = gate.counts()
        kind = next(k for k in after if after[k] != before.get(k, 0))
        return f"{kind}: {gate.last_invalid}" if kind == "invalid" else kind

    entry = Entry(3, "departure", (4.0, 0.0), WALL, ("P",), "camA")
    base = holds_payload(CELL, "monitor-a", BOOT, 1, WALL, (entry,))
    return base, run, seqs


PARSERS = {
    "command": (_command, ("seq", "speed_scale", "ttl_ms", "wall", "state", "boot")),
    "reset": (_reset, ("operator", "request_id", "wall", "note", "latch")),
    "mute": (_mute, ("operator", "zone", "duration_s", "wall", "end")),
    "apply": (_apply, ("operator", "zones_hash", "wall", "note")),
    "selection": (_case, ("selector", "set", "seq", "wall")),
    "holds": (_holds, ("seq", "wall", "entries", "boot", "overflow")),
}


def _parser(name: str):
    made = PARSERS[name][0]()
    base, run = made[0], made[1]
    if name == "holds":  # a fresh seq each time, so a valid one is never "replayed"
        seqs = made[2]

        def fresh(payload: bytes, run=run) -> str | None:
            body = json.loads(base)
            if payload == base:
                body["seq"] = next(seqs)
                return run(json.dumps(body).encode())
            return run(payload)
        return base, fresh
    return base, run


# the raw JSON text of hostile values, put in place of a field's value
HOSTILE_VALUES = {
    "deep": "[" * 1500 + "]" * 1500,
    "1e400": "1e400",
    "-1e400": "-1e400",
    "10**400": "1" + "0" * 400,
    "NaN": "NaN",
    "Infinity": "Infinity",
    "-Infinity": "-Infinity",
    "huge string": '"' + "x" * 100_000 + '"',
}
WRONG_TYPES = {"list": "[1]", "object": "{}", "null": "null"}
HOSTILE_PAYLOADS = {
    "10k [": b"[" * 10_000,
    "10k {": b'{"a":' * 10_000,
    "1e400": b"1e400",
    "10**400": b"1" + b"0" * 400,
    "NaN": b"NaN",
    "huge string": b'"' + b"x" * 200_000 + b'"',
    "not UTF-8": b"\xff\xfe\x00{",
    "empty": b"",
    "list": b"[1, 2]",
}


def _with(base: bytes, field: str, raw_value: str) -> bytes:
    body = json.loads(base)
    assert field in body, field
    body[field] = "@@VALUE@@"
    return json.dumps(body).replace('"@@VALUE@@"', raw_value, 1).encode()


@pytest.mark.parametrize("name", list(PARSERS))
def test_the_valid_message_is_accepted(name):
    base, run = _parser(name)
    assert run(base) is None  # so the refusals below are the hostile value's doing


@pytest.mark.parametrize("value", list(HOSTILE_VALUES), ids=list(HOSTILE_VALUES))
@pytest.mark.parametrize("name", list(PARSERS))
def test_a_hostile_value_in_any_field_is_refused_with_a_reason(name, value):
    base, run = _parser(name)
    for field in PARSERS[name][1]:
        reason = run(_with(base, field, HOSTILE_VALUES[value]))
        assert reason, f"{name}: {value} in {field} was accepted"
        if name == "holds":
            assert reason.startswith("invalid"), reason


@pytest.mark.parametrize("value", list(WRONG_TYPES))
@pytest.mark.parametrize("name", list(PARSERS))
def test_a_wrong_type_in_a_required_field_is_refused(name, value):
    base, run = _parser(name)
    for field in PARSERS[name][1]:
        assert run(_with(base, field, WRONG_TYPES[value])), f"{name}: {value} in {field}"


@pytest.mark.parametrize("payload", list(HOSTILE_PAYLOADS.values()),
                         ids=list(HOSTILE_PAYLOADS))
@pytest.mark.parametrize("name", list(PARSERS))
def test_a_hostile_payload_is_refused_with_a_reason(name, payload):
    _, run = _parser(name)
    assert run(payload)


def test_the_holds_refusal_says_why_and_is_counted():
    base, run = _parser("holds")
    reason = run(_with(base, "wall", "1" + "0" * 400))
    assert reason == "invalid: a number has 401 digits (at most 32)"
    reason = run(b"[" * 10_000)
    assert reason == "invalid: nested deeper than 16 levels"
    entry = json.loads(base)["entries"][0]
    entry["floor_m"] = "@@VALUE@@"
    body = json.loads(base)
    body["entries"] = [entry]
    nested = json.dumps(body).replace('"@@VALUE@@"', "[1e400, 0]").encode()
    assert run(nested).startswith("invalid: number 1e400 is out of range")


@pytest.mark.parametrize("raw, reason", [
    pytest.param(b"[" * 900, "nested deeper than 16 levels", id="deep"),
    pytest.param(b'{"a": 1e400}', "number 1e400 is out of range", id="1e400"),
    pytest.param(b'{"a": ' + b"9" * 400 + b"}", "a number has 400 digits", id="10**400"),
    pytest.param(b'{"a": NaN}', "NaN is not a number", id="NaN"),
    pytest.param(b'{"a": -Infinity}', "-Infinity is not a number", id="-inf"),
    pytest.param(b'{"a": 1}' + b" " * 1000, "payload has 1008 bytes (at most 1000)", id="size"),
    pytest.param(b"\xff", "payload is not UTF-8", id="utf8"),
    pytest.param(b"{", "payload is not JSON", id="truncated"),
    pytest.param(b"[1]", "payload is a JSON list, not an object", id="list"),
])
def test_the_bounded_loader_names_the_fault(raw, reason):
    with pytest.raises(pj.PayloadError) as err:
        pj.load_object(raw, 1000)
    assert str(err.value).startswith(reason), str(err.value)


def test_the_bounded_loader_keeps_what_a_bus_message_holds():
    text = '{"s": "[[[[[[[[[[[[[[[[[[[[", "n": [1, -2.5e9, 1.7e18, 9007199254740993], "t": true}'
    assert pj.load_object(text.encode(), 1000) == json.loads(text)  # brackets in strings
    nested = b"[" * 16 + b"]" * 16
    assert pj.load(nested, 100) == json.loads(nested)  # exactly the limit


ENCODINGS = ("utf-8", "utf-8-sig", "utf-16", "utf-16-le", "utf-16-be", "utf-32", "utf-32-le",
             "utf-32-be")


@pytest.mark.parametrize("encoding", ENCODINGS)
def test_the_bounds_hold_in_every_encoding_json_reads(encoding):
    """Issue 48: the nesting check scanned the raw bytes, so UTF-16/32 JSON passed it (985
    levels accepted). A U+2200 in a string is the byte 0x22 ('"') in UTF-16-BE: the old byte
    scan took everything after it for one string and counted no bracket of 985 levels."""
    smuggled = '["\u2200", ' + "[" * 985 + "]" * 985 + ', "\u2200"]'
    for text in (smuggled, "[" * 900 + "]" * 900):
        with pytest.raises(pj.PayloadError, match="nested deeper than 16 levels"):
            pj.load(text.encode(encoding), 10**6)
    with pytest.raises(pj.PayloadError, match="out of range"):
        pj.load('{"a": 1e400}'.encode(encoding), 1000)
    body = {"s": "[[[[[[[[[[[[[[[[[[[[ \u2200", "n": [1, -2.5e9], "t": True}
    assert pj.load_object(json.dumps(body, ensure_ascii=False).encode(encoding), 1000) == body


# ---- a bounded property test: random JSON and random bytes, never an exception ------------

JSON_LEAVES = st.one_of(
    st.none(), st.booleans(), st.integers(min_value=-(10**30), max_value=10**30),
    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=20))
JSON_VALUES = st.recursive(JSON_LEAVES, lambda kids: st.one_of(
    st.lists(kids, max_size=4), st.dictionaries(st.text(max_size=8), kids, max_size=4)),
    max_leaves=20)


def _mutated(base: bytes, data) -> bytes:
    kind = data.draw(st.sampled_from(["field", "bytes", "whole"]))
    if kind == "whole":
        return json.dumps(data.draw(JSON_VALUES)).encode()
    if kind == "bytes":
        raw = bytearray(base)
        for _ in range(data.draw(st.integers(1, 8))):
            raw[data.draw(st.integers(0, len(raw) - 1))] = data.draw(st.integers(0, 255))
        return bytes(raw)
    body = json.loads(base)
    body[data.draw(st.sampled_from(sorted(body)))] = data.draw(JSON_VALUES)
    return json.dumps(body).encode()  # NaN/Infinity written as json.dumps writes them


PARSED = {name: _parser(name) for name in PARSERS}


@settings(max_examples=300, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_no_exception_escapes_any_parser_on_random_input(data):
    name = data.draw(st.sampled_from(sorted(PARSED)))
    base, run = PARSED[name]
    payload = _mutated(base, data)
    reason = run(payload)  # a refusal is a reason; anything else raised fails the test
    assert reason is None or (isinstance(reason, str) and reason)

