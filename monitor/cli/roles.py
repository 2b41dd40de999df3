"""``--role ROLE``: the operator commands (status, reset, mute, zones apply) address one monitor
of a cell watched by several (``[bus] role``, docs/consumer.md "Several monitors per cell").

One place turns a role into its keys (``role_keys``) and says what to do when nothing answered:
on a cell with roles the role-less keys are silent, so the error names the roles that answer
("this cell has monitors monitor-a, monitor-b: pass --role")."""

from __future__ import annotations

import queue
import time

import zenoh

from monitor.cli.zenoh_args import nothing_found_hint
from monitor.errors import ConfigError
from monitor.wire.busconfig import BusConfig, BusKeys, checked_role

ROLES_LOOKUP_S = 1.0  # s to ask which roles answer, after the asked key stayed silent


def role_keys(bus: BusConfig, role: str = "") -> BusKeys:
    """The keys of the cell's monitor with ``role`` ("" = the cell's only monitor)."""
    return BusKeys.of(bus.key_prefix, role)


def roles_answering(session, bus: BusConfig, timeout: float, stop) -> list[str]:
    """The roles whose monitors answer a status query on the cell within ``timeout`` (from the
    key of each reply: ``safety/<role>/status``), sorted; [] when none."""
    prefix = role_keys(bus).status[:-len("status")]
    inbox: queue.SimpleQueue = queue.SimpleQueue()
    done = object()
    session.get(prefix + "*/status", handler=zenoh.handlers.Callback(
        inbox.put, lambda: inbox.put(done)), consolidation=zenoh.ConsolidationMode.NONE,
        timeout=timeout)
    roles: set[str] = set()
    deadline = time.monotonic() + timeout
    while not stop.is_set() and (left := deadline - time.monotonic()) > 0:
        try:  # in slices: the stop signal is seen within 50 ms
            reply = inbox.get(timeout=min(0.05, left))
        except queue.Empty:
            continue
        if reply is done:
            break
        if reply.ok is not None:
            key = str(reply.ok.key_expr)
            if key.startswith(prefix) and key.endswith("/status"):
                roles.add(key[len(prefix):-len("/status")])
    return sorted(r for r in roles if _is_role(r))


def _is_role(text: str) -> bool:
    try:
        return bool(checked_role(text))
    except ValueError:  # a reply on a wildcard or a nested key: no monitor's status
        return False


def no_answer(command: str, key: str, timeout: float, bus: BusConfig, session, stop,
              role: str = "") -> ConfigError:
    """The one-line error when nothing answered on ``key``: names the roles that do answer on
    the cell (a cell with roles is silent on the role-less keys; a mistyped role too)."""
    roles = [] if stop.is_set() else roles_answering(session, bus, ROLES_LOOKUP_S, stop)
    head = f"{command}: no monitor answered on {key} within {timeout:g} s; "
    if roles and not role:
        return ConfigError(head + f"this cell has monitors {', '.join(roles)}: pass --role")
    if roles:
        return ConfigError(head + f"the monitors of cell {bus.cell!r} are "
                           f"{', '.join(roles)}: check --role")
    return ConfigError(head + nothing_found_hint(bus))
