"""The ``monitor`` command: subcommands are registered by the modules in this package.

Every parser of the tree is a :class:`MonitorParser`: each option's help shows its default, and
the global options (``--debug``) work before or after the subcommand. Errors reach the user as
one line in their words (no exception names, no paths inside the installation); ``--debug``
shows the traceback.

Also here: the deploy kit and the docs shipped in the wheel (``deploykit.py``). May import:
everything but ``monitor.console`` (which imports the cli for its own command).
"""

from __future__ import annotations

import argparse
import errno
import importlib
import os
import re
import sys
from collections.abc import Sequence

from monitor import __version__
from monitor.errors import MonitorError

# Each module has ``register(subparsers)`` that adds its subcommands and sets ``func``.
COMMAND_MODULES = (
    "monitor.cli.detect",
    "monitor.cli.model",
    "monitor.cli.watch",
    "monitor.cli.bridge",
    "monitor.cli.router",
    "monitor.cli.operator",
    "monitor.cli.keys",
    "monitor.cli.zones",
    "monitor.cli.reference",
    "monitor.cli.run",
    "monitor.cli.eval",
    "monitor.cli.init",
    "monitor.console.cli",
    "monitor.cli.incidents",
    "monitor.cli.mute",
    "monitor.cli.objects",
    "monitor.cli.cases",
    "monitor.cli.commission",
)
# The module that registers each command: running a command imports that module alone, so
# `monitor status` does not load the detector, OpenCV or the zone tools, and `monitor zones
# list` not the tracker (start-up time, measured with `python -X importtime`). A bare
# `monitor` or `monitor --help` builds the whole tree. tests/test_cli_startup.py keeps this
# table in step with what each module registers.
COMMANDS = {
    "detect": "monitor.cli.detect", "model": "monitor.cli.model", "watch": "monitor.cli.watch",
    "bridge": "monitor.cli.bridge", "router": "monitor.cli.router",
    "reset": "monitor.cli.operator", "status": "monitor.cli.operator",
    "keys": "monitor.cli.keys", "zones": "monitor.cli.zones",
    "reference": "monitor.cli.reference", "demo": "monitor.cli.run",
    "replay": "monitor.cli.run", "run": "monitor.cli.run", "eval": "monitor.cli.eval",
    "docs": "monitor.cli.init", "init": "monitor.cli.init", "console": "monitor.console.cli",
    "incidents": "monitor.cli.incidents", "mute": "monitor.cli.mute",
    "objects": "monitor.cli.objects", "case": "monitor.cli.cases",
    "commission": "monitor.cli.commission",
}
DEBUG_HELP = "show the full traceback on errors (anywhere on the command line)"


class HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Shows every option's default, except where there is none to show (None, off) or the
    help text already states it."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        if "default" in text.lower() or not _has_default(action):
            return text
        return f"{text} (default: %(default)s)" if text else "default: %(default)s"


def _has_default(action: argparse.Action) -> bool:
    if isinstance(action, argparse._HelpAction | argparse._VersionAction):
        return False
    if not action.option_strings and action.nargs not in ("?", "*"):
        return False  # a required positional has no default
    return action.default not in (None, False, argparse.SUPPRESS, "", [], ())


class _SubParsers(argparse._SubParsersAction):
    """Subcommands whose ``help`` also becomes the description of their own ``-h``."""

    def add_parser(self, name: str, **kwargs) -> argparse.ArgumentParser:
        if "help" in kwargs and "description" not in kwargs:
            kwargs["description"] = kwargs["help"]
        return super().add_parser(name, **kwargs)


class MonitorParser(argparse.ArgumentParser):
    """The parser class of every (sub)command: defaults in help, global options everywhere."""

    def __init__(self, *args, **kwargs) -> None:
        kwargs.setdefault("formatter_class", HelpFormatter)
        super().__init__(*args, **kwargs)
        self.register("action", "parsers", _SubParsers)
        # SUPPRESS: a subcommand that is not given --debug does not reset the global one
        self.add_argument("--debug", action="store_true", default=argparse.SUPPRESS,
                          help=DEBUG_HELP)

    def add_argument(self, *args, **kwargs) -> argparse.Action:
        action = super().add_argument(*args, **kwargs)
        if action.help is None and _has_default(action):
            action.help = "default: %(default)s"
        return action

    def add_subparsers(self, **kwargs):
        kwargs.setdefault("parser_class", MonitorParser)
        return super().add_subparsers(**kwargs)


def build_parser(modules: Sequence[str] = COMMAND_MODULES) -> argparse.ArgumentParser:
    parser = MonitorParser(
        prog="monitor",
        description="Supplementary camera monitor for robot cells (not a certified protective "
        "device).",
    )
    parser.add_argument("--version", action="version", version=f"monitor {__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in modules:
        importlib.import_module(name).register(subparsers)
    return parser


_OS_REASONS = (
    (FileExistsError, "already exists"),
    (FileNotFoundError, "no such file or directory"),
    (IsADirectoryError, "is a directory, not a file"),
    (NotADirectoryError, "a part of the path is not a directory"),
    (PermissionError, "permission denied"),
)
# Paths inside the installation or a compiled library's sources mean nothing to a user.
_FOREIGN_PATH = re.compile(r"(?:[A-Za-z]:)?[\w./\\-]*(?:site-packages|dist-packages|/lib/python"
                           r"|\.py\b|\.cc\b|\.cpp\b|\.h\b|\.so\b)[\w./\\:-]*")


def user_message(exc: BaseException) -> str:
    """One line in the user's words for an exception that is not a MonitorError."""
    if isinstance(exc, OSError):
        reason = next((text for kind, text in _OS_REASONS if isinstance(exc, kind)), None)
        if reason is None:
            reason = (exc.strerror or errno.errorcode.get(exc.errno or 0, "")
                      or "input/output error").lower()
        name = exc.filename
        return f"{name}: {reason}" if name else reason
    if isinstance(exc, MemoryError):
        return "out of memory"
    text = (str(exc).strip().splitlines() or [""])[0]
    text = _FOREIGN_PATH.sub("<internal>", text)[:200]
    return (f"unexpected problem: {text}" if text else "unexpected problem") + \
        " (run again with --debug for the details)"


def _quiet_broken_pipe() -> None:
    """The reader of our output went away (``monitor detect v.mp4 | head -1``): stop quietly,
    and keep Python from complaining when it flushes stdout at exit."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):  # stdout already closed or not a real file
        pass


def main(argv: Sequence[str] | None = None) -> int:
    args_list = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in args_list
    if not debug:
        # OpenCV and FFmpeg print their own warnings before our one-line error: quiet them
        os.environ.setdefault("OPENCV_LOG_LEVEL", "OFF")
        os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")
    command = next((a for a in args_list if not a.startswith("-")), None)
    quick = COMMANDS.get(command or "")
    parser = build_parser((quick,) if quick else COMMAND_MODULES)
    args, extra = parser.parse_known_args(args_list)
    # a command may take what argparse left over (an optional positional after an option,
    # e.g. `zones add FILE ID --kind K 'x,y ...'`); anything else is refused as before
    late = getattr(args, "late_positionals", None)
    if extra and not (late is not None and late(args, extra)):
        parser.error(f"unrecognized arguments: {' '.join(extra)}")
    debug = bool(getattr(args, "debug", False))
    try:
        return int(args.func(args) or 0)
    except BrokenPipeError:
        _quiet_broken_pipe()
        return 0
    except MonitorError as exc:
        if debug:
            raise
        print(f"monitor: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    except Exception as exc:  # one line for the user; --debug shows the traceback
        if debug:
            raise
        print(f"monitor: error: {user_message(exc)}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
