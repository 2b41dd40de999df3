"""`monitor reset --role ROLE ...`: a reset for a cell watched by several monitors.

Each monitor of the cell latches its own STOP and judges its own resets (its boot, its latch
nonce, its view of the cell), so one signed request goes to each named role: its status is read
(boot and latch nonce), a request naming them is signed for that role's reset key, and each
answer is printed with the role's name. A role that is not latched needs nothing. The cell runs
again only when every latched monitor accepted: exit 0 then, 1 when any refused (or none was
latched), 2 when any did not answer.
"""

from __future__ import annotations

import argparse
import sys
import time

from monitor.cli.roles import role_keys
from monitor.signals import Interrupted, call_interruptible
from monitor.wire.answers import ignored_text
from monitor.wire.busconfig import BusConfig
from monitor.wire.resets import latch_of_status, request_reset, reset_payload


def reset_roles(args: argparse.Namespace, bus: BusConfig, session, signer, stop,
                first_status, monitor_keys=None) -> int:
    """Reset every latched monitor of ``args.role``; print one line per role; the exit code."""
    refused = silent = latched = 0
    for role in args.role:
        keys = role_keys(bus, role)
        if stop.is_set():
            return 130
        skipped: list[str] = []  # status answers not the monitor's (--monitor-key)
        status = first_status(session, keys, args.timeout, stop, monitor_keys, skipped)
        if skipped:
            print(f"{role}: status {ignored_text(skipped)}: someone else answers on "
                  f"{keys.status}", file=sys.stderr, flush=True)
        if status is None:
            silent += 1
            print(f"{role}: NO ANSWER on {keys.status} within {args.timeout:g} s")
            continue
        boot, latch = latch_of_status(status)
        if latch is None:
            print(f"{role}: not latched (state {status.get('state')}): nothing to reset")
            continue
        latched += 1
        rid = f"{args.request_id}-{role}" if args.request_id else ""
        payload = reset_payload(args.operator, rid, args.note,
                                cell=bus.cell if bus.prefix is None else "",
                                confirm_clear=args.confirm_clear, boot=boot, latch=latch)
        signature = signer.sign(keys.reset, payload) if signer else None
        ignored: list[str] = []  # answers not believed (--monitor-key): someone else's
        answer = _ask(session, keys.reset, payload, signature, args.timeout, stop,
                      monitor_keys, ignored)
        if ignored:
            print(f"monitor reset: {role}: {ignored_text(ignored)}: someone else answers on "
                  f"{keys.reset}", file=sys.stderr, flush=True)
        if answer is None:
            silent += 1
            print(f"{role}: NO ANSWER on {keys.reset} within {args.timeout:g} s")
            continue
        ok = answer["accepted"]
        refused += not ok
        print(f"{role}: reset by {args.operator} {'accepted' if ok else 'REFUSED'}: "
              f"{answer.get('reason', '')}"
              + (f" (monitor now {answer['state']})" if answer.get("state") else ""))
    if stop.is_set():
        return 130
    if refused or (not latched and not silent):
        if not latched and not silent:
            print("monitor reset: nothing to reset: no monitor of the cell is latched")
        return 1
    return 2 if silent else 0


def _ask(session, key: str, payload: bytes, signature: bytes | None, timeout: float,
         stop, monitor_keys=None, ignored: list[str] | None = None) -> dict | None:
    started = time.monotonic()
    while not stop.is_set():
        left = timeout - (time.monotonic() - started)
        if left <= 0:
            return None
        asked = time.monotonic()
        try:
            answer = call_interruptible(lambda left=left: request_reset(
                session, key, payload, signature, left, monitor_keys, ignored), stop)
        except Interrupted:
            return None
        if answer is not None or time.monotonic() - asked > 0.2:
            return answer  # answered, or a monitor got it and did not answer in time
        stop.wait(0.1)  # nothing routed yet: ask again
    return None
