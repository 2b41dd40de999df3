"""The replay's annotated video: what the monitor saw and decided, frame by frame, drawn so that
a reviewer understands it without the code.

Every frame shows a header (video time, frame number, camera id), the zones with labels that
never overlap (``monitor.zones.labels``) and a legend of the zone colours (the colours of
``monitor zones preview``), each person's box labelled with the id the commands use (the
tracker's id), and for a person in a zone the floor range the zone check tested (from
``monitor.geometry.occlusion``'s placement: the nearest to the farthest floor position, drawn back
into the image), resets (accepted or refused, by whom) and alerts for ``HOLD_S`` seconds after they
happen, the lost persons' areas, what the camera cannot see and the hidden pockets with their
counts (``monitor.records.areas_draw``: why the cell is held), and the command in the bottom bar.

``Annotator.step`` returns the image and a ``Drawn`` record of every text it drew, so tests
assert on the texts rather than read them back from pixels.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from monitor.health import draw_health
from monitor.pipeline import StepResult
from monitor.policy import RUN, SLOW, STOP
from monitor.records.areas_draw import (
    draw_areas,
    draw_key,
    draw_pockets,
    draw_unseen,
    key_rect,
)
from monitor.records.events import describe
from monitor.timetext import TimeText
from monitor.zones import Cell
from monitor.zones.check import placement
from monitor.zones.draw import (
    COLOURS_BGR,
    LEGEND_KINDS,
    ZoneDrawCache,
    ZoneLabel,
    draw_legend,
    draw_zones_labelled,
    legend_rect,
)
from monitor.zones.labels import Rect

STATE_BGR = {RUN: (60, 170, 60), SLOW: (0, 170, 255), STOP: (40, 40, 220)}
PERSON_BGR = (60, 200, 60)  # a person in no zone
HOLD_S = 2.0  # a reset or an alert stays on screen this long (seconds of video)
HEADER_PX = 28  # the header band at the top
BAR_PX = 44  # the command bar at the bottom
EVENT_ROW_PX = 22
MAX_EVENT_ROWS = 4  # the newest events shown at once (a burst of alerts must not hide the cell)
FONT = cv2.FONT_HERSHEY_SIMPLEX


@dataclass(frozen=True)
class FloorRange:
    """The floor positions the zone check tested for one person, drawn into the image.

    ``points_px`` (K, 2): the cell-floor segment from the nearest to the farthest position
    projected into the image (empty when it cannot be projected); ``text`` what is written
    beside it."""

    person: int | str  # the person id (as in the box label and the commands)
    near_m: tuple[float, float]
    far_m: tuple[float, float]
    located: bool
    hidden: bool  # the feet may be hidden: the range comes from the head
    points_px: np.ndarray
    text: str


@dataclass(frozen=True)
class Drawn:
    """Every text drawn on one frame (and the layout that matters for a reviewer)."""

    header: str
    persons: tuple[str, ...]  # one box label per person, in the rows of ``result.persons``
    person_ids: tuple[int | str, ...]
    events: tuple[str, ...]  # resets and alerts still on screen
    banner: str  # the command bar: state, speed, latch, tool separation
    reason: str
    legend: tuple[str, ...]
    zone_labels: tuple[ZoneLabel, ...]
    floor_ranges: tuple[FloorRange, ...]
    faults: tuple[str, ...]
    areas: tuple[str, ...] = ()  # the label of each lost person's area that holds a zone
    pockets: tuple[str, ...] = ()  # the label of each hidden pocket (its count)


def person_ids(result: StepResult) -> tuple[int | str, ...]:
    """The id of each person row as the commands' reasons name it (``monitor.policy.causes``):
    the cell person's (one id for one person on every camera, ``monitor.tracking.cell_persons``),
    the tracker's id without one, the row index only where there is no tracker."""
    n = len(result.persons) if result.persons is not None else 0
    if len(result.person_ids) == n:
        return tuple(result.person_ids)
    if len(result.track_ids) == n:
        return tuple(int(i) for i in result.track_ids)
    return tuple(range(n))


def event_texts(result: StepResult) -> list[str]:
    """The resets and alerts of one step as a reviewer reads them."""
    out = []
    reset = result.command.reset
    if reset is not None:
        out.append(f"reset by {reset.operator}: {reset.message}")
    for alert in result.alerts:
        if reset is not None and reset.message in alert.message:
            out.append(f"alert {alert.kind}")  # the reset's line above says the rest
        else:
            out.append(f"alert {alert.kind}: {alert.message}")
    return out


def header_text(result: StepResult, camera_id: str, when: TimeText | None = None) -> str:
    """Time, frame and camera. The time: the video's seconds (replay), or ``when``'s text of
    it (the live recorder's clips: local wall-clock time)."""
    seq = result.frame.seq if result.frame is not None else -1
    at = f"t {result.now:.2f} s" if when is None else when(result.now)
    text = f"{at}   frame {seq}   camera {camera_id}"
    sets = getattr(result.command, "zone_sets", ())
    if sets:  # the zone sets in force; two or more while switching (docs/cases.md)
        text += f"   sets {'+'.join(sets)}" + ("  (switching)" if len(sets) > 1 else "")
    return text


class Annotator:
    """Draws the frames of one camera in order; remembers the resets and alerts of the last
    ``hold_s`` seconds (also those decided on timer ticks between frames)."""

    def __init__(self, cell: Cell | None, camera_id: str, watch: list,
                 foot_band_px: tuple[float, float] = (0.0, 0.0), hold_s: float = HOLD_S,
                 prepared=None):
        self.cell, self.camera_id, self.watch = cell, camera_id, watch
        # the prepared zones the pipeline checked with (its reference's edges included)
        self.prepared = prepared
        self.foot_band_px = foot_band_px
        self.hold_s = hold_s
        self.recent: list[tuple[float, str]] = []
        self.zone_cache = ZoneDrawCache()

    def step(self, result: StepResult, image: np.ndarray | None
             ) -> tuple[np.ndarray, Drawn] | None:
        """Take a step's events; draw its frame (None for a timer tick)."""
        self.recent.extend((result.now, text) for text in event_texts(result))
        self.recent = [(t, x) for t, x in self.recent if result.now - t < self.hold_s]
        if image is None:
            return None
        shown = tuple(x for _, x in self.recent[-MAX_EVENT_ROWS:])
        return annotate(image, result, self.cell, self.camera_id, self.watch, shown,
                        self.foot_band_px, self.zone_cache, prepared=self.prepared)


def annotate(image: np.ndarray, result: StepResult, cell: Cell | None, camera_id: str,
             watch: list, events: tuple[str, ...] = (),
             foot_band_px: tuple[float, float] = (0.0, 0.0),
             zone_cache: ZoneDrawCache | None = None, when: TimeText | None = None,
             prepared=None) -> tuple[np.ndarray, Drawn]:
    """The frame with everything drawn on (see the module docstring), and what was drawn.
    ``when``: times as text (header, description); None: seconds of the video."""
    h, w = image.shape[:2]
    top = HEADER_PX + EVENT_ROW_PX * len(events)  # the legend sits below header and events
    reserved: list[Rect] = [(0, 0, w, top), (0, h - BAR_PX, w, h), legend_rect(w, top + 4)]
    # the key of the areas' colours below the legend, when this camera has any to show
    keyed = any(v.camera_id == camera_id
                for v in (*result.areas, *result.unseen, *result.pockets))
    key_top = legend_rect(w, top + 4)[3] + 4
    if keyed:
        reserved.append(key_rect(w, key_top))
    hits = {x.zone_id for x in result.zone_report.hits} if result.zone_report else set()
    if cell is not None:
        out, labels = draw_zones_labelled(image, cell, camera_id, hits, reserved,
                                          cache=zone_cache)
    else:
        out, labels = image.copy(), []
    # why the cell is held: what this camera cannot see (hatched), where lost persons could be
    draw_unseen(out, result.unseen, camera_id)
    avoid = [legend_rect(w, top + 4), *([key_rect(w, key_top)] if keyed else [])]
    areas = draw_areas(out, result.areas, camera_id, top_px=top, avoid=avoid)
    # the hidden pockets over the areas: their count says what ends a hold behind a cabinet
    pockets = draw_pockets(out, result.pockets, camera_id, avoid=avoid)
    faults: tuple[str, ...] = ()
    if result.health is not None:
        draw_health(out, result.health, watch, text_top=top + 22)
        faults = tuple(f"{f.name}: {f.reason}"[:90] for f in result.health.faults)
    ids = person_ids(result)
    labels_drawn, ranges = _draw_persons(out, result, cell, camera_id, ids, foot_band_px,
                                         prepared)
    legend = tuple(kind for kind, _ in draw_legend(out, top + 4, LEGEND_KINDS))
    if keyed:
        draw_key(out, key_top)
    header = header_text(result, camera_id, when)
    _draw_header(out, header, events)
    banner, reason = _draw_bar(out, result, when)
    return out, Drawn(header, labels_drawn, ids, events, banner, reason, legend, tuple(labels),
                      ranges, faults, areas, pockets)


def _worst_kind(result: StepResult) -> dict[int, str]:
    """Per person row, the worst zone kind it is in (protective over warning)."""
    out: dict[int, str] = {}
    for hit in result.zone_report.hits if result.zone_report else ():
        if out.get(hit.person) != "protective":
            out[hit.person] = hit.kind
    return out


def _draw_persons(out: np.ndarray, result: StepResult, cell: Cell | None, camera_id: str,
                  ids: tuple[int | str, ...], foot_band_px: tuple[float, float],
                  prepared=None) -> tuple[tuple[str, ...], tuple[FloorRange, ...]]:
    persons = result.persons
    if persons is None or not len(persons):
        return (), ()
    in_zone = _worst_kind(result)
    ranges = floor_ranges(cell, camera_id, persons.boxes_px, ids, sorted(in_zone),
                          foot_band_px, prepared=prepared) if cell is not None else ()
    texts = []
    for k, (x1, y1, x2, y2) in enumerate(persons.boxes_px):
        colour = COLOURS_BGR.get(in_zone.get(k, ""), PERSON_BGR)
        cv2.rectangle(out, (int(x1), int(y1)), (int(x2) - 1, int(y2) - 1), colour, 3)
        text = f"person {ids[k]} {persons.scores[k]:.2f}"
        _text_on_black(out, text, (int(x1), max(HEADER_PX + 16, int(y1) - 6)), colour, 0.6, 2)
        texts.append(text)
    for r in ranges:
        row = ids.index(r.person)
        colour = COLOURS_BGR.get(in_zone.get(row, ""), PERSON_BGR)
        if len(r.points_px) >= 2:
            pts = np.round(r.points_px).astype(np.int32)
            cv2.polylines(out, [pts], False, (0, 0, 0), 7, cv2.LINE_AA)
            cv2.polylines(out, [pts], False, colour, 3, cv2.LINE_AA)
            for end in (pts[0], pts[-1]):
                cv2.circle(out, (int(end[0]), int(end[1])), 5, colour, -1, cv2.LINE_AA)
        x1, _, _, y2 = persons.boxes_px[row]
        below = int(max(y2, r.points_px[:, 1].max() if len(r.points_px) else y2)) + 18
        _text_on_black(out, r.text, (int(x1), min(below, out.shape[0] - BAR_PX - 6)), colour,
                       0.5, 1)
    return tuple(texts), ranges


def floor_ranges(cell: Cell, camera_id: str, boxes_px: np.ndarray, ids: tuple[int | str, ...],
                 rows: list[int], foot_band_px: tuple[float, float] = (0.0, 0.0),
                 samples: int = 16, prepared=None) -> tuple[FloorRange, ...]:
    """The floor range behind each zone hit of ``rows``: the placement the zone check used
    (``monitor.zones.check.placement``, same boxes and foot band), its nearest..farthest
    segment on the cell floor projected back into the image. A camera without calibration
    (image zones only) has no floor range: none."""
    rows = [r for r in rows if 0 <= r < len(boxes_px)]
    prep = prepared if prepared is not None else cell.prepared
    place = placement(prep, camera_id, boxes_px, foot_band_px) if rows else None
    model = cell.camera_models.get(camera_id)
    if place is None or model is None:
        return ()
    out = []
    for r in rows:
        near, far = place.near_m[r], place.far_m[r]
        located, hidden = bool(place.located[r]), bool(place.hidden[r])
        pts = np.zeros((0, 2))
        if located:
            t = np.linspace(0.0, 1.0, samples)[:, None]
            line = np.c_[near + t * (far - near), np.zeros(samples)]
            px, front = model.project(line)
            keep = front & np.all(np.isfinite(px), axis=1) & np.all(np.abs(px) < 1e5, axis=1)
            pts = px[keep]
            length = float(np.hypot(*(far - near)))
            text = f"person {ids[r]} floor range {length:.1f} m" + \
                (" (feet may be hidden: from the head)" if hidden else "")
        else:
            text = f"person {ids[r]} cannot be placed: counts in every zone"
        out.append(FloorRange(ids[r], (float(near[0]), float(near[1])),
                              (float(far[0]), float(far[1])), located, hidden, pts, text))
    return tuple(out)


def _text_on_black(img: np.ndarray, text: str, org: tuple[int, int], colour, scale: float,
                   thick: int) -> None:
    (tw, th), base = cv2.getTextSize(text, FONT, scale, thick)
    x, y = org
    cv2.rectangle(img, (x - 2, y - th - 3), (x + tw + 2, y + base), (0, 0, 0), -1)
    cv2.putText(img, text, (x, y), FONT, scale, colour, thick, cv2.LINE_AA)


def _draw_header(out: np.ndarray, header: str, events: tuple[str, ...]) -> None:
    """The header band (time, frame, camera) and below it one row per recent event."""
    w = out.shape[1]
    cv2.rectangle(out, (0, 0), (w, HEADER_PX - 1), (30, 30, 30), -1)
    cv2.putText(out, header, (10, HEADER_PX - 8), FONT, 0.65, (255, 255, 255), 2, cv2.LINE_AA)
    for k, text in enumerate(events):
        y0 = HEADER_PX + k * EVENT_ROW_PX
        refused = "refused" in text or text.startswith("alert")
        colour = (80, 80, 255) if refused else (120, 230, 120)
        cv2.rectangle(out, (0, y0), (w, y0 + EVENT_ROW_PX - 1), (0, 0, 0), -1)
        cv2.putText(out, text[:110], (10, y0 + EVENT_ROW_PX - 6), FONT, 0.55, colour, 1,
                    cv2.LINE_AA)


def _draw_bar(out: np.ndarray, result: StepResult,
              when: TimeText | None = None) -> tuple[str, str]:
    """The command bar at the bottom: state, speed, latch, tool separation, and why."""
    cmd = result.command
    h, w = out.shape[:2]
    cv2.rectangle(out, (0, h - BAR_PX), (w, h), STATE_BGR[cmd.state], -1)
    text = f"{cmd.state}  x{cmd.speed_scale:.2f}"
    if cmd.latched:
        text += "  LATCHED - reset possible" if getattr(cmd, "reset_possible", False) \
            else "  LATCHED - reset needed"
    rep = result.zone_report
    if rep is not None and rep.tool_separation_m is not None:
        text += f"  tool {rep.tool_separation_m:.2f} m"
        if rep.required_separation_m is not None:
            text += f" (needs {rep.required_separation_m:.2f} m)"
    reason = describe(cmd) if when is None else describe(cmd, when)
    cv2.putText(out, text, (12, h - 16), FONT, 0.8, (255, 255, 255), 2)
    cv2.putText(out, reason[:80], (int(w * 0.45), h - 16), FONT, 0.55, (255, 255, 255), 1,
                cv2.LINE_AA)
    return text, reason[:80]
