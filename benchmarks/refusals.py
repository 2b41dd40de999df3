"""What refused each reset although the protective zone was free (issue 46's "let go when the
cell is seen empty"): the availability benchmark's scenes (``benchmarks/availability.py``)
through the real pipeline, and for every refused-free reset each STOP cause behind it.

Run: .venv/bin/python benchmarks/refusals.py [NAME ...]   (default: the busy scenes)

Per cause, one line:
* a seen person (``protective_zone``): their box, whether its feet may be cut off (the
  wall-foot line: ``cut_feet_rows``, how far down), and the ground-truth person under it;
* a lost person (``person_lost``): the lost track, when and where it was lost (its last box,
  the ground-truth person it was and whether the camera showed them), who was seen next near
  there and how that person was seen again (the same track, a new one, another old one: ids
  switched), and its area now: cells in all, hidden, under seen persons' feet, seen free but
  not yet for clear_time; the cells that hold the protective zone, by the same kinds (what
  would have to be seen to let go); and of the rules that end areas (seen free, bounded
  life, under seen persons, seen again) why none has yet.
A last table counts, per scene, the areas ended by each rule (all areas, and those that
held a zone), and the causes of the refusals by kind (a seen person, cut off or not; a lost
person's area, a place a merged track stood or not, by what its cells that hold the
protective zone are).
"""

from __future__ import annotations

import math
import sys
from collections import Counter, defaultdict
from dataclasses import dataclass, field

import numpy as np
from monitor.models import synthetic

from monitor.detector import Detector
from monitor.pipeline.locate import cut_feet_rows
from monitor.replay import scenarios as sc
from monitor.replay.scenario_run import StepSeen
from monitor.tracking.whereabouts import LostArea, shows_only_seen_persons


@dataclass
class _Life:
    """What the diagnostic remembers of one lost person's area."""

    track_id: int
    lost_since: float
    box: tuple[float, float, float, float]
    behind: bool
    held: bool = False  # touched a zone at some step


@dataclass
class Diagnosis:
    scene: str
    lines: list[str] = field(default_factory=list)
    causes: Counter = field(default_factory=Counter)
    ended: Counter = field(default_factory=Counter)  # rule -> areas (all)
    ended_held: Counter = field(default_factory=Counter)  # rule -> areas that held a zone


class Observer:
    """Watches a scenario step by step (``run_scenario(observe=...)``)."""

    def __init__(self, scenario: sc.Scenario) -> None:
        self.scenario = scenario
        self.d = Diagnosis(scenario.name)
        self.sightings: dict[int, list[tuple[float, tuple[float, ...]]]] = defaultdict(list)
        self.truths: dict[float, object] = {}
        self.lives: dict[int, _Life] = {}
        self._last: dict[int, LostArea] = {}  # the areas after the previous step
        # ground-truth person -> (time, track id) of every box nearest to them
        self.tracks_of: dict[int, list[tuple[float, int]]] = defaultdict(list)

    # -------------------------------------------------------------------------------------
    def __call__(self, step: StepSeen) -> None:
        res, pipe = step.result, step.pipeline
        t = res.now
        self.truths[round(t, 6)] = step.truth
        boxes = np.zeros((0, 4)) if res.persons is None else \
            np.asarray(res.persons.boxes_px, np.float64).reshape(-1, 4)
        for row, tid in enumerate(res.track_ids):
            self.sightings[tid].append((t, tuple(float(v) for v in boxes[row])))
            who = self._nearest(step.truth, boxes[row])
            if who is not None:
                self.tracks_of[who.person_id].append((t, tid))
        for cid, cam in pipe.cameras.items():
            if cam.tracker is None:
                continue
            self._areas(cam.tracker.where, set(res.track_ids))
            if step.refused_free:
                self._refusal(step, cid, cam, boxes)

    def _areas(self, where, seen: set[int]) -> None:
        """Areas begun and ended since the last step, with the rule that ended each."""
        live = where.areas
        merged = {m: a.track_id for a in live.values() for m in a.merged}
        for tid in [t for t in self.lives if t not in live]:
            life = self.lives.pop(tid)
            area = self._last.get(tid)
            rule = area.ended_by if area is not None and area.ended_by else \
                "joined" if tid in merged else "seen again" if tid in seen else "seen free"
            self.d.ended[rule] += 1
            if life.held:
                self.d.ended_held[rule] += 1
        for tid, area in live.items():
            life = self.lives.get(tid)
            if life is None or abs(life.lost_since - area.lost_since) > 1e-9:
                life = self.lives[tid] = _Life(tid, area.lost_since, area.box_px, area.behind)
            life.held |= bool(area.zones)
        self._last = dict(live)

    # -------------------------------------------------------------------------------------
    def _refusal(self, step: StepSeen, cid: str, cam, boxes: np.ndarray) -> None:
        res, pipe = step.result, step.pipeline
        t = res.now
        stops = [r for r in res.command.reasons
                 if r.code in ("protective_zone", "person_lost", "separation")]
        self.d.lines.append(f"{self.scenario.name} {t:5.1f} s: refused, {len(stops)} cause(s)")
        tracker = cam.tracker
        where = tracker.where
        foot = pipe.detector.foot_uncertainty_px(where.grid.width, where.grid.height)
        cut = cut_feet_rows(pipe.prepared, cid, boxes, foot)
        cut = np.full(len(boxes), np.nan) if cut is None else cut
        persons = step.result.person_ids
        for r in stops:
            if r.code == "person_lost":
                hold = next((h for h in pipe.holds.get(cid, ()) if h.who == r.person
                             or h.track_id == r.person), None)
                area = where.areas.get(hold.track_id) if hold is not None else None
                if area is None:
                    self.d.lines.append(f"    lost person {r.person}: (no area found)")
                    continue
                kind, text = self._lost(step, where, area, boxes, cut)
                self.d.causes[kind] += 1
                self.d.lines.append(f"    {text}")
            else:
                row = next((i for i, p in enumerate(persons) if p == r.person), None)
                if row is None:
                    self.d.causes["seen person"] += 1
                    self.d.lines.append(f"    seen person {r.person} in {r.zone_id}")
                    continue
                b = boxes[row]
                cutoff = math.isfinite(cut[row])
                kind = "seen person, cut off" if cutoff else "seen person"
                self.d.causes[kind] += 1
                who = self._truth_under(step.truth, b)
                self.d.lines.append(
                    f"    seen person {r.person} in {r.zone_id}: box {_box(b)}"
                    + (f", feet may be cut off down to row {cut[row]:.0f}" if cutoff else "")
                    + f"; truth: {who}")

    def _lost(self, step: StepSeen, where, area: LostArea, boxes: np.ndarray,
              cut: np.ndarray) -> tuple[str, str]:
        t = step.result.now
        grid = where.grid
        cells = area.cells
        hidden = cells & where.hidden
        uncut = boxes[~np.isfinite(cut)] if len(boxes) else boxes
        explains = grid.cells_under(uncut, 0.0)
        occupied = grid.cells_under(boxes, 0.0)
        if np.isfinite(cut).any():
            below = boxes[np.isfinite(cut)].copy()
            below[:, 1] = below[:, 3]
            below[:, 3] = np.maximum(below[:, 3], cut[np.isfinite(cut)])
            occupied |= grid.cells_under(below, 0.0, band=1.0)
        seen_free = ~where.hidden & ~occupied
        streak = cells & seen_free  # seen free now, not yet for clear_time
        under = cells & occupied & ~where.hidden
        life = where.life_s(area)
        n = int(cells.sum())
        truth = self.truths.get(round(area.lost_since, 6))
        was = self._truth_under(truth, np.array(area.box_px)) if truth is not None else "?"
        seen_next = self._seen_next(area)
        person = self._nearest(truth, np.array(area.box_px)) if truth is not None else None
        if person is not None:
            again = next(((ts, tid) for ts, tid in self.tracks_of[person.person_id]
                          if ts > area.lost_since + 1e-9), None)
            if again is None:
                seen_next += f"; person {person.person_id} not seen since"
            else:
                ts, tid = again
                first = self.sightings[tid][0][0]
                how = "the same track" if tid == area.track_id else \
                    "a new track" if first > area.lost_since + 1e-9 else "another old track"
                seen_next += (f"; person {person.person_id} seen again at {ts:.1f} s as "
                              f"track {tid} ({how})")
        why = []
        if hidden.any():
            why.append(f"seen free/bounded life/under seen persons: never ({int(hidden.sum())}"
                       " hidden cells)")
        else:
            left = life - area.age_s
            why.append(f"bounded life in {left:.1f} s" if left > 0 else "bounded life: due")
            if under.any():
                why.append(f"seen free: {int(under.sum())} cells under seen persons' feet"
                           + (", of them under cut-off boxes"
                              if (under & ~explains).any() else ""))
            if streak.any():
                why.append(f"seen free: {int(streak.sum())} cells seen free < clear_time")
            only = shows_only_seen_persons(cells, where.hidden, explains, seen_free)
            why.append("under seen persons: counting since "
                       f"{area.explained:.1f} s" if area.explained is not None else
                       "under seen persons: " + ("all shown as seen persons now"
                                                 if only else "partly seen empty, partly "
                                                 "under a person" if under.any() and
                                                 streak.any() else "no"))
        who = f"track {area.track_id}" + (f" (+{','.join(map(str, area.merged))})"
                                          if area.merged else "")
        prot = where.zone_cells(area, ("protective",))
        fs = where.free_since
        holding = (f"{int(prot.sum())} cells hold the protective zone: "
                   f"{int((prot & where.hidden).sum())} hidden, "
                   f"{int((prot & explains & ~where.hidden).sum())} under seen persons' feet, "
                   f"{int((prot & occupied & ~explains & ~where.hidden).sum())} under a "
                   f"cut-off box's range, {int((prot & ~np.isnan(fs)).sum())} seen free for "
                   f"< clear_time")
        # what holds the protective zone: what would have to be seen to let go
        kinds = [name for name, cells in (
            ("hidden", prot & where.hidden), ("under feet", prot & explains & ~where.hidden),
            ("cut-off range", prot & occupied & ~explains & ~where.hidden),
            ("seen free < clear_time", prot & ~np.isnan(fs))) if cells.any()]
        kind = ("behind: " if area.behind else "lost: ") + (" + ".join(kinds) or "-")
        text = (f"lost {who}, lost at {area.lost_since:.1f} s ({t - area.lost_since:.1f} s "
                f"ago; {'behind, ' if area.behind else ''}age {area.age_s:.1f} of life "
                f"{life:.1f} s) box {_box(area.box_px)}; was {was}; next near there: "
                f"{seen_next}; area {n} cells: {int(hidden.sum())} hidden, "
                f"{int(under.sum())} under feet, {int(streak.sum())} seen free now; "
                f"zones {','.join(z.zone_id for z in area.zones)} ({holding}); not ended: "
                + "; ".join(why))
        return kind, text

    def _seen_next(self, area: LostArea) -> str:
        """The first sighting after the loss whose box's feet lie near the lost box's."""
        x1, y1, x2, y2 = area.box_px
        h = max(y2 - y1, 1.0)
        best = None
        for tid, seen in self.sightings.items():
            for ts, b in seen:
                if ts <= area.lost_since + 1e-9:
                    continue
                d = math.hypot((b[0] + b[2] - x1 - x2) / 2, b[3] - y2)
                if d <= h and (best is None or ts < best[0]):
                    best = (ts, tid, d)
        if best is None:
            return "nobody"
        ts, tid, d = best
        same = "the same id" if tid == area.track_id else "a new id" \
            if self.sightings[tid][0][0] > area.lost_since else "another track"
        return f"track {tid} at {ts:.1f} s ({d:.0f} px off, {same})"

    @staticmethod
    def _nearest(truth, box: np.ndarray):
        """The ground-truth person whose whole figure's feet are nearest the box's."""
        if truth is None:
            return None
        bx, by = (box[0] + box[2]) / 2, box[3]
        return min((p for p in truth.persons if p.full_box_px is not None),
                   key=lambda p: math.hypot((p.full_box_px[0] + p.full_box_px[2]) / 2 - bx,
                                            p.full_box_px[3] - by), default=None)

    def _truth_under(self, truth, box: np.ndarray) -> str:
        """The ground-truth person whose whole figure's feet are nearest the box's, and
        whether the camera showed them."""
        if truth is None or not truth.persons:
            return "nobody in the scene"
        bx, by = (box[0] + box[2]) / 2, box[3]
        best = self._nearest(truth, box)
        if best is None:
            return "?"
        walker = self.scenario.scene.walkers[best.person_id]
        missed = truth.index in walker.unseen_frames or truth.index in self.scenario.missed
        fb = best.full_box_px
        d = math.hypot((fb[0] + fb[2]) / 2 - bx, fb[3] - by)
        state = "missed by the detector" if missed else \
            f"{best.visible_fraction:.0%} in view"
        return (f"person {best.person_id} at ({best.floor_m[0]:.1f}, {best.floor_m[1]:.1f}) m,"
                f" feet {d:.0f} px off, {state}, "
                f"{sc.rect_distance(best.floor_m):.1f} m from the protective zone")


def _box(b) -> str:
    return "(" + ", ".join(f"{float(v):.0f}" for v in b) + ")"


def main(names: list[str]) -> int:
    detector = Detector(synthetic.ensure_model())
    pool = [*sc.evidence_scenarios(), *sc.busy_scenarios()]
    chosen = [s for s in pool if s.name in names] if names else sc.busy_scenarios()
    unknown = set(names) - {s.name for s in pool}
    if unknown:
        print(f"unknown scene {', '.join(sorted(unknown))} (known: "
              f"{', '.join(s.name for s in pool)})")
        return 2
    diagnoses = []
    for scenario in chosen:
        obs = Observer(scenario)
        r = sc.run_scenario(scenario, detector, observe=obs)
        diagnoses.append((obs.d, r))
        for line in obs.d.lines:
            print(line)
    print()
    rules = sorted({k for d, _ in diagnoses for k in (*d.ended, *d.ended_held)})
    kinds = sorted({k for d, _ in diagnoses for k in d.causes})
    print("areas ended by rule (all / held a zone):")
    for d, _ in diagnoses:
        print(f"  {d.scene}: " + ", ".join(f"{k} {d.ended[k]}/{d.ended_held[k]}"
                                           for k in rules))
    print("refusal causes:")
    for d, r in diagnoses:
        print(f"  {d.scene} ({r.resets_refused_free} refused free): "
              + ", ".join(f"{k} {d.causes[k]}" for k in kinds if d.causes[k]))
    return 0


if __name__ == "__main__":
    if {"-h", "--help"} & set(sys.argv[1:]):
        print(__doc__)
        sys.exit(0)
    sys.exit(main(sys.argv[1:]))
