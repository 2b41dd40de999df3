"""Makes the pictures of docs/occlusion.md that show objects put into the cell since
commissioning, from the real code: the scenario suite's scenes, the object check of
``monitor/health/objects.py``, the acceptance of ``monitor/health/acceptance.py`` (through the
signed request's gate) and the pipeline with the synthetic model.

    python docs/occlusion/pictures.py            # writes the PNGs beside this file

(cut-off-feet.png and crouch-hidden.png come from `monitor zones preview` and the hidden-feet
scenes; this script makes object-since-commissioning.png and floor-coloured-object.png.)
"""

from __future__ import annotations

import dataclasses
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey
from monitor.models import synthetic

from monitor.detector import Detector, DetectorConfig
from monitor.health.objects import objects_of
from monitor.pipeline import Pipeline
from monitor.policy import PolicyConfig, ResetRequest
from monitor.replay import scenarios as sc
from monitor.scene.cell import CellScene
from monitor.types import FrameInfo
from monitor.wire.object_accepts import AcceptGate, accept_payload
from monitor.wire.signing import Signer
from monitor.zones import draw_zones, parse_cell

HERE = Path(__file__).resolve().parent
FPS = 5.0
KEY = "workcell/cell1/safety/objects/accept"
RED, ORANGE, WHITE = (40, 40, 220), (0, 140, 255), (255, 255, 255)


def _caption(img: np.ndarray, lines: list[str], colour=(30, 30, 30)) -> np.ndarray:
    band = np.full((22 * len(lines) + 8, img.shape[1], 3), 245, np.uint8)
    for k, text in enumerate(lines):
        cv2.putText(band, text, (8, 20 + 22 * k), cv2.FONT_HERSHEY_SIMPLEX, 0.5, colour, 1,
                    cv2.LINE_AA)
    return np.vstack([img, band])


def _shadow(img: np.ndarray, watch, step: int = 8) -> None:
    """Hatch the foot positions the camera counts as hidden behind the objects."""
    h, w = img.shape[:2]
    ys, xs = np.mgrid[step // 2:h:step, step // 2:w:step]
    pts = np.c_[xs.ravel(), ys.ravel()].astype(float)
    for x, y in pts[watch.hidden_cells(pts)]:
        cv2.line(img, (int(x) - 3, int(y) + 3), (int(x) + 3, int(y) - 3), ORANGE, 1)


def _boxes(img: np.ndarray, watch, colour) -> None:
    for o in watch.objects.values():
        x1, y1, x2, y2 = o.box_px
        cv2.rectangle(img, (x1 - 2, y1 - 2), (x2 + 2, y2 + 2), colour, 2)


def object_since_commissioning(detector: Detector) -> np.ndarray:
    """Reference | the crate holds the cell | accepted: its shadow stays held."""
    scenario = sc.select(["crate-after-reference"], FPS)[0]
    cell = parse_cell(scenario.zone_data())
    ref = scenario.scene.reference()
    pipe = Pipeline(detector, "cam0", PolicyConfig(), cell, references={"cam0": ref})
    anna = Signer(Ed25519PrivateKey.generate())
    gate = AcceptGate({"anna": anna.key.public_key()}, "cell1", KEY)
    shots = {}
    for k, (img, truth) in enumerate(scenario.scene.frames()):
        t = truth.time_s
        if abs(t - 9.0) < 1e-6:  # anna looked at the crate: her signed acceptance
            payload = accept_payload("anna", "cam0", "robot-protective", cell="cell1",
                                     boot="b1")
            pipe.accept_objects([gate.check(payload, anna.sign(KEY, payload), t, boot="b1")],
                                t)
        res = pipe.process(img, FrameInfo("cam0", k, t, 640, 360), t,
                           reset=ResetRequest("eval", t, request_id=f"r{k}"))
        if abs(t - 8.0) < 1e-6 or abs(t - 11.0) < 1e-6:
            watch = pipe.objects["cam0"]
            shot = draw_zones(img, cell, "cam0")
            _shadow(shot, watch)
            accepted = any(o.accepted_by for o in watch.objects.values())
            _boxes(shot, watch, ORANGE if accepted else RED)
            faults = sorted({f.name for f in res.faults})
            shots[t] = (shot, res.command.state, faults, res.command.reset)
    first = _caption(draw_zones(ref, cell, "cam0"), [
        "1. the commissioning reference", "(the empty cell, fixtures included)"])
    shot, state, faults, _ = shots[8.0]
    second = _caption(shot, [
        f"2. a crate put in since (red): {state}, fault {', '.join(faults) or 'none'}",
        "a person crouches behind it; every reset refused until accepted"])
    shot, state, faults, reset = shots[11.0]
    third = _caption(shot, [
        f"3. accepted by anna (orange): {state}, fault {', '.join(faults) or 'none'}",
        "its shadow (hatched) stays held: the person lost there is"
        + (" held" if reset is not None and not reset.accepted else "")])
    return np.hstack([first, second, third])


def floor_coloured_object() -> np.ndarray:
    """The object check on a blue crate and on one the colour of the floor."""
    base = sc.select(["crate-after-reference"], FPS)[0]
    cell = parse_cell(base.zone_data())
    crate = base.scene.blocks[0]
    panels = []
    for name, colour in (("a blue crate", crate.colour), ("a crate the colour of the floor",
                                                          None)):
        scene = CellScene((), (crate,), fps=FPS, duration_s=4.0)
        ref = scene.reference()
        if colour is None:  # the floor's own grey where the crate stands
            x1, y1, x2, y2 = _crate_box(scene, crate)
            grey = ref[y2 - 4:y2, x1:x2].reshape(-1, 3).mean(axis=0)
            crate_here = dataclasses.replace(crate, colour=tuple(int(v) for v in grey))
            scene = CellScene((), (crate_here,), fps=FPS, duration_s=4.0)
        watch = objects_of(cell, {"cam0": ref})["cam0"]
        last = None
        for img, truth in scene.frames():
            watch.check(img, [], truth.time_s)
            last = img
        shot = draw_zones(last, cell, "cam0")
        _boxes(shot, watch, RED)
        _shadow(shot, watch)
        found = list(watch.objects.values())
        x1, y1, x2, y2 = _crate_box(scene, crate)
        whole = bool(found) and found[0].box_px[3] - found[0].box_px[1] >= 0.5 * (y2 - y1)
        where = found[0].place().split(" (")[0] if found else ""
        if whole:
            lines = [f"{name}: found, in {where}", "its shadow hatched: held"]
        elif found:
            lines = [f"{name}: only its top found (against the floor behind it),",
                     f"placed in {where}: the floor behind its body counts as seen"]
        else:
            lines = [f"{name}: NOT found (no change against the reference)",
                     "the floor behind it counts as seen"]
        panels.append(_caption(shot, lines))
    return np.hstack(panels)


def _crate_box(scene: CellScene, crate) -> tuple[int, int, int, int]:
    corners = np.array([[x, y, z] for x in (crate.min_m[0], crate.max_m[0])
                        for y in (crate.min_m[1], crate.max_m[1])
                        for z in (crate.min_m[2], crate.max_m[2])], float)
    px = scene.camera.project(corners)
    return (int(px[:, 0].min()), int(px[:, 1].min()), int(px[:, 0].max()),
            int(px[:, 1].max()))


def _write(name: str, img: np.ndarray) -> Path:
    """Two thirds of the panels' size, 6 bits per colour, the strongest PNG compression:
    the sensor noise of the scenes makes full-size PNGs heavy in the wheel."""
    small = cv2.resize(img, (img.shape[1] * 2 // 3, img.shape[0] * 2 // 3),
                       interpolation=cv2.INTER_AREA)
    path = HERE / name
    cv2.imwrite(str(path), (small // 4) * 4, [cv2.IMWRITE_PNG_COMPRESSION, 9])
    return path


def main() -> int:
    with tempfile.TemporaryDirectory() as tmp:
        model = Path(tmp) / "synthetic.onnx"
        synthetic.write_model(model)
        detector = Detector(model, DetectorConfig(threads=1))
        first = _write("object-since-commissioning.png", object_since_commissioning(detector))
    second = _write("floor-coloured-object.png", floor_coloured_object())
    print(f"wrote {first}, {second}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
