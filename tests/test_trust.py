"""Trust details (issue 20, part 8): who may write the key files, how far a consumer's inbox
grows, how late a genuine command may arrive. Unsigned traffic on the command key is in
tests/test_rogue.py (a second process)."""

from __future__ import annotations

import json
import os

import pytest

from monitor.bus.foreign import ForeignCommands
from monitor.errors import ConfigError
from monitor.wire.signing import load_operators, load_private_key, load_public_key, new_key_pair
from tests.helpers import (
    assert_one_line,
    assert_one_line_error,
    free_port,
    run_monitor,
    wait_for,
)

# --- (a) key and operators files writable (or, private keys, readable) by others ---------------


@pytest.mark.parametrize("mode", [0o666, 0o620, 0o660, 0o640, 0o604, 0o602])
def test_a_private_key_others_may_read_or_write_is_refused_naming_file_and_mode(tmp_path, mode):
    private, _, _ = new_key_pair(tmp_path / "mon.key")
    os.chmod(private, mode)
    with pytest.raises(ConfigError) as err:
        load_private_key(private)
    assert_one_line(err.value, str(private), f"mode {mode:04o}", "chmod 600")


@pytest.mark.parametrize("mode", [0o666, 0o620, 0o602])
def test_an_operators_file_others_may_write_is_refused_naming_file_and_mode(tmp_path, mode):
    _, _, text = new_key_pair(tmp_path / "anna.key")
    ops = tmp_path / "operators"
    ops.write_text(f"anna {text}\n")
    os.chmod(ops, mode)
    with pytest.raises(ConfigError) as err:
        load_operators(ops)
    assert_one_line(err.value, str(ops), f"mode {mode:04o}", "operators file", "write")
    os.chmod(ops, 0o644)  # readable by all is fine: it holds public keys only
    assert list(load_operators(ops)) == ["anna"]


@pytest.mark.parametrize("mode", [0o666, 0o620])
def test_a_monitor_public_key_others_may_write_is_refused(tmp_path, mode):
    _, public, _ = new_key_pair(tmp_path / "mon.key")
    os.chmod(public, mode)
    with pytest.raises(ConfigError) as err:
        load_public_key(public)
    assert_one_line(err.value, str(public), f"mode {mode:04o}")
    os.chmod(public, 0o644)
    load_public_key(public)


def _service_config(tmp_path, **bus: str) -> str:
    lines = "".join(f'{k} = "{v}"\n' for k, v in bus.items())
    cfg = tmp_path / "monitor.toml"
    cfg.write_text(f'[camera]\nsource = "synthetic:demo"\n[bus]\ncell = "trust"\n{lines}'
                   f'listen = ["tcp/127.0.0.1:{free_port()}"]\n')
    return str(cfg)


@pytest.mark.parametrize(("which", "mode"), [("signing_key", 0o666), ("signing_key", 0o620),
                                             ("operators_file", 0o666),
                                             ("operators_file", 0o620)])
def test_monitor_run_refuses_key_files_others_may_write(tmp_path, which, mode):
    private, _, text = new_key_pair(tmp_path / "mon.key")
    ops = tmp_path / "operators"
    ops.write_text(f"anna {text}\n")
    target = private if which == "signing_key" else ops
    os.chmod(target, mode)
    out = run_monitor("run", "--config", _service_config(
        tmp_path, signing_key=str(private), operators_file=str(ops)), "--duration", "5",
        timeout=60)
    assert_one_line_error(out, str(target), f"mode {mode:04o}")


@pytest.mark.parametrize("mode", [0o666, 0o620])
def test_monitor_reset_refuses_an_operator_key_others_may_read_or_write(tmp_path, mode):
    private, _, _ = new_key_pair(tmp_path / "anna.key")
    os.chmod(private, mode)
    out = run_monitor("reset", "--operator", "anna", "--key", private, "--cell", "trust",
                      "--connect", f"tcp/127.0.0.1:{free_port()}", "--timeout", "0.5",
                      timeout=60)
    assert_one_line_error(out, str(private), f"mode {mode:04o}")


def test_monitor_watch_refuses_a_monitor_key_others_may_write(tmp_path):
    _, public, _ = new_key_pair(tmp_path / "mon.key")
    os.chmod(public, 0o666)
    out = run_monitor("watch", "--monitor-key", public, "--cell", "trust",
                      "--connect", f"tcp/127.0.0.1:{free_port()}", "--duration", "0.5",
                      timeout=60)
    assert_one_line_error(out, str(public), "mode 0666")


def test_new_key_pairs_are_loadable_under_a_group_writable_umask(tmp_path):
    old = os.umask(0o002)
    try:
        private, public, _ = new_key_pair(tmp_path / "mon.key")
    finally:
        os.umask(old)
    load_private_key(private)
    load_public_key(public)


# --- (b) what counts as a second monitor (pure; the flood over Zenoh is in test_rogue.py) -----

CMD_KEY = "workcell/c1/safety/command"


def _cmd(boot: str = "other", wall: float = 1000.0, seq: int = 1) -> bytes:
    return json.dumps({"schema": "workcell.safety.command/1", "cell": "c1", "seq": seq,
                       "boot": boot, "instance": "m2", "state": "RUN", "speed_scale": 1.0,
                       "ttl_ms": 300, "wall": wall, "reasons": []}).encode()


def test_only_fresh_commands_signed_with_the_cells_key_from_another_boot_are_a_second_monitor(
        tmp_path):
    mon = load_private_key(new_key_pair(tmp_path / "mon.key")[0])
    rogue = load_private_key(new_key_pair(tmp_path / "rogue.key")[0])
    seen = ForeignCommands(mon.key.public_key(), CMD_KEY)

    def sort(payload: bytes, signer=None, boot: str = "mine", wall_now: float = 1000.0):
        sig = signer.sign(CMD_KEY, payload) if signer else None
        return seen.classify(payload, sig, boot, 0.0, wall_now)

    assert sort(_cmd()) is None  # unsigned
    assert sort(_cmd(), rogue) is None  # signed by another key
    assert seen.classify(_cmd(), b"x" * 10, "mine", 0.0, 1000.0) is None
    assert sort(b"not json", mon) is None
    assert sort(_cmd(boot="mine"), mon) is None  # our own session, replayed by someone
    assert sort(_cmd(wall=900.0), mon) is None  # an old recording of another run
    assert sort(_cmd(), mon) == "other"
    assert seen.counts() == {"unsigned": 1, "signature": 2, "invalid": 1, "replayed": 1,
                             "stale": 1}
    alert = seen.alert("bus", 1.0)
    assert alert.kind == "foreign_commands" and alert.details["new"]["signature"] == 2
    assert seen.alert("bus", 2.0) is None  # nothing new: no alert


def test_signature_checks_of_foreign_commands_are_budgeted(tmp_path):
    mon = load_private_key(new_key_pair(tmp_path / "mon.key")[0])
    rogue = load_private_key(new_key_pair(tmp_path / "rogue.key")[0])
    seen = ForeignCommands(mon.key.public_key(), CMD_KEY, verify_per_s=10)
    bad = rogue.sign(CMD_KEY, _cmd())
    for _ in range(100):  # one instant: at most the budget is verified
        seen.classify(_cmd(), bad, "mine", 5.0, 1000.0)
    assert seen.counts() == {"signature": 10, "unchecked": 90}
    # a second later the budget is back: a genuine second monitor is found
    good = _cmd()
    assert seen.classify(good, mon.sign(CMD_KEY, good), "mine", 6.0, 1000.0) == "other"


def test_without_a_signing_key_any_well_formed_command_of_another_boot_is_a_second_monitor():
    seen = ForeignCommands(None, CMD_KEY)  # consumers cannot tell a forger from a monitor
    assert seen.classify(_cmd(), None, "mine", 0.0, 0.0) == "other"
    assert seen.classify(_cmd(boot="mine"), None, "mine", 0.0, 0.0) is None
    assert seen.classify(b"{}", None, "mine", 0.0, 0.0) is None


# --- (c) the consumer's inbox under a flood ----------------------------------------------------


def test_the_watch_inbox_stays_bounded_under_a_flood_and_the_newest_command_wins():
    import zenoh

    from monitor.bus.session import BusConfig, BusKeys, open_session
    from monitor.cli.watch import _watch_subscriptions
    from monitor.wire.inbox import Inbox

    port = free_port()
    keys = BusKeys.of("workcell/flood/")
    inbox = Inbox(64)
    with open_session(BusConfig(cell="flood", instance="watch",
                                listen=(f"tcp/127.0.0.1:{port}",))) as consumer, \
            open_session(BusConfig(cell="flood", instance="rogue",
                                   connect=(f"tcp/127.0.0.1:{port}",))) as rogue:
        subs = _watch_subscriptions(consumer, keys, inbox, lambda: 0.0)
        token = rogue.liveliness().declare_token(f"{keys.alive}/mon-a")
        assert wait_for(lambda: inbox.lengths().get("alive") == 1)
        pub = rogue.declare_publisher(keys.command,
                                      congestion_control=zenoh.CongestionControl.BLOCK)
        last = 5000
        for seq in range(1, last + 1):  # the consumer's loop is not reading: worst case
            pub.put(_cmd(seq=seq))
            assert len(inbox) <= 64 + 1  # every kind within its bound, at every moment
        assert wait_for(lambda: inbox.dropped["command"] >= last - 64 - 100,
                        what=lambda: inbox.dropped)
        assert wait_for(lambda: any(_seq(e) == last for e in _peek(inbox)))
        assert inbox.lengths() == {"alive": 1, "command": 64}  # the token survived the flood
        entries = [inbox.get(0.1) for _ in range(65)]
        assert entries[0][0] == "alive"  # arrival order across kinds
        seqs = [_seq(e) for e in entries[1:]]
        assert seqs == sorted(seqs) and seqs[-1] == last  # the newest 64, in order
        assert inbox.get(0.01) is None
        token.undeclare()
        for s in subs:
            s.undeclare()


def _peek(inbox) -> list:
    with inbox._ready:
        return [item for q in inbox._queues.values() for _, item in q]


def _seq(entry) -> int | None:
    return json.loads(entry[1])["seq"] if entry[0] == "command" else None


# --- (d) genuine commands relayed late --------------------------------------------------------


def test_a_command_later_than_clock_sync_plus_ttl_is_dropped_the_window_is_the_declared_sync():
    from monitor.wire.consumer import CommandWatchdog

    def late(seconds: float, **kw) -> str | None:
        dog = CommandWatchdog(max_ttl_ms=1000, require_liveliness=False, cell="c1", **kw)
        return dog.on_command(_cmd(wall=1000.0), 5.0, wall_now=1000.0 + seconds)

    # default: one host (or a declared 100 ms sync); the command's ttl is 300 ms
    assert late(3.0) == "window"  # the assessor's relay: 3 s late never counts
    assert late(0.5) == "window"
    assert late(0.35) is None and late(0.0) is None and late(-0.05) is None
    assert late(-0.2) == "window"  # from the future beyond the declared sync
    # a deployment that declares a coarser sync gets a wider window, and only that
    assert late(3.0, clock_sync_ms=3000) is None
    assert late(3.5, clock_sync_ms=3000) == "window"
    # the consumer's own ttl cap bounds the window too
    dog = CommandWatchdog(max_ttl_ms=100, require_liveliness=False, cell="c1")
    assert dog.on_command(_cmd(wall=1000.0), 5.0, wall_now=1000.25) == "window"
    with pytest.raises(ValueError, match="clock_sync_ms"):
        CommandWatchdog(clock_sync_ms=float("nan"))
