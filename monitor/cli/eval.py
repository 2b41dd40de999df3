"""``monitor eval``: evaluate the whole monitor on synthetic scenarios with ground truth."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "eval", help="evaluate the monitor on synthetic scenarios",
        description="Run synthetic scenes with ground truth through the real pipeline.")
    sub = parser.add_subparsers(dest="eval_command", metavar="ACTION", required=True)
    p = sub.add_parser(
        "scenarios", help="hidden, crouching and crossing persons: missed and false STOPs",
        description="Render each scenario (640x360), run it through the detector, zone check "
        "and policy with a reset request every 0.5 s, and print per scenario: ground-truth "
        "entry into the protective zone, first STOP, missed-STOP frames, false-STOP frames "
        "and resets accepted/refused while a person is inside (docs/occlusion.md).")
    p.add_argument("names", nargs="*", help="scenarios to run (default: the whole suite)")
    p.add_argument("--list", action="store_true", help="list the scenarios and exit")
    p.add_argument("--fps", type=float, default=10.0, help="frames per second (default 10)")
    p.add_argument("--model", type=Path, help="ONNX model (default: the synthetic model)")
    p.set_defaults(func=cmd_scenarios)


def cmd_scenarios(args: argparse.Namespace) -> int:
    from monitor.errors import ConfigError
    from monitor.replay import scenarios as sc

    if not 1.0 <= args.fps <= 60.0:
        raise ConfigError(f"--fps {args.fps:g}: must be within [1, 60]")
    if args.list:
        for s in (*sc.scenarios(args.fps), *sc.behind_scenarios(args.fps)):
            needs = f" (needs {', '.join(s.needs)})" if s.needs else ""
            print(f"{s.name:20s} {s.description}{needs}")
        return 0
    chosen = sc.select(args.names, args.fps)
    from monitor.detector import Detector
    from monitor.models import synthetic

    detector = Detector(args.model if args.model else synthetic.ensure_model())
    results = []
    for k, s in enumerate(chosen, 1):
        print(f"[{k}/{len(chosen)}] {s.name}: {s.description}", file=sys.stderr, flush=True)
        results.append(sc.run_scenario(s, detector))
    print(sc.format_table(results))
    failed = [r for r in results if not r.ok]
    if failed:
        print(f"{len(failed)} of {len(results)} scenarios failed: "
              f"{', '.join(r.name for r in failed)}", file=sys.stderr)
    return 1 if failed else 0
