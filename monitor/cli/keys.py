"""``monitor keys new``: Ed25519 key pairs for the monitor, operators, selectors and
commissioners (one key, one role)."""

from __future__ import annotations

import argparse
from pathlib import Path

from monitor.errors import ConfigError
from monitor.wire.signing import new_key_pair

KEY_DIR = Path("~/.config/workcell-monitor/keys")


def cmd_keys_new(args: argparse.Namespace) -> int:
    roles = [r for r in ("operator", "selector", "commissioner") if getattr(args, r)]
    if len(roles) > 1:
        raise ConfigError(f"monitor keys new: --{roles[0]} or --{roles[1]}, not both (a "
                          "selector or a commissioner must not be able to reset: one key, one "
                          "role)")
    name = args.operator or args.selector or args.commissioner
    if args.path:
        path = Path(args.path)
    elif name:
        path = (KEY_DIR / f"{name}.key").expanduser()
    else:
        raise ConfigError("monitor keys new: give a PATH for the key, or --operator NAME, "
                          f"--selector NAME or --commissioner NAME (then {KEY_DIR}/NAME.key)")
    flag = f"--{roles[0]}" if roles else ""
    if name and any(c.isspace() or c == "#" for c in name):
        raise ConfigError(f"{flag} {name!r}: no spaces or '#' in {flag[2:]} ids")
    private, public, text = new_key_pair(path, force=args.force)
    print(f"private key: {private} (mode 600; keep it on this host only)")
    print(f"public key:  {public}")
    print(text)
    if args.operator:
        print("(operators may reset a latched STOP; a robot program or PLC that selects zone "
              "sets is a selector: monitor keys new --selector NAME)")
        print(f"add this line to the monitor's operators file (bus.operators_file):\n"
              f"{args.operator} {text}")
    elif args.commissioner:
        print(f"sign the commissioning report with it (`monitor commission report --key "
              f"{private}`); add this line to the monitor's commissioners file "
              f"([service] commissioners_file), never to the operators file:\n"
              f"{args.commissioner} {text}")
    elif args.selector:
        print(f"add this line to the monitor's selectors file (bus.selectors_file), never to "
              f"the operators file (that would let it reset a latched STOP):\n"
              f"{args.selector} {text}")
    else:
        print("monitor: set bus.signing_key to the private key; give consumers the public key "
              "(`monitor watch --monitor-key " + str(public) + "`)")
    return 0


def register(subparsers) -> None:
    keys = subparsers.add_parser("keys", help="make signing keys (monitor, operators, "
                                 "selectors, commissioners)")
    ksub = keys.add_subparsers(dest="keys_action", metavar="ACTION", required=True)
    p = ksub.add_parser("new", help="write a new Ed25519 key pair (private key mode 600)",
                        description="Writes PATH (private, mode 600) and PATH.pub (public). "
                        "Never overwrites an existing key unless --force.")
    p.add_argument("path", nargs="?", help="private key file to write (default "
                   f"{KEY_DIR}/<operator>.key with --operator)")
    p.add_argument("--operator", help="operator id: print the line for the operators file "
                   "(default: a monitor key)")
    p.add_argument("--selector", help="selector id (a robot program, a PLC adapter that "
                   "selects zone sets): print the line for the selectors file (default: a "
                   "monitor key)")
    p.add_argument("--commissioner", help="commissioner id (who signs the commissioning report "
                   "and commissioned.json): print the line for the commissioners file "
                   "(default: none)")
    p.add_argument("--force", action="store_true",
                   help="replace existing key files (default: refuse)")
    p.set_defaults(func=cmd_keys_new)
