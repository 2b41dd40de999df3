"""The ``monitor`` command: subcommands are registered by the modules in this package."""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from collections.abc import Sequence

from monitor import __version__
from monitor.errors import MonitorError

# Each module has ``register(subparsers)`` that adds its subcommands and sets ``func``.
COMMAND_MODULES = (
    "monitor.cli.detect",
    "monitor.cli.model",
    "monitor.cli.bus",
    "monitor.cli.zones",
    "monitor.cli.reference",
    "monitor.cli.run",
    "monitor.cli.eval",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="monitor",
        description="Supplementary camera monitor for robot cells (not a certified protective "
        "device).",
    )
    parser.add_argument("--version", action="version", version=f"monitor {__version__}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(subparsers)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    if "--debug" not in (sys.argv[1:] if argv is None else argv):
        # OpenCV and FFmpeg print their own warnings before our one-line error: quiet them
        os.environ.setdefault("OPENCV_LOG_LEVEL", "OFF")
        os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except MonitorError as exc:
        if args.debug:
            raise
        print(f"monitor: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    except Exception as exc:  # one line for the user; --debug shows the traceback
        if args.debug:
            raise
        print(f"monitor: error: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
