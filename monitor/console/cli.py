"""``monitor console``: the web console process; ``monitor console passwd``: its operators.

Starlette and uvicorn are imported only when the console runs (the optional extra
``console``): every other command works without them.
"""

from __future__ import annotations

import argparse
import getpass
import sys
import threading
from pathlib import Path

from monitor.errors import ConfigError

DEFAULT_LISTEN = "127.0.0.1:8080"


def register(subparsers: argparse._SubParsersAction) -> None:
    from monitor.adapters.follower import DEFAULT_TICK_S
    from monitor.cli.adapters import add_consumer_args
    from monitor.cli.zenoh_args import add_zenoh_args as _add_zenoh_args

    p = subparsers.add_parser(
        "console", help="web console: live state, incidents, zone editor (docs/console.md)",
        description="Serve the web console: the cell's state as the consumer rule sees it, "
        "the incident list with clip playback, and the zone editor (edits need an operator "
        "password; every edit is audited). Listens on 127.0.0.1 by default; another address "
        "needs --https-cert/--https-key and --passwords.")
    _add_zenoh_args(p, listen_flag="--zenoh-listen", default_connect=True)
    add_consumer_args(p)
    p.set_defaults(tick=max(DEFAULT_TICK_S, 0.05))
    p.add_argument("--zones", type=Path, help="the zone file the monitor runs with (required)")
    p.add_argument("--listen", dest="http_listen", default=DEFAULT_LISTEN, metavar="HOST:PORT",
                   help="HTTP(S) address of the console")
    p.add_argument("--incidents", type=Path, metavar="DIR",
                   help="the incident recorder's data dir ([recorder] data_dir: "
                   "DIR/index.sqlite3); zone edits are recorded there too (default: none)")
    p.add_argument("--reference", action="append", default=[], metavar="CAMERA=FILE",
                   help="a camera's reference image for the live view and the editor "
                   "(repeatable; default: a grey canvas)")
    p.add_argument("--passwords", type=Path, metavar="FILE",
                   help="users and their levels (monitor console passwd); without it the "
                   "console is read-only (default: none)")
    p.add_argument("--operators", dest="reset_operators", type=Path, metavar="FILE",
                   help="the monitor's operators file (bus.operators_file): the setup page "
                   "lists who may reset, read-only (default: none, not shown)")
    p.add_argument("--reset-key", action="append", default=[], metavar="NAME=FILE",
                   help="an operator's private reset key (NAME as in the monitor's operators "
                   "file): a console user NAME at the operator level may then confirm the cell "
                   "clear from the live page, signed with it (repeatable; default: none, the "
                   "console sends no confirm-clear)")
    p.add_argument("--audit", type=Path, metavar="FILE",
                   help="audit log of edits, JSON lines (default: ZONEFILE.audit.jsonl)")
    p.add_argument("--trusted-proxy", action="append", default=[], metavar="ADDRESS",
                   help="a reverse proxy (address or network) whose X-Forwarded-For names the "
                   "client: throttled and audited by that address, beside the proxy's "
                   "(repeatable; default: none, the header is ignored)")
    p.add_argument("--https-cert", metavar="PEM", help="TLS certificate of the console "
                   "(default: none, plain HTTP; allowed on loopback only)")
    p.add_argument("--https-key", metavar="PEM", help="TLS private key of the console "
                   "(default: none)")
    p.set_defaults(func=cmd_console)
    sub = p.add_subparsers(dest="console_command", metavar="ACTION", required=False)
    pw = sub.add_parser("passwd", help="set a console user's password and level (the "
                        "password from the terminal, or one line on stdin)",
                        description="Add or change one user of the console's passwords file. "
                        "Levels: viewer (may view), operator (also edits zone polygons), admin "
                        "(also mute settings, zone set rules, volumes); docs/console.md. No "
                        "level grants a reset: that is the monitor's operators file.")
    pw.add_argument("file", type=Path, help="passwords file (created mode 0600)")
    pw.add_argument("operator", metavar="NAME", help="user name")
    pw.add_argument("--level", choices=("viewer", "operator", "admin"),
                    help="what the user may do (default: the user's level in the file; a new "
                    "user: operator)")
    pw.set_defaults(func=cmd_passwd)


def cmd_passwd(args: argparse.Namespace) -> int:
    from monitor.console.auth import set_password

    if sys.stdin.isatty():
        password = getpass.getpass(f"password for {args.operator}: ")
        if getpass.getpass("again: ") != password:
            raise ConfigError("the two passwords differ: nothing written")
    else:
        password = sys.stdin.readline().rstrip("\n")
    level = set_password(args.file, args.operator, password, args.level)
    print(f"password of {args.operator} ({level}) set in {args.file}")
    return 0


def _references(items: list[str]) -> dict[str, Path]:
    out = {}
    for item in items:
        camera, sep, path = item.partition("=")
        if not sep or not camera or not path:
            raise ConfigError(f"--reference {item!r}: expected CAMERA=FILE")
        if not Path(path).is_file():
            raise ConfigError(f"--reference {item!r}: {path}: no such file")
        out[camera] = Path(path)
    return out


def cmd_console(args: argparse.Namespace) -> int:
    from monitor.console.audit import AuditLog
    from monitor.console.auth import Operators, is_loopback, require_safe_listen
    from monitor.pose.stream import parse_host_port

    if args.zones is None:
        raise ConfigError("monitor console: give --zones FILE (the zone file the monitor runs "
                          "with)")
    if not args.monitor_key and not args.unauthenticated:
        raise ConfigError("monitor console: give --monitor-key FILE (the monitor's public key), "
                          "or --unauthenticated for a bench")
    host, port = parse_host_port(args.http_listen, 8080)
    tls = bool(args.https_cert and args.https_key)
    if bool(args.https_cert) != bool(args.https_key):
        raise ConfigError("monitor console: --https-cert and --https-key go together")
    # refused before anything opens: off loopback only with TLS and operator passwords
    require_safe_listen(host, tls, args.passwords is not None)
    try:
        import uvicorn  # noqa: F401
        from starlette.applications import Starlette  # noqa: F401
    except ImportError:
        raise ConfigError("monitor console needs the optional extra: pip install "
                          "'workcell-monitor[console]'") from None
    from monitor.console.sources import TrustedProxies

    operators = Operators(args.passwords)
    args.trusted_proxies = TrustedProxies(args.trusted_proxy)  # a bad one: one line, no start
    references = _references(args.reference)
    from monitor.console.confirm_clear import reset_keys

    args.reset_signers = reset_keys(args.reset_key)  # a bad one: one line, nothing started
    audit = AuditLog(args.audit or args.zones.with_name(args.zones.name + ".audit.jsonl"))
    # off loopback viewing needs a login too (the live picture shows people): sessions.py
    args.view_login = not is_loopback(host)
    return _serve(args, host, port, tls, operators, references, audit)


def _serve(args, host: str, port: int, tls: bool, operators, references, audit) -> int:
    import uvicorn

    from monitor.adapters.follower import Follower, subscribe
    from monitor.bus.session import BusKeys, default_instance, open_session
    from monitor.cli.watch import make_watchdog
    from monitor.cli.zenoh_args import bus_config as _bus_config
    from monitor.console.app import SERVER_OPTIONS, Console, build_app
    from monitor.console.edits import ZoneEditIncidents
    from monitor.console.incidents import NoIncidents, RecorderIncidents
    from monitor.console.live import LiveRenderer, LiveState, subscribe_live
    from monitor.console.zones_api import ZoneEditor
    from monitor.signals import close_bounded
    from monitor.wire.inbox import Inbox
    from monitor.wire.signing import load_public_key

    editor = ZoneEditor(args.zones)  # a broken zone file: one line, nothing started
    unknown = set(references) - set(editor.cell().cameras)
    if unknown:
        raise ConfigError(f"--reference: no camera {sorted(unknown)[0]!r} in {args.zones}")
    bus = _bus_config(args, instance=args.instance or default_instance("console"))
    keys = BusKeys.of(bus.key_prefix)
    dog = make_watchdog(args, bus, keys)
    # live pictures and alerts count only when signed with a pinned monitor key (as commands)
    live = LiveState(preview_keys=tuple(load_public_key(p) for p in args.monitor_key),
                     require_signed=not args.unauthenticated, preview_key=keys.preview,
                     alert_key=keys.alert)
    console = Console(cell_name=bus.cell, live=live,
                      renderer=LiveRenderer(live, editor.cell, references), editor=editor,
                      incidents=RecorderIncidents(args.incidents) if args.incidents
                      else NoIncidents(), operators=operators, audit=audit,
                      references=references,
                      edits=ZoneEditIncidents(args.incidents, bus.cell) if args.incidents
                      else None, view_login=args.view_login,
                      reset_operators=args.reset_operators,
                      trusted_proxies=args.trusted_proxies)
    def on_alert(alert) -> None:  # a lock-out: on the live page and in the console's log
        live.add_alert(alert)
        print(f"monitor console: alert {alert.kind}: {alert.message}", file=sys.stderr,
              flush=True)

    console.on_alert = on_alert
    app = build_app(console)
    session = open_session(bus)
    if args.reset_signers:  # confirm-clear from the live page (confirm_clear.py)
        from monitor.console.confirm_clear import ConfirmClear

        console.confirm = ConfirmClear(
            session, keys, args.reset_signers, cell=bus.cell if bus.prefix is None else "",
            monitor_keys=tuple(load_public_key(p) for p in args.monitor_key) or None)
    stop = threading.Event()
    entities: list = []
    try:
        entities = subscribe(session, keys, inbox := Inbox(args.inbox)) + \
            subscribe_live(session, keys, live)
        follower = Follower(dog, inbox, cameras=tuple(editor.cell().cameras))
        runner = threading.Thread(target=follower.run, args=([live], stop, args.tick),
                                  name="console-follower", daemon=True)
        runner.start()
        scheme = "https" if tls else "http"
        print(f"monitor console: {scheme}://{host}:{port}/ following {keys.command}"
              + ("" if operators.enabled else " (read-only: no --passwords)"),
              file=sys.stderr, flush=True)
        config = uvicorn.Config(app, host=host, port=port, log_level="warning",
                                ssl_certfile=args.https_cert if tls else None,
                                ssl_keyfile=args.https_key if tls else None,
                                timeout_graceful_shutdown=1, **SERVER_OPTIONS)
        server = uvicorn.Server(config)
        if args.duration:
            threading.Timer(args.duration, lambda: setattr(server, "should_exit", True)).start()
        server.run()  # until SIGINT/SIGTERM (uvicorn's handlers)
    finally:
        stop.set()
        if not close_bounded(session, 1.0, entities):
            print("monitor console: Zenoh did not close within 1 s; exiting anyway",
                  file=sys.stderr, flush=True)
    return 0
