"""Where one frame's persons are: the zone check of their boxes (with the tool's pose and the
zones that follow it), then the camera's tracks (where its lost persons could be, and the
zones that holds) and the cell persons' names. A stage that fails adds a STOP fault naming
it; its answer is then unknown, never "no persons"."""

from __future__ import annotations

import functools
import logging
from collections.abc import Callable, Mapping
from dataclasses import replace

import numpy as np

from monitor.detector import Detector
from monitor.geometry.occlusion import Placement
from monitor.health.objects import ZoneObjects
from monitor.pipeline.data import CameraState
from monitor.pipeline.fault_alerts import one_line
from monitor.policy import PolicyConfig
from monitor.tracking.cell_persons import CellPersons, Who
from monitor.tracking.gaps import DetectorGap
from monitor.tracking.pairs import heads_in_boxes
from monitor.tracking.pockets import SINGLE_WIDTH
from monitor.tracking.whereabouts import CellZones, FootGrid, FreeElsewhere
from monitor.types import Alert, Fault, FrameInfo, Persons, ZoneReport
from monitor.zones import Cell, check_persons, merge_towards_danger
from monitor.zones.check import placement
from monitor.zones.masks import MaskRule
from monitor.zones.moving import ToolState
from monitor.zones.visibility import hidden_feet

log = logging.getLogger("monitor.pipeline")  # the pipeline's log, as before the split
# a box wider than one person (``SINGLE_WIDTH`` of its height) may be two side by side: each
# end is also checked as one person this wide (of the box height; the synthetic model boxes
# a walker 0.61 wide: narrower puts the end person's feet nearer the box's edge)
DETECTOR_GAP = "detector_gap"  # the alert of a person missed longer than clear_time
END_PERSON_WIDTH = 0.5


def tool_for(now: float, tool_pose, tool_speed_mps: float | None, pose_time: float | None,
             policy: PolicyConfig) -> tuple[object, ToolState]:
    """The pose the separation uses (only with separation monitoring on: a pose fed for
    zones that follow the tool must not switch it on) and the tool state the following
    zones use (the pose with its age against ``policy.pose_timeout``)."""
    state = ToolState.at(now, tool_pose, pose_time, policy.pose_timeout, tool_speed_mps)
    return (tool_pose if policy.separation_monitoring else None), state


def zones_of(prepared, detector: Detector, frame: FrameInfo, tool_pose, tool_speed_mps,
             tool_state: ToolState | None = None) -> CellZones | None:
    """The zone checks for other boxes of this frame's camera: the hypothetical persons on
    the cells of a lost person's area (``CellZones``: on a hidden cell the full check, on a
    cell the camera sees with the feet on the cell, never taken as cut off by a fixture's
    outline or a line of the commissioning reference)."""
    if prepared is None:
        return None
    foot = detector.foot_uncertainty_px(frame.width, frame.height)
    in_view = replace(prepared, occluder_columns={}, reference_edges={})

    def check(boxes_px: np.ndarray, prep=prepared) -> ZoneReport:
        return check_persons(prep, frame.camera_id, boxes_px, tool_pose,
                             tool_speed_mps, foot, tool_state=tool_state)
    return CellZones(check, functools.partial(check, prep=in_view))


def seen_placement(prepared, camera_id: str, boxes_px: np.ndarray,
                   foot_uncertainty_px: float) -> Placement | None:
    """The floor placement of a frame's boxes as the zone check makes it (``placement``
    with the band (0, foot uncertainty)), made once for the zone check and the tracks'
    cut-off feet (``check_seen``, ``cut_feet_rows``); None where the zone check makes and
    judges its own: no boxes, no calibration, an unknown camera or non-finite boxes (the
    zone check's errors stay its own)."""
    boxes = np.asarray(boxes_px, np.float64).reshape(-1, 4)
    if prepared is None or not len(boxes) or camera_id not in prepared.cell.cameras \
            or not np.all(np.isfinite(boxes)):
        return None
    return placement(prepared, camera_id, boxes, (0.0, max(foot_uncertainty_px, 0.0)))


def check_seen(prepared, camera_id: str, boxes_px: np.ndarray, tool_pose,
               tool_speed_mps: float | None, foot_uncertainty_px: float,
               tool_state: ToolState | None, placed: Placement | None = None) -> ZoneReport:
    """The zone answer of the persons seen in a frame: every box placed as one person
    (``check_persons``), and a box too wide for one person also as one person at each of its
    ends, merged towards danger (the hits of an end are its box's row). Two persons boxed as
    one stand apart: the box's bottom centre lies between them, and the one over a zone's
    edge would be placed outside it. ``placed``: ``seen_placement`` of these boxes."""
    report = check_persons(prepared, camera_id, boxes_px, tool_pose, tool_speed_mps,
                           foot_uncertainty_px, tool_state=tool_state, placed=placed)
    boxes = np.asarray(boxes_px, np.float64).reshape(-1, 4)
    height = np.maximum(boxes[:, 3] - boxes[:, 1], 1.0)
    wide = np.flatnonzero(boxes[:, 2] - boxes[:, 0] > SINGLE_WIDTH * height)
    if not len(wide):
        return report
    one = END_PERSON_WIDTH * height[wide]
    left, right = boxes[wide].copy(), boxes[wide].copy()
    left[:, 2] = left[:, 0] + one
    right[:, 0] = right[:, 2] - one
    rows = np.concatenate([wide, wide])
    ends = check_persons(prepared, camera_id, np.concatenate([left, right]), tool_pose,
                         tool_speed_mps, foot_uncertainty_px, tool_state=tool_state)
    hits = tuple(replace(h, person=int(rows[h.person])) for h in ends.hits
                 if 0 <= h.person < len(rows))
    return merge_towards_danger(report, replace(ends, hits=hits, masked=report.masked))


def hidden_of(cell: Cell | None, camera_id: str, rule: MaskRule | None,
              measured_fraction: float | None = None, objects: ZoneObjects | None = None
              ) -> tuple[Callable[[FootGrid], np.ndarray] | None, object]:
    """The camera's hidden foot cells for a grid of its image (``zones.visibility``), and
    the key under which they stay valid (the zone set, the mask rule, the fraction).
    ``measured_fraction``: the visible share the detector was measured to need
    (``monitor.detector.visible``); the larger of it and the zone file's is used.
    ``objects``: the camera's objects placed since commissioning (their shadows hidden too)."""
    if cell is None:
        return None, None
    model = cell.camera_models.get(camera_id)
    masks = rule.polygons if rule is not None else ()
    margin = rule.margin_px if rule is not None else 0.0
    fraction = max(cell.spec.person.needed_fraction, measured_fraction or 0.0)

    def hidden(grid: FootGrid) -> np.ndarray:
        centres = grid.centres()
        out = hidden_feet(centres, (grid.width, grid.height), model, cell.spec,
                          cell.meshes, masks, margin, fraction)
        if objects is not None and objects.objects:
            spec = cell.cameras.get(camera_id)
            scale = np.array([spec.width / grid.width, spec.height / grid.height]) \
                if spec is not None else np.ones(2)
            out |= objects.hidden_cells(centres * scale)
        return out.reshape(grid.shape)
    version = objects.version if objects is not None else None
    return hidden, (id(cell), id(rule), fraction, id(objects), version)


def free_elsewhere(cameras: Mapping[str, CameraState], cell: Cell | None, camera_id: str,
                   now: float, clear_time: float) -> FreeElsewhere | None:
    """Floor points the cell's *other* calibrated cameras have seen free for ``clear_time``
    as of their newest frames (each no older than ``clear_time``): a lost person's area on
    this camera loses them too (None: no such camera)."""
    if cell is None:
        return None
    others = []
    for cid, cam in cameras.items():
        model = cell.camera_models.get(cid)
        if cid == camera_id or cam.tracker is None or model is None:
            continue
        where = cam.tracker.where
        free = where.free_now()
        if free is None or where.grid is None or where.last_time is None \
                or now - where.last_time > clear_time:
            continue
        others.append((model, where.grid, free))
    if not others:
        return None

    def seen_free(xy: np.ndarray) -> np.ndarray:
        out = np.zeros(len(xy), dtype=bool)
        pts = np.c_[np.asarray(xy, np.float64).reshape(-1, 2), np.zeros(len(xy))]
        for model, grid, free in others:
            px, front = model.project(pts)
            px = np.asarray(px, np.float64)
            ok = np.asarray(front, bool) & np.all(np.isfinite(px), axis=1)
            i = np.floor(px[:, 0] * (grid.width / model.width) / grid.cell_px)
            j = np.floor(px[:, 1] * (grid.height / model.height) / grid.cell_px)
            ok &= (i >= 0) & (i < grid.nx) & (j >= 0) & (j < grid.ny)
            hit = np.zeros(len(xy), dtype=bool)
            hit[ok] = free[j[ok].astype(int), i[ok].astype(int)]
            out |= hit
        return out
    return seen_free


def cut_feet_rows(prepared, camera_id: str, boxes_px: np.ndarray,
                  foot_px: float, placed: Placement | None = None) -> np.ndarray | None:
    """(N,) per box: the lowest image row its feet may be on when the box may be cut off at
    the bottom (a fixture, declared or seen in the reference, the image edge, a box too
    short: placed from the head as a range towards the camera); NaN where the feet are in
    view. None without a calibration of the camera. ``placed``: ``seen_placement`` of these
    boxes with ``foot_px`` (the zone check's, made once a frame)."""
    boxes = np.asarray(boxes_px, np.float64).reshape(-1, 4)
    if prepared is None or not len(boxes):
        return None
    place = placed if placed is not None else placement(prepared, camera_id, boxes,
                                                        (0.0, foot_px))
    if place is None:
        return None
    return np.where(place.hidden, place.feet_bottom_px, np.nan)


def camera_working(camera_id: str, faults: list[Fault] | tuple[Fault, ...]) -> bool:
    """False when a STOP fault of the camera or the detector says its view cannot be trusted
    in this frame: nothing it shows counts as seen free."""
    return not any(f.stop and f.source in (camera_id, "detector") for f in faults)


def locate(frame: FrameInfo, persons: Persons, cam: CameraState, prepared, detector: Detector,
           cell_persons: CellPersons, detector_error: str | None, now: float, tool_pose,
           tool_speed_mps: float | None, pose_time: float | None, policy: PolicyConfig,
           faults: list[Fault], *, working: bool = True,
           hidden: tuple[Callable[[FootGrid], np.ndarray] | None, object] = (None, None),
           elsewhere: FreeElsewhere | None = None,
           image: np.ndarray | None = None, reference: np.ndarray | None = None
           ) -> tuple[ZoneReport | None, tuple[int, ...], tuple[Who, ...], tuple[Alert, ...]]:
    """The frame's zone answer (None: unknown), each row's track id and cell person, and the
    alerts of persons the detector missed longer than clear_time (``gap_alerts``); the
    faults of a failed stage are added to ``faults``. Nothing is checked after a detector
    error (the answer is unknown, nothing is seen free); no zones (``prepared`` None) is an
    empty answer. ``working``: the camera's view can be trusted in this frame (its lost
    persons' areas shrink where it sees no person); ``hidden``: ``hidden_of``'s answer;
    ``elsewhere``: ``free_elsewhere``'s answer. ``image`` and the camera's commissioning
    ``reference``: the heads in each box (two persons boxed as one, ``monitor.tracking.pairs``;
    without a reference the tracker judges by the box widths)."""
    report, placed, foot = None, None, None
    tool_pose, tool_state = tool_for(now, tool_pose, tool_speed_mps, pose_time, policy)
    if prepared is not None and detector_error is None:
        try:
            foot = detector.foot_uncertainty_px(frame.width, frame.height)
            placed = seen_placement(prepared, frame.camera_id, persons.boxes_px, foot)
            report = check_seen(prepared, frame.camera_id, persons.boxes_px, tool_pose,
                                tool_speed_mps, foot, tool_state, placed)
        except Exception as exc:  # the zone answer is unknown: fail towards STOP
            faults.append(Fault("zone_check_error", one_line(exc), True, "zones"))
    elif detector_error is None:
        report = ZoneReport()
    track_ids: tuple[int, ...] = ()
    person_ids: tuple[Who, ...] = ()
    alerts: tuple[Alert, ...] = ()
    if detector_error is not None and cam.tracker is not None:
        cam.tracker.blind()
    if detector_error is None and cam.tracker is not None:
        # the zone answers of hypothetical persons stay valid while the zone set does,
        # unless zones follow the tool or the separation uses its pose (then: this frame)
        static = prepared is not None and not prepared.moving and tool_pose is None
        try:
            if foot is None:  # inside the try: a failure here is a tracking fault, as before
                foot = detector.foot_uncertainty_px(frame.width, frame.height)
            cut = cut_feet_rows(prepared, frame.camera_id, persons.boxes_px, foot, placed)
            heads = heads_in_boxes(image, reference, persons.boxes_px)
            update = cam.tracker.update(
                persons, report, frame.capture_time, (frame.width, frame.height),
                zones_of(prepared, detector, frame, tool_pose, tool_speed_mps, tool_state),
                working=working and report is not None, hidden=hidden[0],
                hidden_key=hidden[1], clear_time=policy.clear_time,
                zones_key=id(prepared) if static else None, free_elsewhere=elsewhere,
                feet_bottom_px=cut, heads=heads)
            named = cell_persons.name(frame.camera_id, cam.tracker, update, frame.capture_time)
            report, track_ids, person_ids = named.report, update.track_ids, named.person_ids
            for line in named.lines:  # holds begun, guesses (said once, holds stay)
                log.info("%s: %s", frame.camera_id, line)
            for line in cam.tracker.pockets.take_changes():  # pocket counts (in, out, unknown)
                log.info("%s: %s", frame.camera_id, line)
            alerts = gap_alerts(cam.tracker.gaps.take(), frame.camera_id, cell_persons,
                                policy.clear_time, now)
        except Exception as exc:  # tracks unknown: a lost person may be missing, STOP
            faults.append(Fault("tracking_error", one_line(exc), True, frame.camera_id))
    return report, track_ids, person_ids, alerts


def gap_alerts(gaps: list[DetectorGap], camera_id: str, cell_persons: CellPersons,
               clear_time: float, now: float) -> tuple[Alert, ...]:
    """A warning for each person seen again within a walk of where their hold had ended as
    seen free (``monitor.tracking.gaps``): the detector missed them for longer than
    clear_time, and a reset in that time would have been accepted with them there."""
    out = []
    for gap in gaps:
        who = cell_persons.who(camera_id, gap.track_id)
        message = (f"{camera_id}: person {who} seen again where they were lost "
                   f"{gap.seen_again - gap.lost_at:.2f} s earlier ({gap.missed_frames} frames "
                   f"missed) after the camera had shown that floor empty for clear_time "
                   f"{clear_time:g} s: the detector missed them there (or someone in front hid "
                   f"them) and their hold ended; "
                   f"raise [policy] clear_time above {gap.clear_time_s:.2f} s and check the "
                   f"light, the lens and the model (docs/tracking.md)")
        log.warning("%s", message)
        out.append(Alert(DETECTOR_GAP, "warning", message, camera_id, now, details={
            "person": who, "lost_at": round(gap.lost_at, 3),
            "seen_again": round(gap.seen_again, 3), "missed_frames": gap.missed_frames,
            "clear_time_s": clear_time, "raise_clear_time_above_s": round(gap.clear_time_s, 3),
            "box_px": [round(v, 1) for v in gap.box_px]}))
    return tuple(out)
