"""Running a scenario and scoring it: ``run_scenario`` renders a ``Scenario`` (a ``CellScene``
with its zone file), feeds every frame to ``monitor.pipeline.Pipeline`` with the real detector,
sends a reset request every 0.5 s and scores the commands against the ground truth (the scores
are listed in ``monitor.replay.scenarios``, which holds the scene sets)."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

import numpy as np

from monitor.pipeline import Pipeline, StepResult
from monitor.policy import STOP, PolicyConfig, ResetRequest
from monitor.replay.end_holds import EndHold, hidden_persons, judge_end_holds
from monitor.scene.cell import SCENE_ROBOT_BASE, CellFrameTruth, CellScene, zone_data
from monitor.types import FrameInfo
from monitor.zones import parse_cell

RESET_PERIOD_S = 0.5
CLEAR_VIEW_FRACTION = 0.95
OUTSIDE_MARGIN_M = 1.0
PROTECTIVE = ((-1.0, -1.0), (1.0, 1.0))


@dataclass(frozen=True)
class Scenario:
    name: str
    description: str
    scene: CellScene
    needs: tuple[str, ...] = ()  # pipeline features the scenario relies on ("tracker", "masks")
    extra_zones: tuple[dict, ...] = ()
    check_false_stops: bool = True
    declare_occluders: bool = True  # False: the zone file leaves the fixtures out
    declare_floors: bool = True  # False: the zone file leaves the platforms out
    # the zone file accepts zone floor no camera sees (a bench taller than a crouching person
    # hides one right behind it): ``unobserved_ok`` on the protective and warning zones
    unobserved_ok: bool = False
    # frames the detector misses: it is shown the empty cell instead (a real detector that
    # flickers); the ground truth still has the persons there
    missed: frozenset[int] = frozenset()
    # the monitor has the commissioning reference of the empty cell (fixtures included, even
    # those the zone file leaves out): its horizontal edges tell boxes cut off by a fixture
    reference: bool = True
    # ``person:`` settings of the zone file (e.g. (("crouching_height_m", 1.0),))
    person: tuple[tuple[str, float], ...] = ()
    # the zone file as real footage is set up: image polygons, no calibration
    image_polygons: bool = False

    def zone_data(self) -> dict:
        data = zone_data(self.scene, PROTECTIVE)
        # the painted robot hides nobody (a scene with a pedestal adds it as a block)
        data["robot_base"] = dict(SCENE_ROBOT_BASE)
        if not self.declare_occluders:
            data["zones"] = [z for z in data["zones"] if z["kind"] != "occluder"]
        if not self.declare_floors:
            data.pop("floors", None)
        if self.unobserved_ok:
            for z in data["zones"]:
                if z["kind"] in ("protective", "warning"):
                    z["unobserved_ok"] = True
        data["zones"] += [dict(z) for z in self.extra_zones]
        if self.person:
            data["person"] = {**data.get("person", {}), **dict(self.person)}
        if self.image_polygons:
            data = image_polygon_zones(self.scene, data)
        return data


@dataclass(frozen=True)
class FrameScore:
    time_s: float
    state: str
    inside: bool  # ground truth: a person overlaps the protective zone
    clear_outside: bool  # every person in clear view and > 1 m outside (for long enough)
    reset_accepted: bool | None  # None: no reset handled in this frame


@dataclass(frozen=True)
class ScenarioResult:
    name: str
    frames: int
    entry_s: float | None  # first frame with a person inside the protective zone
    first_stop_s: float | None  # start of the STOP that holds at the entry
    missed_stop_frames: int
    false_stop_frames: int
    resets_accepted_inside: int
    resets_refused_inside: int
    resets_accepted_outside: int
    needs: tuple[str, ...] = ()
    # availability: resets refused although nobody has been inside the protective zone for
    # the policy's clear time; frames with a hold of a lost person and nobody in the scene
    resets_refused_free: int = 0
    holds_when_empty: int = 0
    holds_at_end: int = 0  # lost persons' holds alive after the last frame
    # of those: a person really hidden where the hold covers / nobody hidden there
    # (``monitor.replay.end_holds``)
    holds_at_end_correct: int = 0
    holds_at_end_ghost: int = 0
    end_holds: tuple[EndHold, ...] = field(default=(), repr=False)
    oldest_hold_s: float = 0.0  # the longest any hold was alive after its person was lost
    scores: tuple[FrameScore, ...] = field(default=(), repr=False)

    @property
    def ok(self) -> bool:
        late = (self.entry_s is not None and (self.first_stop_s is None
                                              or self.first_stop_s > self.entry_s + 1e-9))
        return (self.missed_stop_frames == 0 and self.resets_accepted_inside == 0
                and not late and self.false_stop_frames == 0)


@dataclass(frozen=True)
class StepSeen:
    """One frame of a running scenario, for a diagnostic (``run_scenario``'s ``observe``):
    the ground truth, the pipeline after the step (its trackers' areas), the step's result,
    and whether its reset was refused although nobody had been inside for the grace."""

    index: int
    truth: CellFrameTruth
    pipeline: Pipeline
    result: StepResult
    refused_free: bool


def rect_distance(p: tuple[float, float], rect=PROTECTIVE) -> float:
    """How far floor point ``p`` lies outside the rectangle ``rect`` (0: inside)."""
    (x0, y0), (x1, y1) = rect
    dx = max(x0 - p[0], 0.0, p[0] - x1)
    dy = max(y0 - p[1], 0.0, p[1] - y1)
    return math.hypot(dx, dy)


def image_polygon_zones(scene: CellScene, data: dict, margin_m: float = 0.4) -> dict:
    """``data`` with its protective and warning zones as image polygons (their floor outline
    grown by ``margin_m``, a person's radius and a little, projected into the camera) and no
    calibration nor occluders: a camera set up by drawing zones on its picture (an image
    polygon tests the feet, so a user draws it a body's width around the floor to guard)."""
    cam = scene.camera
    zones = []
    for z in data["zones"]:
        if z["kind"] not in ("protective", "warning"):
            continue
        if z["shape"] == "box":
            (x0, y0, _), (x1, y1, _) = z["min_m"], z["max_m"]
        else:
            (x0, y0), (x1, y1) = np.min(z["points_m"], axis=0), np.max(z["points_m"], axis=0)
        g = margin_m
        floor = [[x0 - g, y0 - g], [x1 + g, y0 - g], [x1 + g, y1 + g], [x0 - g, y1 + g]]
        px = cam.project(np.array([[x, y, 0.0] for x, y in floor]))
        px = np.clip(px, [0, 0], [cam.width - 1, cam.height - 1])
        keep = {k: v for k, v in z.items() if k in ("id", "kind", "speed_scale")}
        zones.append({**keep, "shape": "polygon", "camera": cam.camera_id,
                      "points_px": [[round(float(x), 1), round(float(y), 1)] for x, y in px]})
    cameras = [{"id": c["id"], "width": c["width"], "height": c["height"]}
               for c in data["cameras"]]
    return {**{k: v for k, v in data.items() if k != "floors"}, "cameras": cameras,
            "zones": zones}


def run_scenario(scenario: Scenario, detector, policy=None,
                 on_frame: Callable[[int], None] | None = None,
                 observe: Callable[[StepSeen], None] | None = None) -> ScenarioResult:
    """Render the scenario, run every frame through the real pipeline, score the commands.
    ``observe``: called after every step with what it saw (a diagnostic's look inside)."""
    cell = parse_cell(scenario.zone_data())
    policy = policy or PolicyConfig()
    cam = scenario.scene.camera
    references = {cam.camera_id: scenario.scene.reference()} if scenario.reference else None
    pipe = Pipeline(detector, cam.camera_id, policy, cell, references=references)
    radius = cell.spec.person.radius_m
    grace = policy.clear_time + RESET_PERIOD_S + 0.2
    scores: list[FrameScore] = []
    next_reset = RESET_PERIOD_S
    last_near = -math.inf  # last time a person was not clearly outside
    stop_since = None
    entry = first_stop = None
    last_inside = -math.inf
    refused_free = holds_empty = 0
    oldest = 0.0
    empty = scenario.scene.background() if scenario.missed else None
    last: CellFrameTruth | None = None
    for k, (img, truth) in enumerate(scenario.scene.frames()):
        t = truth.time_s
        if k in scenario.missed:
            img = empty
        reset = None
        if t + 1e-9 >= next_reset:
            reset = ResetRequest("eval", t, request_id=f"{scenario.name}-{k}")
            next_reset += RESET_PERIOD_S
        frame = FrameInfo(cam.camera_id, k, t, cam.width, cam.height)
        res = pipe.process(img, frame, t, reset=reset)
        inside = any(rect_distance(p.floor_m) < radius for p in truth.persons)
        if inside:
            last_inside = t
        outcome = res.command.reset
        # (a reset while nothing is latched is answered "nothing to reset": no refusal)
        free_refusal = bool(outcome is not None and not outcome.accepted
                            and res.command.latched and entry is not None
                            and t - last_inside > grace)
        refused_free += free_refusal
        holds = [h for hs in pipe.holds.values() for h in hs]
        holds_empty += bool(not truth.persons and holds)
        oldest = max([oldest, *(t - h.lost_since for h in holds)])
        clear = all(p.visible_fraction >= CLEAR_VIEW_FRACTION and p.full_box_px is not None
                    and _in_image(p.full_box_px, cam.width, cam.height)
                    and rect_distance(p.floor_m) > OUTSIDE_MARGIN_M for p in truth.persons)
        if not clear:
            last_near = t
        state = res.command.state
        if state == STOP and stop_since is None:
            stop_since = t
        elif state != STOP:
            stop_since = None
        if inside and entry is None:
            entry = t
            first_stop = stop_since
        outcome = res.command.reset
        scores.append(FrameScore(t, state, inside, clear and t - last_near >= grace
                                 and t >= grace,
                                 None if outcome is None else outcome.accepted))
        if on_frame is not None:
            on_frame(k)
        if observe is not None:
            observe(StepSeen(k, truth, pipe, res, free_refusal))
        last = truth
    end = () if last is None else judge_end_holds(
        pipe.cameras, hidden_persons(last, scenario.scene, scenario.missed))
    return ScenarioResult(
        scenario.name, len(scores), entry, first_stop,
        missed_stop_frames=sum(s.inside and s.state != STOP for s in scores),
        false_stop_frames=sum(s.clear_outside and s.state == STOP for s in scores)
        if scenario.check_false_stops else 0,
        resets_accepted_inside=sum(s.inside and s.reset_accepted is True for s in scores),
        resets_refused_inside=sum(s.inside and s.reset_accepted is False for s in scores),
        resets_accepted_outside=sum(not s.inside and s.reset_accepted is True for s in scores),
        needs=scenario.needs, scores=tuple(scores), resets_refused_free=refused_free,
        holds_when_empty=holds_empty, holds_at_end=sum(map(len, pipe.holds.values())),
        oldest_hold_s=oldest, holds_at_end_correct=sum(h.correct for h in end),
        holds_at_end_ghost=sum(not h.correct for h in end), end_holds=end)


def _in_image(box: tuple[int, int, int, int], width: int, height: int) -> bool:
    return box[0] > 0 and box[1] > 0 and box[2] < width and box[3] < height


def format_table(results: Iterable[ScenarioResult]) -> str:
    """One row per scenario, fixed-width columns."""
    head = ("scenario", "frames", "GT entry s", "first STOP s", "missed STOP", "false STOP",
            "resets in: acc/ref", "resets out acc", "refused free", "needs", "result")
    rows = [head]
    for r in results:
        rows.append((r.name, str(r.frames), _s(r.entry_s), _s(r.first_stop_s),
                     str(r.missed_stop_frames), str(r.false_stop_frames),
                     f"{r.resets_accepted_inside}/{r.resets_refused_inside}",
                     str(r.resets_accepted_outside), str(r.resets_refused_free),
                     ",".join(r.needs) or "-",
                     "ok" if r.ok else "FAIL"))
    widths = [max(len(row[i]) for row in rows) for i in range(len(head))]
    lines = ["  ".join(c.ljust(w) for c, w in zip(row, widths, strict=True)).rstrip()
             for row in rows]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(lines)


def _s(v: float | None) -> str:
    return "-" if v is None else f"{v:.1f}"
