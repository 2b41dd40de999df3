"""Trust details (issue 20, part 8): who may write the key files, how far a consumer's inbox
grows, how late a genuine command may arrive. Unsigned traffic on the command key is in
tests/test_rogue.py (a second process)."""

from __future__ import annotations

import os

import pytest

from monitor.errors import ConfigError
from monitor.signing import load_operators, load_private_key, load_public_key, new_key_pair
from tests.helpers import assert_one_line, assert_one_line_error, free_port, run_monitor

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
