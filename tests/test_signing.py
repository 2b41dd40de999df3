"""Keys, signatures, the reset gate and the hardened consumer rule (pure, no Zenoh)."""

from __future__ import annotations

import json
import os
import stat
import subprocess
import sys

import pytest

from monitor.errors import ConfigError
from monitor.wire.consumer import CommandWatchdog, parse_command
from monitor.wire.resets import ResetGate, ResetPolicy, ResetRefused, reset_payload
from monitor.wire.signing import (
    load_operators,
    load_private_key,
    load_public_key,
    new_key_pair,
    parse_public_key,
)

CMD_KEY = "workcell/c1/safety/command"
RESET_KEY = "workcell/c1/safety/reset"
WALL = 1_800_000_000.0


@pytest.fixture
def keys(tmp_path):
    out = {}
    for name in ("monitor", "anna", "operator1", "rogue"):
        private, public, text = new_key_pair(tmp_path / f"{name}.key")
        out[name] = (load_private_key(private), load_public_key(public), text)
    return out


def command(seq: int, state: str = "RUN", *, boot: str = "b1", instance: str = "mon1",
            ttl=300, wall=WALL, **over) -> bytes:
    body = {"schema": "workcell.safety.command/1", "cell": "c1", "seq": seq, "boot": boot,
            "instance": instance, "state": state,
            "speed_scale": 1.0 if state == "RUN" else 0.0, "ttl_ms": ttl, "wall": wall,
            "reasons": [], "latched": False, **over}
    return json.dumps(body).encode()


# --- keys ------------------------------------------------------------------------------------


def test_new_key_pair_is_private_and_never_overwritten(tmp_path):
    private, public, text = new_key_pair(tmp_path / "k" / "mon.key")
    assert stat.S_IMODE(os.stat(private).st_mode) == 0o600
    assert public.read_text().strip() == text and text.startswith("ed25519:")
    with pytest.raises(ConfigError, match="exists; not overwriting"):
        new_key_pair(private)
    _, _, text2 = new_key_pair(private, force=True)
    assert text2 != text and stat.S_IMODE(os.stat(private).st_mode) == 0o600


def test_a_private_key_readable_by_others_is_refused(tmp_path):
    private, _, _ = new_key_pair(tmp_path / "mon.key")
    os.chmod(private, 0o644)
    with pytest.raises(ConfigError, match="mode 0644: group and others can read it"):
        load_private_key(private)


@pytest.mark.parametrize("text", ["", "ed25519:", "ed25519:!!!", "rsa:AAAA",
                                  "ed25519:" + "A" * 40])
def test_bad_public_keys_are_one_line_config_errors(text):
    with pytest.raises(ConfigError, match="not an Ed25519 public key"):
        parse_public_key(text)


def test_operators_file_lists_names_and_keys(tmp_path, keys):
    f = tmp_path / "operators"
    f.write_text(f"# who may reset\nanna {keys['anna'][2]}\n\noperator1 {keys['operator1'][2]}\n")
    assert sorted(load_operators(f)) == ["anna", "operator1"]
    f.write_text(f"anna {keys['anna'][2]}\nanna {keys['rogue'][2]}\n")
    with pytest.raises(ConfigError, match=r"operators:2: operator 'anna' is listed twice"):
        load_operators(f)


def test_keys_new_cli_prints_the_operators_line_and_refuses_to_overwrite(tmp_path):
    path = tmp_path / "anna.key"
    run = [sys.executable, "-m", "monitor", "keys", "new", str(path), "--operator", "anna"]
    out = subprocess.run(run, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    line = out.stdout.strip().splitlines()[-1]
    assert line.startswith("anna ed25519:") and line.split()[1] == \
        (tmp_path / "anna.key.pub").read_text().strip()
    out = subprocess.run(run, capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and "--force" in out.stderr and out.stderr.count("\n") == 1


# --- resets ----------------------------------------------------------------------------------


def gate(keys, **kw) -> ResetGate:
    ops = {n: keys[n][1] for n in ("anna", "operator1")}
    return ResetGate(ResetPolicy(kw.pop("operators", ops), "c1", RESET_KEY, **kw))


BOUND = {"boot": "boot-1", "latch": "1-0123456789abcdef"}  # as read from the status


def signed(keys, signer: str, operator: str, **kw):
    payload = reset_payload(operator, cell="c1", wall=kw.pop("wall", WALL), **{**BOUND, **kw})
    return payload, keys[signer][0].sign(RESET_KEY, payload)


def test_a_properly_signed_reset_passes_the_gate(keys):
    payload, sig = signed(keys, "anna", "anna", note="looked", confirm_clear=True)
    req = gate(keys).check(payload, sig, received=12.5, wall_now=WALL + 1)
    assert (req.operator, req.time, req.note, req.confirm_clear) == ("anna", 12.5, "looked", True)


@pytest.mark.parametrize("case, reason", [
    pytest.param(lambda k: (reset_payload("anna", cell="c1", wall=WALL, **BOUND), None),
                 "unsigned reset in the name of 'anna'", id="unsigned"),
    pytest.param(lambda k: signed(k, "rogue", "mallory"), "unknown operator 'mallory'",
                 id="unknown-operator"),
    pytest.param(lambda k: signed(k, "operator1", "anna"),
                 "signature does not match operator 'anna'", id="another-operators-name"),
    pytest.param(lambda k: signed(k, "anna", "anna", wall=WALL - 300), "off the monitor's clock",
                 id="old"),
    pytest.param(lambda k: (lambda p: (p, k["anna"][0].sign(RESET_KEY, p)))(
        reset_payload("anna", cell="c2", wall=WALL, **BOUND)), "is for cell 'c2'", id="other-cell"),
    pytest.param(lambda k: (lambda p: (p, k["anna"][0].sign("workcell/c2/safety/reset", p)))(
        reset_payload("anna", cell="c1", wall=WALL, **BOUND)), "signature does not match",
        id="signed-for-another-key"),
    pytest.param(lambda k: (b"garbage", None), "not JSON", id="garbage"),
    pytest.param(lambda k: (json.dumps({"operator": "anna", "request_id": "x",
                                        "wall": float("nan")}).encode(), None),
                 "NaN is not a number", id="nan-wall"),
])
def test_rogue_resets_are_refused_with_the_reason(keys, case, reason):
    payload, sig = case(keys)
    with pytest.raises(ResetRefused, match=reason):
        gate(keys).check(payload, sig, received=1.0, wall_now=WALL)


def test_a_replayed_reset_is_refused(keys):
    g = gate(keys)
    payload, sig = signed(keys, "anna", "anna")
    g.check(payload, sig, 1.0, WALL)
    with pytest.raises(ResetRefused, match="already used"):
        g.check(payload, sig, 2.0, WALL + 1)


def test_without_operators_resets_are_refused_unless_explicitly_allowed(keys):
    payload = reset_payload("anna", cell="c1", wall=WALL, **BOUND)
    with pytest.raises(ResetRefused, match="no operators configured"):
        gate(keys, operators=None).check(payload, None, 1.0, WALL)
    req = gate(keys, operators=None, allow_unsigned=True).check(payload, None, 1.0, WALL)
    assert req.operator == "anna"


def test_a_reset_names_the_boot_and_latch_it_releases(keys):
    """The gate checks the nonce against the latch the monitor publishes now, and the boot
    against this run: a reset captured earlier is refused naming the stale nonce, whatever
    its age (here 1 s, well within the 30 s window) and even with a fresh request id."""
    boot, latch = BOUND["boot"], BOUND["latch"]
    payload, sig = signed(keys, "anna", "anna", confirm_clear=True)
    req = gate(keys).check(payload, sig, 1.0, WALL + 1, boot=boot, latch=latch)
    assert req.latch == latch and req.confirm_clear
    # the same monitor, a new latch; then a restarted monitor (new boot) with its own latch
    for now_boot, now_latch, why in [(boot, "2-fedcba9876543210", "has nonce '2-fedcba"),
                                     ("boot-2", "1-0011223344556677", "boot 'boot-1', this "
                                      "monitor runs boot 'boot-2'")]:
        with pytest.raises(ResetRefused, match=f"stale latch nonce '{latch}'.*{why}"):
            gate(keys).check(payload, sig, 1.0, WALL + 1, boot=now_boot, latch=now_latch)
    # a fresh gate (a restart forgets request ids) refuses it just the same
    with pytest.raises(ResetRefused, match="stale latch nonce"):
        gate(keys).check(payload, sig, 1.0, WALL + 1, boot="boot-2", latch=None)


@pytest.mark.parametrize("missing, reason", [
    ({"latch": ""}, "names no latch nonce"), ({"boot": ""}, "names no monitor boot"),
    ({"latch": 7}, "malformed latch nonce"), ({"boot": ["b"]}, "malformed boot")])
def test_a_reset_without_a_latch_nonce_or_boot_is_refused(keys, missing, reason):
    body = json.loads(signed(keys, "anna", "anna")[0])
    body.update(missing)
    payload = json.dumps({k: v for k, v in body.items() if v != ""}).encode()
    with pytest.raises(ResetRefused, match=reason):
        gate(keys).check(payload, keys["anna"][0].sign(RESET_KEY, payload), 1.0, WALL,
                         boot=BOUND["boot"], latch=BOUND["latch"])


def test_latch_nonces_are_unique_per_latch_and_per_run():
    from monitor.wire.resets import LatchNonces

    run1, run2 = LatchNonces("boot-1"), LatchNonces("boot-1")  # even with a repeated boot id
    nonces = {run1(1), run1(2), run2(1), run2(2)}
    assert len(nonces) == 4 and run1(1) == run1(1) and run1(3).startswith("3-")


# --- consumer --------------------------------------------------------------------------------


def signed_dog(keys, **kw) -> CommandWatchdog:
    dog = CommandWatchdog(public_keys=(keys["monitor"][1],), cell="c1", key_expr=CMD_KEY, **kw)
    dog.on_liveliness("workcell/c1/safety/alive/mon1", True)
    return dog


def test_consumer_follows_only_commands_signed_by_the_monitor(keys):
    dog = signed_dog(keys)
    mon = keys["monitor"][0]
    p = command(1, "STOP")
    assert dog.on_command(p, 0.0, mon.sign(CMD_KEY, p), WALL) is None
    forged = command(2)
    assert dog.on_command(forged, 0.01, None, WALL) == "unsigned"
    assert dog.on_command(forged, 0.02, keys["rogue"][0].sign(CMD_KEY, forged), WALL) \
        == "signature"
    assert dog.on_command(forged, 0.03, b"\0" * 64, WALL) == "signature"
    tampered = p.replace(b'"STOP"', b'"RUN"').replace(b'"speed_scale": 0.0', b'"speed_scale": 1.0')
    assert dog.on_command(tampered, 0.04, mon.sign(CMD_KEY, p), WALL) == "signature"
    assert dog.verdict(0.05).state == "STOP"
    # replayed (same seq) and recorded long ago (wall time out of the window)
    assert dog.on_command(p, 0.06, mon.sign(CMD_KEY, p), WALL) == "seq"
    old = command(3, wall=WALL - 60)
    assert dog.on_command(old, 0.07, mon.sign(CMD_KEY, old), WALL) == "window"
    assert dog.rejected == {"unsigned": 1, "signature": 3, "seq": 1, "window": 1}


def test_consumer_never_goes_back_to_a_replaced_boot(keys):
    dog = signed_dog(keys)
    mon = keys["monitor"][0]
    b1 = command(50, boot="b1")
    assert dog.on_command(b1, 0.0, mon.sign(CMD_KEY, b1), WALL) is None
    b2 = command(1, "STOP", boot="b2")  # the monitor restarted
    assert dog.on_command(b2, 0.1, mon.sign(CMD_KEY, b2), WALL) is None
    replay = command(51, boot="b1")  # a recording of the old boot, newer seq
    assert dog.on_command(replay, 0.2, mon.sign(CMD_KEY, replay), WALL) == "old_boot"
    assert dog.verdict(0.2).state == "STOP"


def test_consumer_drops_an_older_boot_of_any_instance_for_good(keys):
    """A restarted monitor has a new instance id by default: the old boot is retired by the
    newer ``boot_wall`` (signed), not by the instance, and never followed again, even inside
    the wall-clock window and after the new boot goes quiet."""
    dog = CommandWatchdog(public_keys=(keys["monitor"][1],), cell="c1", key_expr=CMD_KEY)
    mon = keys["monitor"][0]

    def send(seq, boot, instance, boot_wall, now, state="RUN"):
        p = command(seq, state, boot=boot, instance=instance, boot_wall=boot_wall)
        dog.on_liveliness(f"workcell/c1/safety/alive/{instance}", True)
        return dog.on_command(p, now, mon.sign(CMD_KEY, p), WALL)

    assert send(7, "b1", "mon-a", WALL - 100, 0.0) is None
    assert send(8, "b1", "mon-a", WALL - 100, 0.1) is None
    dog.on_liveliness("workcell/c1/safety/alive/mon-a", False)  # the old process is gone
    assert send(1, "b2", "mon-b", WALL - 2, 3.0, "STOP") is None  # restarted, latched STOP
    # a captured RUN of the old boot, seq newer than ever: dropped, now and later
    assert send(9, "b1", "mon-a", WALL - 100, 3.1) == "old_boot"
    assert dog.verdict(3.1).state == "STOP"
    assert send(50, "b1", "mon-a", WALL - 100, 9.0) == "old_boot"
    assert dog.verdict(9.0).state == "STOP" and dog.last["boot"] == "b2"
    # an older boot never seen before (started before b2) is dropped as well
    assert send(1, "b0", "mon-z", WALL - 500, 9.1) == "old_boot"
    assert dog.rejected["old_boot"] == 3 and dog.last["boot"] == "b2"


BAD_FIELDS = {
    "nan-ttl": {"ttl_ms": float("nan")},
    "inf-ttl": {"ttl_ms": float("inf")},
    "negative-ttl": {"ttl_ms": -5},
    "huge-ttl": {"ttl_ms": 1e300},
    "string-ttl": {"ttl_ms": "300"},
    "huge-seq": {"seq": 10**400},
    "float-seq": {"seq": 1e400},
    "bool-seq": {"seq": True},
    "negative-seq": {"seq": -1},
    "nan-speed": {"speed_scale": float("nan")},
    "speed-above-1": {"speed_scale": 2.0},
    "stop-with-speed": {"state": "STOP", "speed_scale": 0.5},
    "unknown-state": {"state": "GO"},
    "list-boot": {"boot": ["b1"]},
    "long-instance": {"instance": "x" * 1000},
    "nan-wall": {"wall": float("nan")},
    "reasons-not-list": {"reasons": "none"},
}


@pytest.mark.parametrize("fields", BAD_FIELDS.values(), ids=BAD_FIELDS.keys())
def test_malformed_commands_are_dropped_never_raised_never_holding_the_deadline(fields):
    dog = CommandWatchdog(require_liveliness=False)
    assert dog.on_command(command(1, "RUN"), 0.0) is None
    payload = json.dumps({**json.loads(command(2)), **fields}).encode()
    assert dog.on_command(payload, 0.2) == "invalid"
    assert dog.verdict(0.29).state == "RUN"  # still the first command's deadline
    assert dog.verdict(0.31).code == "ttl"


def test_the_consumers_own_ttl_cap_always_applies():
    dog = CommandWatchdog(require_liveliness=False)  # default cap 1000 ms
    assert dog.on_command(command(1, ttl=60_000), 0.0) is None
    assert dog.verdict(0.99).state == "RUN" and dog.verdict(1.01).code == "ttl"
    with pytest.raises(ValueError):
        CommandWatchdog(max_ttl_ms=float("nan"))
    assert dog.verdict(-5.0).code == "ttl"  # a clock going backwards is no excuse


def test_two_live_monitors_on_a_cell_mean_stop(keys):
    dog = signed_dog(keys)
    mon = keys["monitor"][0]
    p = command(1)
    assert dog.on_command(p, 0.0, mon.sign(CMD_KEY, p), WALL) is None
    assert dog.verdict(0.01).state == "RUN"
    dog.on_liveliness("workcell/c1/safety/alive/mon2", True)
    v = dog.verdict(0.02)
    assert v.state == "STOP" and v.code == "duplicate_monitor" and "mon2" in v.reason
    dog.on_liveliness("workcell/c1/safety/alive/mon2", False)
    assert dog.verdict(0.03).state == "RUN"
    # a second instance's commands (no token needed) also count
    q = command(1, instance="mon3", boot="b9")
    assert dog.on_command(q, 0.04, mon.sign(CMD_KEY, q), WALL) is None
    assert dog.verdict(0.05).code == "duplicate_monitor"


def test_parse_command_names_the_bad_field():
    with pytest.raises(ValueError, match="ttl_ms"):
        parse_command(command(1, ttl=-5))
    # NaN is refused by the bounded decoder before any field is read (monitor/wire/payload.py)
    with pytest.raises(ValueError, match="NaN is not a number"):
        parse_command(command(1, ttl=float("nan")))


def test_keys_new_for_a_selector_names_the_selectors_file_and_an_operator_hint_warns(tmp_path):
    """Issue 31: `keys new --operator robot` told the user to put the robot's key into the
    operators file, which would give the robot program reset rights."""
    run = [sys.executable, "-m", "monitor", "keys", "new"]
    sel = subprocess.run([*run, str(tmp_path / "robot.key"), "--selector", "robot"],
                         capture_output=True, text=True)
    assert sel.returncode == 0, sel.stderr
    assert "selectors file (bus.selectors_file)" in sel.stdout
    assert "never to the operators file" in sel.stdout
    assert any(line.startswith("robot ed25519:") for line in sel.stdout.splitlines())
    op = subprocess.run([*run, str(tmp_path / "anna.key"), "--operator", "anna"],
                        capture_output=True, text=True)
    assert "operators file" in op.stdout and "--selector NAME" in op.stdout
    both = subprocess.run([*run, str(tmp_path / "x.key"), "--operator", "a", "--selector", "b"],
                          capture_output=True, text=True)
    assert both.returncode != 0 and "not both" in both.stderr


def test_a_bad_selectors_file_is_named_as_the_selectors_file(tmp_path):
    from monitor.cases.receiver import CaseReceiver

    bad = tmp_path / "selectors"
    bad.write_text("robot\n")
    with pytest.raises(ConfigError) as err:
        CaseReceiver.for_bus(None, type("Bus", (), {
            "key_prefix": "workcell/c/", "selectors_file": str(bad), "cell": "c",
            "case_window_s": 5.0})(), None)
    assert "'<selector> ed25519:<base64>'" in str(err.value)
    bad.chmod(0o666)
    with pytest.raises(ConfigError) as err:
        CaseReceiver.for_bus(None, type("Bus", (), {
            "key_prefix": "workcell/c/", "selectors_file": str(bad), "cell": "c",
            "case_window_s": 5.0})(), None)
    assert "selectors file" in str(err.value) and "operators file" not in str(err.value)
