"""Which backend and precision runs the model: chosen by measurement, gated by agreement.

``[detector] backend = "auto"`` (the default): at start every backend and precision this host
has (``runners.available``) is opened and checked against the reference, onnxruntime on the CPU
at the model's own precision, on the *agreement figures*: the self-test image in the envelope's
four shifted copies and its degraded copies at every grade of the envelope's axes (light,
contrast, noise, blur: where a less precise backend loses a person first). Persons are matched
one to one at IoU >= 0.5 and counted as ``monitor model quantize`` counts them (found by both /
by either >= ``detector.backend_min_agreement``, 0.98); a backend below that is refused, naming
the figures. Each agreeing one is then timed against the reference, interleaved (load that
comes and goes hits all alike), on a frame of the cameras' size, and the fastest runs, if it
is at least ``MARGIN`` faster than the reference (the noise of a busy host never makes ``auto``
slower than onnxruntime).

``monitor model check-backend --frames VIDEO`` checks the same on the user's own frames and
records the result: a backend that disagrees there is never chosen, and a model without a
self-test image (no figures to check on) runs a backend other than the reference only after it
passed there.

Bounded: the measurement stops after ``detector.backend_budget_s`` (the backends not reached are
measured at the next start), and its result is cached beside the model
(``MODEL.onnx.backends.json``) under the model's sha256, the host's CPU and flags, the runtimes'
versions and the detector settings: a later start opens the chosen backend at once.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import os
import platform
import statistics
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from monitor.detector import Detector, DetectorConfig
from monitor.detector.envelope import GRADES, TRIALS, case_digest, degrade, file_sha256
from monitor.detector.quantize import Agreement, compare, detect_all
from monitor.detector.runners import (
    REFERENCE,
    BackendUnavailable,
    Candidate,
    ModelFacts,
    available,
    model_facts,
    open_runner,
    runtime_versions,
)
from monitor.detector.selftest import SelfTestCase
from monitor.errors import ConfigError, MonitorError

log = logging.getLogger(__name__)

FORMAT = 2  # 2: trials carry the side-by-side time ratio
MARGIN = 0.9  # another backend runs only at <= 0.9 of the reference's measured time
TIMED_ROUNDS = 5
_PARAM = {"gain_low": "gain", "gain_high": "gain", "contrast": "contrast", "noise": "noise",
          "blur": "blur", "glare": "glare"}
# the CPU flags that change which kernels a runtime picks (and so its speed and rounding)
_FLAG_PREFIXES = ("avx", "amx", "fma", "f16c", "sse4", "vnni")
# settings that only change how the choice is made or how fast, not what the model computes
_NOT_IN_KEY = {"backend", "precision", "backend_budget_s", "self_test_period_s", "spin_wait",
               "batch_cameras"}


class BackendRefused(ConfigError):
    """A named backend disagrees with the reference (or cannot be checked): not started."""


@dataclass(frozen=True)
class Trial:
    """One backend and precision against the reference: its median inference time, its
    agreement on ``where`` (None: not compared) and why it is not used (None: it may be)."""

    candidate: Candidate
    ms: float | None = None
    reference_ms: float | None = None
    agreement: Agreement | None = None
    where: str = ""
    refused: str | None = None
    # its time over the reference's: the median over rounds of the two run side by side (the
    # same load on both), None: ms / reference_ms
    ratio: float | None = None

    @property
    def speed_ratio(self) -> float:
        if self.ratio is not None:
            return self.ratio
        return self.ms / self.reference_ms if self.ms and self.reference_ms else 9.0

    def to_dict(self) -> dict:
        out: dict = {"backend": self.candidate.backend, "precision": self.candidate.precision}
        if self.ms is not None:
            out["ms"] = round(self.ms, 2)
        if self.reference_ms is not None:
            out["reference_ms"] = round(self.reference_ms, 2)
        if self.ratio is not None:
            out["ratio"] = round(self.ratio, 3)
        if self.agreement is not None:
            out["agreement"] = _agreement_dict(self.agreement)
            out["where"] = self.where
        if self.refused:
            out["refused"] = self.refused
        return out

    @classmethod
    def from_dict(cls, data: dict) -> Trial:
        agreement = data.get("agreement")
        return cls(Candidate(data["backend"], data["precision"]), data.get("ms"),
                   data.get("reference_ms"),
                   Agreement(**agreement) if agreement is not None else None,
                   data.get("where", ""), data.get("refused"), data.get("ratio"))


@dataclass(frozen=True)
class Choice:
    """The backend that runs, every trial behind it, and whether it came from the cache."""

    chosen: Candidate
    trials: tuple[Trial, ...]
    reason: str
    cached: bool = False
    host: str = ""
    reference: Candidate | None = None  # onnxruntime at the model's own precision

    @property
    def agreement(self) -> Agreement | None:
        trial = next((t for t in self.trials if t.candidate == self.chosen), None)
        return trial.agreement if trial is not None else None

    def line(self) -> str:
        """The start-up line: what runs, how it agrees, what else was measured."""
        agreement = self.agreement
        agrees = (f"agreement {agreement.agreement:.3f} with {REFERENCE} on "
                  f"{agreement.frames} {self._where()}" if agreement is not None
                  else "the reference")
        others = "; ".join(_trial_text(t) for t in self.trials if t.candidate != self.chosen)
        return (f"detector backend {self.chosen.label} ({agrees}; {self.reason}"
                f"{', cached' if self.cached else ''})" + (f"; also {others}" if others else ""))

    def _where(self) -> str:
        trial = next((t for t in self.trials if t.candidate == self.chosen), None)
        return trial.where if trial is not None else ""

    def to_dict(self) -> dict:
        agreement = self.agreement
        return {"backend": self.chosen.backend, "precision": self.chosen.precision,
                "agreement": round(agreement.agreement, 4) if agreement is not None else 1.0,
                "reason": self.reason, "cached": self.cached, "host": self.host,
                "trials": [t.to_dict() for t in self.trials]}


def _trial_text(trial: Trial) -> str:
    if trial.refused:
        return f"{trial.candidate.label} refused ({trial.refused})"
    ms = f"{trial.ms:.1f} ms" if trial.ms is not None else "not timed"
    return f"{trial.candidate.label} {ms}"


def _agreement_dict(a: Agreement) -> dict:
    return {k: (round(v, 4) if isinstance(v, float) else v)
            for k, v in dataclasses.asdict(a).items()}


def refusal(agreement: Agreement, min_agreement: float, label: str, where: str) -> str | None:
    """Why ``label`` must not run, naming the figures, or None (the criteria of
    ``monitor.detector.quantize.check_agreement``)."""
    if agreement.fp32_persons == 0:
        return (f"{REFERENCE} finds no person in the {agreement.frames} {where}, so "
                f"{label} cannot be checked")
    if agreement.agreement < min_agreement:
        return (f"{label} agrees with {REFERENCE} on {agreement.agreement:.3f} of the persons "
                f"(below {min_agreement:g}): {agreement.fp32_only} missed, "
                f"{agreement.int8_only} extra, of {agreement.fp32_persons} on "
                f"{agreement.frames} {where}")
    return None


# ----------------------------------------------------------------------------- figures


def agreement_figures(case: SelfTestCase, input_size: tuple[int, int],
                      stride_px: float) -> list[np.ndarray]:
    """The self-test image at the detector's input scale in the envelope's ``TRIALS``
    shifted copies, and degraded at every grade of every envelope axis (one shift each, in
    turn): the images a less precise backend would answer differently first."""
    h, w = case.image.shape[:2]
    scale = min(input_size[0] / w, input_size[1] / h)
    image = cv2.resize(case.image, (max(1, round(w * scale)), max(1, round(h * scale))),
                       interpolation=cv2.INTER_AREA)
    shifts = ((0.0, 0.0), (0.5, 0.0), (0.0, 0.5), (0.25, 0.75))[:TRIALS]

    def shifted(k: int) -> np.ndarray:
        fx, fy = shifts[k % len(shifts)]
        m = np.float32([[1, 0, fx * stride_px], [0, 1, fy * stride_px]])
        return cv2.warpAffine(image, m, (image.shape[1], image.shape[0]),
                              flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)

    def box(k: int) -> np.ndarray:
        """The figure's box in ``shifted(k)``: where a glare band is laid."""
        fx, fy = shifts[k % len(shifts)]
        x1, y1, x2, y2 = (v * scale for v in case.box_px)
        dx, dy = fx * stride_px, fy * stride_px
        return np.array((x1 + dx, y1 + dy, x2 + dx, y2 + dy))

    figures = [shifted(k) for k in range(len(shifts))]
    k = 0
    for n, (axis, steps) in enumerate(GRADES.items()):
        for g, grade in enumerate(steps[1:], start=1):
            rng = np.random.default_rng(n * 1000 + g)
            figures.append(degrade(shifted(k), rng=rng, glare_box=box(k),
                                   **{_PARAM[axis]: grade}))
            k += 1
    return figures


# ----------------------------------------------------------------------------- the cache


def host_key() -> dict:
    """The host's CPU and the flags that change a runtime's kernels."""
    name, flags = platform.processor() or platform.machine(), set()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            key, _, value = line.partition(":")
            if key.strip() == "model name" and name in ("", platform.machine()):
                name = value.strip()
            elif key.strip() == "flags" and not flags:
                flags = set(value.split())
    except OSError:
        pass
    return {"cpu": name, "cores": os.cpu_count() or 0,
            "flags": sorted(f for f in flags if f.startswith(_FLAG_PREFIXES)
                            or f.endswith("vnni"))}


def host_text(host: dict) -> str:
    """"AMD EPYC 9B14, 2 cores, avx512_bf16 + avx512_vnni, no AMX"."""
    flags = set(host.get("flags", ()))
    has = [f for f in ("avx512_bf16", "avx512_vnni", "avx_vnni") if f in flags]
    amx = "AMX" if any(f.startswith("amx") for f in flags) else "no AMX"
    return f"{host.get('cpu', '?')}, {host.get('cores', '?')} cores, " \
           f"{' + '.join(has) or 'no VNNI/BF16'}, {amx}"


def cache_path(model_path: str | Path) -> Path:
    model_path = Path(model_path)
    return model_path.with_name(model_path.name + ".backends.json")


def cache_key(model_sha256: str, config: DetectorConfig, case: SelfTestCase | None,
              host: dict) -> str:
    """What a measurement holds for: the model, the host, the runtimes, the settings that
    change what the model computes and how fast (the threads: only for speed, see
    ``_frames_key``)."""
    settings = {k: v for k, v in dataclasses.asdict(config).items() if k not in _NOT_IN_KEY}
    data = {"model": model_sha256, "host": host, "runtimes": runtime_versions(),
            "settings": settings, "case": case_digest(case) if case is not None else None}
    return hashlib.sha256(json.dumps(data, sort_keys=True, default=str).encode()).hexdigest()


def frames_key(model_sha256: str, config: DetectorConfig, case: SelfTestCase | None,
               host: dict) -> str:
    """The key of a check on the user's frames: agreement does not depend on the threads."""
    return cache_key(model_sha256, dataclasses.replace(config, threads=1), case, host)


def read_cache(model_path: Path, key: str, part: str) -> dict[str, Trial]:
    """The trials (``part``: "trials" or "frames") stored under ``key``, by label."""
    try:
        data = json.loads(cache_path(model_path).read_text())
        if data.get("format") != FORMAT:
            return {}
        entry = data.get("entries", {}).get(key, {})
        return {label: Trial.from_dict(t) for label, t in entry.get(part, {}).items()}
    except (OSError, ValueError, TypeError, KeyError, AttributeError):
        return {}  # absent, unreadable or of another version: measured anew


def write_cache(model_path: Path, key: str, part: str, trials: Sequence[Trial]) -> None:
    """Store ``trials`` under ``key`` (atomically; a read-only model directory only logs)."""
    path = cache_path(model_path)
    try:
        data = json.loads(path.read_text()) if path.is_file() else {}
        if data.get("format") != FORMAT:
            data = {}
    except (OSError, ValueError):
        data = {}
    entries = data.setdefault("entries", {})
    entry = entries.setdefault(key, {})
    stored = entry.setdefault(part, {})
    for trial in trials:
        stored[trial.candidate.label] = trial.to_dict()
    while len(entries) > 8:  # the oldest hosts and settings go first
        entries.pop(next(iter(entries)))
    data["format"] = FORMAT
    tmp = path.with_name(path.name + ".tmp")
    try:
        tmp.write_text(json.dumps(data, indent=1) + "\n")
        os.replace(tmp, path)
    except OSError as exc:
        log.warning("%s: backend measurement not stored (%s); measured again at the next "
                    "start", path, exc)


# ----------------------------------------------------------------------------- measuring


def candidates_for(model_path: Path, config: DetectorConfig, facts: ModelFacts,
                   ) -> list[Candidate]:
    """What the config lets run on this host, the reference first (every other one is
    checked against it). BackendUnavailable when a named backend or precision is not here."""
    found = available(facts)
    if config.backend != "auto":
        of_backend = [c for c in found if c.backend == config.backend]
        if not of_backend:
            # opening it says exactly what is missing (package, provider or device)
            open_runner(model_path, Candidate(config.backend, config.precision), 1,
                        facts=facts)
            raise BackendUnavailable(f"backend {config.backend!r} is not available here")
        found = [c for c in found if c.backend == REFERENCE] + of_backend
    if config.precision != "auto":
        wanted = [c for c in found if c.precision == config.precision]
        if not wanted:
            have = ", ".join(c.label for c in found)
            raise BackendUnavailable(f"precision {config.precision!r} is not available for "
                                     f"this model here (available: {have})")
        found = [found[0]] + [c for c in wanted if c != found[0]]
    return found


def _open(model_path: Path, config: DetectorConfig, candidate: Candidate,
          facts: ModelFacts) -> Detector:
    runner = open_runner(model_path, candidate, config.threads, config.spin_wait, facts)
    return Detector(model_path, config, runner=runner)


def timed(detectors: Sequence[Detector], frame: np.ndarray, rounds: int = TIMED_ROUNDS,
          ) -> tuple[list[float], list[float]]:
    """Median inference ms of each detector on ``frame``, and each one's time over the
    first one's: rounds of a block per detector (one run that brings its weights back into
    the caches, then two timed, the quicker counting: load only ever makes a run slower), and
    the ratio of two blocks run side by side taken per round, its median over the rounds (load
    that comes and goes hits both alike)."""
    times: list[list[float]] = [[] for _ in detectors]
    ratios: list[list[float]] = [[] for _ in detectors]
    for _ in range(rounds):
        best = []
        for k, det in enumerate(detectors):
            det.detect(frame)
            runs = [det.detect_timed(frame).inference_ms for _ in range(2)]
            times[k] += runs
            best.append(min(runs))
        for k in range(len(detectors)):
            ratios[k].append(best[k] / best[0] if best[0] > 0 else 9.0)
    return [statistics.median(t) for t in times], [statistics.median(r) for r in ratios]


def measure(model_path: Path, config: DetectorConfig, candidates: Sequence[Candidate],
            reference: Detector, frame: np.ndarray, facts: ModelFacts,
            budget_s: float, clock: Callable[[], float] = time.monotonic,
            ) -> tuple[list[Trial], dict[Candidate, Detector]]:
    """A trial of every candidate but the reference: opened, compared on the agreement
    figures, timed against the reference. The detectors that agreed, for reuse."""
    deadline = clock() + budget_s
    case = reference.self_test_case
    figures = (agreement_figures(case, (reference.layout.input_width,
                                        reference.layout.input_height),
                                 reference.finest_stride_px()) if case is not None else [])
    where = "self-test and envelope figures"
    # the reference's persons once, compared with every candidate's
    expected = detect_all(reference, figures) if figures else []
    trials: list[Trial] = []
    opened: dict[Candidate, Detector] = {}
    # the reduced precisions first: they are the likely gain, and the budget cuts the rest
    for cand in sorted(candidates, key=lambda c: c.precision in ("fp32", "int8")):
        if cand == reference.backend:
            continue
        if clock() > deadline:
            trials.append(Trial(cand, refused=f"not measured within detector.backend_budget_s "
                                              f"{budget_s:g} s"))
            continue
        try:
            det = _open(model_path, config, cand, facts)
        except MonitorError as exc:
            trials.append(Trial(cand, refused=str(exc)))
            continue
        except Exception as exc:  # a runtime's own error on this model: not usable
            trials.append(Trial(cand, refused=f"failed: {str(exc).splitlines()[0][:160]}"))
            continue
        agreement, why = None, None
        if figures:
            try:
                agreement = compare(expected, det, figures)
                why = refusal(agreement, config.backend_min_agreement, cand.label, where)
            except Exception as exc:  # the detector failing (NaN, shapes) is disagreement
                why = f"failed on the figures: {str(exc).splitlines()[0][:160]}"
        if why is not None:
            trials.append(Trial(cand, agreement=agreement, where=where, refused=why))
            continue
        (ref_ms, ms), (_, ratio) = timed([reference, det], frame)
        trials.append(Trial(cand, ms, ref_ms, agreement, where if agreement else "",
                            ratio=ratio))
        opened[cand] = det
    return trials, opened


def decide(reference: Candidate, trials: Sequence[Trial], frames: dict[str, Trial],
           config: DetectorConfig, has_case: bool) -> tuple[Candidate, str]:
    """The candidate to run and why. Pure. A trial is eligible when it agreed on the figures
    (or, without a self-test image, on the user's frames) and no frames check refused it; the
    fastest eligible one runs when it beats the reference by ``MARGIN``. A named backend
    that is not eligible is refused (``BackendRefused``, naming the figures)."""
    eligible: list[Trial] = []
    for trial in trials:
        checked = frames.get(trial.candidate.label)
        if trial.refused or (checked is not None and checked.refused):
            continue
        if trial.agreement is None and (checked is None or has_case):
            continue  # never compared: not run
        if trial.ms is None:
            continue
        eligible.append(trial)
    named = config.backend != "auto" and not (config.backend == REFERENCE
                                               and config.precision in ("auto",
                                                                        reference.precision))
    if named:
        wanted = [t for t in trials if t.candidate.backend == config.backend
                  and config.precision in ("auto", t.candidate.precision)]
        ok = [t for t in eligible if t in wanted]
        if not ok:
            reasons = []
            for t in wanted:
                checked = frames.get(t.candidate.label)
                why = t.refused or (checked.refused if checked is not None else None) or (
                    "no self-test image to check it on (set detector.self_test_image and "
                    "self_test_box, or run 'monitor model check-backend --frames')")
                reasons.append(f"{t.candidate.label}: {why}")
            raise BackendRefused(f"[detector] backend {config.backend!r}"
                                 f"{'' if config.precision == 'auto' else ' ' + config.precision}"
                                 f" refused: {'; '.join(reasons) or 'not measured'}")
        best = min(ok, key=lambda t: t.speed_ratio)
        return best.candidate, "named in [detector], agrees"
    if not eligible:
        why = "nothing else agreed" if has_case or frames else \
            "no self-test image to check other backends on"
        return reference, f"{why}"
    best = min(eligible, key=lambda t: t.speed_ratio)
    ratio = best.speed_ratio
    if ratio > MARGIN:
        return reference, (f"fastest other: {best.candidate.label} at {ratio:.2f} of its "
                           f"time, not below {MARGIN:g}")
    return best.candidate, f"{1 / ratio:.2f}x faster than {REFERENCE} here"


def open_detector(model_path: str | Path, config: DetectorConfig | None = None,
                  frame_size: tuple[int, int] = (1920, 1080),
                  progress: Callable[[str], None] | None = None,
                  ) -> tuple[Detector, Choice]:
    """The detector on the backend the config asks for, chosen by measurement (cached), and
    the choice. ``BackendUnavailable`` / ``BackendRefused`` (one line) for a named backend
    this host lacks or that disagrees."""
    config = config or DetectorConfig()
    model_path = Path(model_path)
    reference = Detector(model_path, dataclasses.replace(config, backend=REFERENCE,
                                                         precision="auto"))
    facts = model_facts(model_path)
    cands = candidates_for(model_path, config, facts)
    host = host_key()
    if len(cands) == 1:  # nothing but the reference here: nothing to measure
        return reference, Choice(reference.backend, (), "the only backend here",
                                 host=host_text(host), reference=reference.backend)
    sha = file_sha256(model_path)
    key = cache_key(sha, config, reference.self_test_case, host)
    trials = {t.candidate: t for t in read_cache(model_path, key, "trials").values()}
    frames = read_cache(model_path, frames_key(sha, config, reference.self_test_case, host),
                        "frames")
    missing = [c for c in cands if c != reference.backend and (
        c not in trials or (trials[c].refused or "").startswith("not measured"))]
    if reference.self_test_case is None:  # no figures: only those your frames checked
        missing = [c for c in missing if c.label in frames and not frames[c.label].refused]
    opened: dict[Candidate, Detector] = {}
    if missing:
        if progress is not None:
            progress(f"measuring {', '.join(c.label for c in missing)} against {REFERENCE}")
        frame = np.full((frame_size[1], frame_size[0], 3), 114, np.uint8)
        frame[::7, ::5] = 90
        new, opened = measure(model_path, config, missing, reference, frame, facts,
                              config.backend_budget_s)
        write_cache(model_path, key, "trials", new)
        trials.update({t.candidate: t for t in new})
    # every candidate has a trial: one not measured (no self-test image) is never chosen
    ordered = tuple(trials.get(c, Trial(c)) for c in cands if c != reference.backend)
    chosen, reason = decide(reference.backend, ordered, frames, config,
                            reference.self_test_case is not None)
    choice = Choice(chosen, ordered, reason, cached=not missing, host=host_text(host),
                    reference=reference.backend)
    if chosen == reference.backend:
        return reference, choice
    try:
        detector = opened.get(chosen) or _open(model_path, config, chosen, facts)
    except MonitorError as exc:
        if config.backend != "auto":
            raise
        # measured here before, not usable now (a GPU gone, a driver changed): the reference
        log.warning("%s: %s no longer opens (%s): running %s", model_path.name, chosen.label,
                    exc, reference.backend.label)
        return reference, dataclasses.replace(choice, chosen=reference.backend,
                                              reason=f"{chosen.label} did not open")
    return detector, choice


def check_frames(model_path: Path, config: DetectorConfig, frames: Sequence[np.ndarray],
                 wrap=None) -> list[Trial]:
    """``monitor model check-backend``: every candidate the config allows against the
    reference on the user's ``frames``, recorded for ``open_detector`` (a refused one is never
    chosen)."""
    reference = Detector(model_path, dataclasses.replace(config, backend=REFERENCE,
                                                         precision="auto"))
    facts = model_facts(model_path)
    host = host_key()
    where = "of your frames"
    expected = detect_all(reference, frames)
    trials = []
    for cand in candidates_for(model_path, config, facts):
        if cand == reference.backend:
            continue
        try:
            det = _open(model_path, config, cand, facts)
            agreement = compare(expected, det, frames, wrap=wrap)
        except Exception as exc:  # not usable here, or failing on these frames
            trials.append(Trial(cand, refused=str(exc).splitlines()[0][:200]))
            continue
        why = refusal(agreement, config.backend_min_agreement, cand.label, where)
        trials.append(Trial(cand, agreement.int8_ms, agreement.fp32_ms, agreement, where, why))
    key = frames_key(file_sha256(model_path), config, reference.self_test_case, host)
    measured = [t for t in trials if t.agreement is not None]
    if measured:
        write_cache(model_path, key, "frames", measured)
    return trials
