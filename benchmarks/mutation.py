"""Mutation testing of the safety core with mutmut 3: do the tests notice a deliberate bug?

For each target (a module of the safety core and the fast tests that cover it) the project is
copied to a scratch folder with a ``[tool.mutmut]`` section written for that target, mutmut runs
there (the worktree is never touched), and a table prints killed / survived / equivalent per
target. Equivalent mutants (a change no test can see because behaviour is identical) are named
in ``EQUIVALENT`` below with the reason; docs/policy.md lists them too.

    .venv/bin/python benchmarks/mutation.py                  # every target
    .venv/bin/python benchmarks/mutation.py policy watchdog  # some targets
    .venv/bin/python benchmarks/mutation.py policy --survivors  # print each survivor's diff

Slow (minutes per target on two cores): a benchmark, never part of the test suite. Needs the
``test`` extra plus ``mutmut>=3.2``.
"""

from __future__ import annotations

import argparse
import fnmatch
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


@dataclass(frozen=True)
class Target:
    name: str
    files: tuple[str, ...]  # files mutmut mutates (globs relative to the project)
    tests: tuple[str, ...]  # pytest selection: the fast tests that cover them
    functions: str = ""  # regex on mutant names: only these count (e.g. one class of a file)
    # mutmut name patterns: only these mutants are run (the decision functions of a big module)
    names: tuple[str, ...] = ()


TARGETS = {
    t.name: t for t in (
        Target("policy", ("monitor/policy/*",),
               ("tests/test_policy.py", "tests/test_policy_properties.py")),
        Target("watchdog", ("monitor/bus/session.py",),
               ("tests/test_safety_mutants.py", "-k", "watchdog"), r"CommandWatchdog"),
        Target("zone_check", ("monitor/zones/check.py", "monitor/zones/volumes.py"),
               ("tests/test_zones.py", "tests/test_zone_merge.py", "tests/test_mesh_zones.py",
                "tests/test_zone_check_edges.py", "tests/test_occlusion.py",
                "tests/test_separation.py", "tests/test_masks.py", "tests/test_safety_mutants.py",
                "-m", "not slow"),
               names=("monitor.zones.check.x_check_persons*", "monitor.zones.check.x__check_*",
                      "monitor.zones.check.x__volume_hits*", "monitor.zones.volumes.x_overlaps*",
                      "monitor.zones.check.x_merge_towards_danger*",
                      "monitor.zones.check.x__worse*")),
        Target("pipeline", ("monitor/pipeline/core.py", "monitor/pipeline/evidence.py",
                            "monitor/pipeline/holds.py"),
               ("tests/test_pipeline.py", "tests/test_pipeline_edges.py",
                "tests/test_multicamera.py", "tests/test_safety_mutants.py", "-m", "not slow"),
               names=("monitor.pipeline.core.xǁPipelineǁ_inputs*",
                      "monitor.pipeline.core.xǁPipelineǁtick*",
                      "monitor.pipeline.core.xǁPipelineǁ_decide*",
                      "monitor.pipeline.evidence.x_policy_inputs*",
                      "monitor.pipeline.evidence.xǁZonesApplyingǁfault*",
                      "monitor.pipeline.holds.x_confirm_clear*")),
        Target("detector_decode", ("monitor/geometry/boxes.py",),
               ("tests/test_boxes.py", "tests/test_boxes_edges.py",
                "tests/test_safety_mutants.py", "-m", "not slow")),
        # the fault decisions (the STOP faults and their timers), not the drawing and scene code
        Target("health", ("monitor/health/camera.py",),
               ("tests/test_health.py", "tests/test_health_edges.py",
                "tests/test_safety_mutants.py", "-m", "not slow"),
               names=("monitor.health.camera.xǁ_Timerǁ*",
                      "monitor.health.camera.xǁCameraHealthǁcheck_lost*",
                      "monitor.health.camera.xǁCameraHealthǁ_check_blinded*",
                      "monitor.health.camera.xǁCameraHealthǁ_check_frozen*",
                      "monitor.health.camera.xǁ_Freezeǁ*",
                      "monitor.health.camera.xǁCameraHealthǁ_check_moved*")),
        # issue 45: the bugs a safety assessor applied by hand that no test caught, kept as
        # targets so the mutation run keeps catching them and their neighbours
        # the lost persons' areas: growth budget, ghosts, seen free (tracking/whereabouts.py)
        Target("whereabouts", ("monitor/tracking/whereabouts.py",),
               ("tests/test_tracks.py", "tests/test_evidence_gaps.py",
                "tests/test_holds_evidence.py", "-m", "not slow"),
               names=("monitor.tracking.whereabouts.xǁWhereaboutsǁupdate*",
                      "monitor.tracking.whereabouts.xǁWhereaboutsǁfound*",
                      "monitor.tracking.whereabouts.xǁWhereaboutsǁlose*",
                      "monitor.tracking.whereabouts.xǁWhereaboutsǁblind*",
                      "monitor.tracking.whereabouts.x_grow*")),
        # the image conditions per zone region: limits, measures, the verdict
        Target("conditions", ("monitor/health/conditions.py",),
               ("tests/test_envelope.py", "-m", "not slow"),
               names=("monitor.health.conditions.x_camera_limits*",
                      "monitor.health.conditions.x_measures*",
                      "monitor.health.conditions.x_judge*",
                      "monitor.health.conditions.xǁEnvelopeWatchǁprepare*",
                      "monitor.health.conditions.xǁEnvelopeWatchǁcheck*")),
        # hidden foot cells (the mask margin's sign) and another camera's seen-free map
        Target("evidence", ("monitor/zones/visibility.py", "monitor/pipeline/locate.py"),
               ("tests/test_evidence_gaps.py", "tests/test_occlusion.py",
                "tests/test_pipeline.py", "-m", "not slow"),
               names=("monitor.zones.visibility.x_hidden_feet*",
                      "monitor.pipeline.locate.x_free_elsewhere*",
                      "monitor.pipeline.locate.x_camera_working*",
                      "monitor.pipeline.locate.x_locate*")),
        # the bus decoder's bounds (nesting, numbers, size)
        Target("payload", ("monitor/wire/payload.py",),
               ("tests/test_bus_parsers.py", "tests/test_evidence_gaps.py", "-k",
                "decoder or depth or loader or refusal or hostile")),
        # the robot-side adapters: what a PLC / OPC UA client / ROS node reads (pure functions;
        # the servers around them are tested on the wire, far too slowly to run per mutant)
        Target("modbus", ("monitor/adapters/modbus_map.py",),
               ("tests/test_adapter_stale_limits.py", "tests/test_adapter_decisions.py"),
               names=("monitor.adapters.modbus_map.x_render*",
                      "monitor.adapters.modbus_map.x__ms*",
                      "monitor.adapters.modbus_map.x__set_bits*",
                      "monitor.adapters.modbus_map.x__fault_bits*",
                      "monitor.adapters.modbus_map.x_check_write*")),
        Target("opcua_values", ("monitor/adapters/opcua.py",),
               ("tests/test_adapter_stale_limits.py", "tests/test_adapter_decisions.py",
                "tests/test_adapter_opcua.py::"
                "test_the_state_is_written_first_when_safer_and_last_when_less_safe"),
               names=("monitor.adapters.opcua.x_values_of*",
                      "monitor.adapters.opcua.x_stop_values*",
                      "monitor.adapters.opcua.x_stale*",
                      "monitor.adapters.opcua.x_next_values*",
                      "monitor.adapters.opcua.x_initial_values*",
                      "monitor.adapters.opcua.x_write_order*")),
        # the verdict -> snapshot override every adapter shows, and the ROS 2 speed override
        Target("adapter_override", ("monitor/adapters/snapshot.py", "monitor/adapters/ros2.py"),
               ("tests/test_adapter_stale_limits.py", "tests/test_adapter_decisions.py",
                "tests/test_adapters_core.py::"
                "test_a_verdict_that_cannot_be_is_a_stop_snapshot_never_run",
                "tests/test_adapters_core.py::"
                "test_an_overriding_verdict_says_nothing_about_cameras_or_zones",
                "tests/test_adapters_ros2.py::"
                "test_the_override_is_zero_for_anything_but_a_valid_run_or_slow"),
               names=("monitor.adapters.snapshot.x_snapshot_of*",
                      "monitor.adapters.snapshot.x__reasons*",
                      "monitor.adapters.snapshot.x__zone_sets*",
                      "monitor.adapters.ros2.x_speed_override*")),
        # the driver's own fault decisions: frame_late, the stall gap, frames from before a gap
        Target("driver", ("monitor/driver.py",),
               ("tests/test_driver.py", "tests/test_driver_decisions.py", "-m", "not slow"),
               names=("monitor.driver.xǁDriverǁ_late_fault*",
                      "monitor.driver.xǁDriverǁ_stall_gap*",
                      "monitor.driver.xǁDriverǁstep__*")),
    )
}

# mutant name -> why no test can tell it from the original (the behaviour is the same)
EQUIVALENT: dict[str, str] = {
    **{f"monitor.bus.session.xǁCommandWatchdogǁ__init____mutmut_{n}":
       "received/boot/seq_error start as '' instead of None: each is set before it is read, or "
       "read only for truth (both falsy)" for n in (6, 7, 8)},
    **{f"monitor.bus.session.xǁCommandWatchdogǁon_command__mutmut_{n}":
       "the text of a ValueError that is caught and counted as 'invalid' is never seen"
       for n in (7, 8, 9, 43, 44, 45)},
    **{f"monitor.bus.session.xǁCommandWatchdogǁon_liveliness__mutmut_{n}":
       "rsplit('/') / rsplit('/', 2) / [+1] of rsplit('/', 1): all give the key's last "
       "segment" for n in (5, 8, 9)},
    # detector post-processing (monitor/geometry/boxes.py)
    "monitor.geometry.boxes.x_iou_matrix__mutmut_17":
        "union >= 0 vs > 0: a union of 0 means both boxes are empty, so inter is 0 and 0/1e-12 "
        "is the same 0.0",
    "monitor.geometry.boxes.x_ios_matrix__mutmut_19":
        "smaller >= 0 vs > 0: the intersection is never larger than the smaller box, so it is "
        "0 and 0/1e-12 is the same 0.0",
    "monitor.geometry.boxes.x_connected_groups__mutmut_5":
        "an early return for one box gives arange(1) = [0], exactly what the loop computes",
    "monitor.geometry.boxes.x_nms__mutmut_16":
        "numpy reads sort kinds case-insensitively: 'STABLE' is 'stable'",
    "monitor.geometry.boxes.x_merge_boxes__mutmut_124":
        "numpy reads sort kinds case-insensitively: 'STABLE' is 'stable'",
    # camera health fault decisions (monitor/health/camera.py)
    "monitor.health.camera.xǁ_Timerǁupdate__mutmut_4":
        "the 'not holding' sentinel -1.0 vs -2.0: only compared with limits >= 0",
    "monitor.health.camera.xǁCameraHealthǁ_check_blinded__mutmut_17":
        "reason None vs '' before a check sets it: both falsy, and only read for truth",
    "monitor.health.camera.xǁCameraHealthǁ_check_blinded__mutmut_39":
        "'reason or held >= limit': without a reason the timer says -1, below every limit >= 0",
    "monitor.health.camera.xǁCameraHealthǁ_check_blinded__mutmut_40":
        "held > limit vs >=: the timer adds 1e-9 to what has held, so the two differ only when "
        "float sums meet a limit exactly",
    "monitor.health.camera.xǁCameraHealthǁ_check_moved__mutmut_42":
        "_moved_raw None vs False: it is only read for truth",
    "monitor.health.camera.xǁCameraHealthǁ_check_moved__mutmut_5":
        "margin=None vs False: _small_boxes reads it only for truth",
    # the zone check (monitor/zones/check.py)
    **{f"monitor.zones.check.x__check__mutmut_{n}":
       "zip(strict=...) of np.nonzero's two index lists, always of equal length"
       for n in (110, 113, 114)},
    **{f"monitor.zones.check.x__volume_hits__mutmut_{n}":
       "zip(strict=...) of np.nonzero's two index lists, always of equal length"
       for n in (29, 32, 33)},
    **{f"monitor.zones.check.x__check__mutmut_{n}":
       "asarray without dtype float64: integer boxes give the same floats one step later"
       for n in (18, 20)},
    "monitor.zones.check.x__check__mutmut_22": "reshape(-2, 4): NumPy reads any negative size "
                                               "as 'infer', like -1",
    **{f"monitor.zones.check.x__check__mutmut_{n}":
       "camera_centre None / missing: place_persons computes the same centre itself"
       for n in (49, 57, 59)},
    "monitor.zones.check.x__check__mutmut_106": "distance_m=None passed or left to its default",
    **{f"monitor.zones.volumes.x_overlaps__mutmut_{n}":
       "python-fcl builds a default request / result when given None or nothing"
       for n in (3, 4, 8)},
    **{f"monitor.zones.volumes.x_overlaps__mutmut_{n}":
       "the mesh-inside-the-person fallback (a vertex within the swept cylinder): FCL's solid "
       "triangle-vs-shape test already reports such a mesh (tests/test_mesh_zones.py), so no "
       "input reaches this line with another answer; kept as a defence"
       for n in range(19, 36)},
    "monitor.zones.check.x__volume_hits__mutmut_81": "distance_m=None passed or left to its "
                                                     "default",
    **{f"monitor.zones.check.x__volume_hits__mutmut_{n}":
       "a miss of the per-person shape cache: the same shapes are built again"
       for n in (35, 36)},
    # the pipeline's timer step, evidence and confirm-clear (monitor/pipeline/; numbers as
    # mutmut 3.8 gives them for the current files: they shift when the named functions change)
    "monitor.pipeline.core.xǁPipelineǁtick__mutmut_11":
        "with_frame=None vs False: it is only read for truth",
    "monitor.pipeline.evidence.x_policy_inputs__mutmut_98":
        "the zone report handed in on a tick too: the policy reads zone_report only when the "
        "step has a frame (frame_time set), and a tick has none",
    "monitor.pipeline.holds.x_confirm_clear__mutmut_11":
        "break vs continue on a camera without a tracker: every camera gets one in __init__",
    "monitor.geometry.boxes.x_merge_boxes__mutmut_12":
        "reshape(None) of the empty 1-D score array is the same (0,) array",
    # the bus decoder (monitor/wire/payload.py)
    "monitor.wire.payload.x_check_depth__mutmut_6":
        "the shortcut for payloads with few brackets at < instead of <=: exactly max_depth "
        "brackets are scanned instead of skipped, and the scan finds no deeper nesting either",
    # the Modbus register map (monitor/adapters/modbus_map.py)
    "monitor.adapters.modbus_map.x__set_bits__mutmut_12":
        "table[:16] vs [:15]: the 16th set's own bit would be 15, the 'other' bit it gets",
    # the ROS 2 speed override (monitor/adapters/ros2.py)
    "monitor.adapters.ros2.x_speed_override__mutmut_9":
        "0.0 < scale vs <=: a scale of 0 gives 0.0 either way (the scale itself or the "
        "fallback; -0.0 == 0.0)",
    # the driver (monitor/driver.py)
    **{f"monitor.driver.xǁDriverǁstep__mutmut_{n}":
       "start read from the clock (or 1.0) without stall detection: it is read only by "
       "_stall_gap, which returns None then, and inside 'if stall_after_s is not None'"
       for n in (8, 10)},
    # the OPC UA values (monitor/adapters/opcua.py)
    "monitor.adapters.opcua.x_write_order__mutmut_31":
        "old values without a SpeedScale read as scale 1 instead of 0: the server always has "
        "one (initial_values), and without one the State default 0 decides unless the new "
        "State is 0 too, which is always a STOP at scale 0.0 (stop_values, snapshot_of)",
}

_SKIP = {".git", ".venv", "mutants", "__pycache__", ".pytest_cache", ".hypothesis",
         ".ruff_cache", "workcell_monitor.egg-info"}


def _copy_project(dest: Path) -> None:
    for item in ROOT.iterdir():
        if item.name in _SKIP:
            continue
        if item.is_dir():
            shutil.copytree(item, dest / item.name,
                            ignore=shutil.ignore_patterns(*_SKIP, "*.onnx"))
        else:
            shutil.copy2(item, dest / item.name)


def _toml_list(values: tuple[str, ...]) -> str:
    return "[" + ", ".join(f'"{v}"' for v in values) + "]"


def _configure(dest: Path, target: Target) -> None:
    text = (dest / "pyproject.toml").read_text()
    text = re.sub(r"(?ms)^\[tool\.mutmut\].*?(?=^\[|\Z)", "", text)
    text += (
        "\n[tool.mutmut]\n"
        'source_paths = ["monitor/"]\n'
        'also_copy = ["zones/", "models/"]\n'
        f"only_mutate = {_toml_list(target.files)}\n"
        f"pytest_add_cli_args_test_selection = {_toml_list(target.tests)}\n"
        # one process: the suite's addopts start xdist workers, whose coverage of the mutated
        # functions mutmut's stats run never sees (it then finds no test for any mutant)
        'pytest_add_cli_args = ["-n", "0", "-x", "-q", "-p", "no:cacheprovider"]\n'
        "use_git_change_detection = false\n"
    )
    (dest / "pyproject.toml").write_text(text)


def _results(workdir: Path, mutmut: str) -> dict[str, str]:
    out = subprocess.run([mutmut, "results", "--all", "true"], cwd=workdir,
                         capture_output=True, text=True, check=False).stdout
    found = {}
    for line in out.splitlines():
        name, sep, status = line.strip().rpartition(": ")
        if sep and name:
            found[name] = status
    return found


def run_target(target: Target, mutmut: str, show_survivors: bool, keep: bool,
               examples: str) -> dict[str, int]:
    work = Path(tempfile.mkdtemp(prefix=f"mutation-{target.name}-"))
    try:
        _copy_project(work)
        _configure(work, target)
        env = {**os.environ, "POLICY_PROPERTY_EXAMPLES": examples}
        t0 = time.perf_counter()
        with open(work / "mutmut.log", "w") as log:
            subprocess.run([mutmut, "run", "--max-children", "2", *target.names], cwd=work,
                           env=env, stdout=log, stderr=subprocess.STDOUT, check=False)
        seconds = time.perf_counter() - t0
        results = {n: s for n, s in _results(work, mutmut).items()
                   if re.search(target.functions, n)
                   and (not target.names or any(fnmatch.fnmatchcase(n, p) for p in target.names))}
        counts = {"mutants": len(results), "killed": 0, "survived": 0, "equivalent": 0,
                  "no tests": 0, "timeout": 0, "other": 0, "seconds": round(seconds)}
        if results and all(status == "not checked" for status in results.values()):
            # mutmut stopped before any mutant (its stats or clean test run failed): say why
            tail = (work / "mutmut.log").read_text(errors="replace").replace("\r", "\n")
            lines = [ln for ln in tail.splitlines()
                     if ln.strip() and not re.search("[\u2800-\u28ff]", ln)]  # no spinners
            print(f"  {target.name}: mutmut checked no mutant; the end of its output:")
            print("    " + "\n    ".join(lines[-25:]))
        survivors = []
        for name, status in sorted(results.items()):
            if status == "survived" and name in EQUIVALENT:
                counts["equivalent"] += 1
            elif status in counts:
                counts[status] += 1
                if status in ("survived", "no tests"):
                    survivors.append(name)
            else:
                counts["other"] += 1
        for name in survivors:
            print(f"  {target.name}: {results[name]}: {name}")
            if show_survivors:
                diff = subprocess.run([mutmut, "show", name], cwd=work, capture_output=True,
                                      text=True, check=False).stdout
                print("    " + diff.replace("\n", "\n    "))
        return counts
    finally:
        if keep:
            print(f"  kept {work}")
        else:
            shutil.rmtree(work, ignore_errors=True)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("targets", nargs="*", default=[],
                        help=f"targets to run (default: all): {', '.join(TARGETS)}")
    parser.add_argument("--survivors", action="store_true", help="print each survivor's diff")
    parser.add_argument("--keep", action="store_true", help="keep the scratch folders")
    parser.add_argument("--examples", default="60",
                        help="hypothesis sequences per property test run (default 60)")
    args = parser.parse_args(argv)
    unknown = [t for t in args.targets if t not in TARGETS]
    if unknown:
        parser.error(f"unknown target {unknown[0]!r} (targets: {', '.join(TARGETS)})")
    mutmut = shutil.which("mutmut", path=str(Path(sys.executable).parent)) or "mutmut"
    rows = []
    for name in args.targets or list(TARGETS):
        counts = run_target(TARGETS[name], mutmut, args.survivors, args.keep, args.examples)
        judged = counts["mutants"] - counts["equivalent"]
        # a mutant that makes the tests hang is noticed too
        score = (100.0 * (counts["killed"] + counts["timeout"]) / judged if judged
                 else float("nan"))
        rows.append((name, counts, score))
    print(f"\n{'target':16} {'mutants':>8} {'killed':>7} {'survived':>9} {'equiv':>6} "
          f"{'no tests':>9} {'timeout':>8} {'score %':>8} {'time s':>7}")
    for name, c, score in rows:
        print(f"{name:16} {c['mutants']:8} {c['killed']:7} {c['survived']:9} "
              f"{c['equivalent']:6} {c['no tests']:9} {c['timeout']:8} {score:8.1f} "
              f"{c['seconds']:7}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
