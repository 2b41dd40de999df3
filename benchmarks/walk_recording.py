"""The walk recorder on a loaded host: distinct frames kept when the encoder runs on the reading
thread (the recorder before issue 47) and when frames go to a writer thread (now).

An HTTP MJPEG camera at 1280x720 and 15 fps on 127.0.0.1 (tests/cameras.py), recorded at
``--fps`` for ``--seconds`` with ``--load`` busy processes beside it, each mode ``--runs``
times, alternating. Prints a table: mode, run, load average, slots, distinct share, repeated,
camera fps.

    .venv/bin/python benchmarks/walk_recording.py                  # load 8, 3 runs, 10 s
    .venv/bin/python benchmarks/walk_recording.py --load 0 --runs 1
"""

from __future__ import annotations

import argparse
import math
import multiprocessing as mp
import os
import sys
import tempfile
import threading
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from monitor.commission.recording import record_walk
from monitor.frames import SourceOptions, open_source
from monitor.replay.video import open_video_writer
from tests.cameras import MjpegCamera
from tests.test_commission_recording import _jpegs


def spin(stop) -> None:
    while not stop.is_set():
        sum(range(10_000))


def inline(source, path: Path, seconds: float, fps: float) -> dict:
    """The recorder before issue 47: every slot encoded on the reading thread."""
    slots = max(1, math.ceil(seconds * fps - 1e-9))
    writer, t0, written, repeated, last, read = None, None, 0, 0, None, 0
    while written < slots:
        frame = source.read()
        if frame is None:
            break
        read += 1
        t = frame.info.capture_time
        t0 = t if t0 is None else t0
        slot = math.floor((t - t0) * fps + 1e-6)
        if writer is None:
            writer, _ = open_video_writer(path, fps, frame.image.shape)
        while written < min(slot, slots) and last is not None:
            writer.write(last)
            written += 1
            repeated += 1
        if slot == written and written < slots:
            writer.write(frame.image)
            written += 1
        last = frame.image
    writer.release()
    return {"slots": slots, "repeated": repeated, "distinct_share": (written - repeated) / slots,
            "camera_frames": read}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--load", type=int, default=8)
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--fps", type=float, default=10.0)
    args = parser.parse_args()
    ctx = mp.get_context("spawn")
    stop = ctx.Event()
    hogs = [ctx.Process(target=spin, args=(stop,), daemon=True) for _ in range(args.load)]
    rows = []
    with MjpegCamera(_jpegs()) as camera, tempfile.TemporaryDirectory() as tmp:
        for h in hogs:
            h.start()
        try:
            for run in range(args.runs):
                for mode in ("inline (before)", "writer thread (now)"):
                    source = open_source(camera.url, "cam0", options=SourceOptions(),
                                         stop=threading.Event())
                    path = Path(tmp) / "walk.mp4"
                    try:
                        if mode.startswith("inline"):
                            r = inline(source, path, args.seconds, args.fps)
                        else:
                            r = record_walk(source, path, args.seconds, args.fps).to_dict()
                    finally:
                        source.close()
                    rows.append((mode, run + 1, os.getloadavg()[0], r))
                    print(f"{mode} run {run + 1}: {r}", file=sys.stderr)
        finally:
            stop.set()
            for h in hogs:
                h.join(10)
    print(f"\nwalk recording, 1280x720 MJPEG at 15 fps -> {args.fps:g} fps, {args.seconds:g} s, "
          f"{args.load} busy processes, {os.cpu_count()} cores\n")
    print("| recorder | run | load (1 min) | slots | distinct | repeated | frames read |")
    print("|---|---|---|---|---|---|---|")
    for mode, run, load, r in rows:
        print(f"| {mode} | {run} | {load:.1f} | {r['slots']} | "
              f"{100 * r['distinct_share']:.0f} % | {r['repeated']} | {r['camera_frames']} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
