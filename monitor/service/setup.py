"""The start-up of ``monitor run`` before and beside the loop: the pipeline from a validated
config (model, zones, health), the checks a zone set must pass (at start and at a signed apply),
the host's capacity and the int8 hint, and the reaction-time budget (configured, then measured)."""

from __future__ import annotations

import dataclasses
import logging
import time
from pathlib import Path

from monitor.bus.session import BusConfig, SafetyBus
from monitor.config import DEMO_SOURCE, MonitorConfig, demo_cell_path
from monitor.detector.test_model import require_real_model
from monitor.driver import require_protective_zone
from monitor.errors import ConfigError
from monitor.geometry import ReactionBudget
from monitor.geometry.reaction import (
    Allowances,
    MeasuredBudget,
    ReactionSink,
    ReactionWatch,
    at_start,
)
from monitor.pipeline import Pipeline
from monitor.service.capacity import CameraDemand, Limits, cameras_served
from monitor.service.capacity import check as capacity_check
from monitor.service.log import event
from monitor.service.metrics import Metrics
from monitor.zones.separation import require_separation_ready, with_reaction_time


def bus_config_for(config: MonitorConfig, cell) -> BusConfig:
    """The bus config with the active zone set's hash filled in."""
    return dataclasses.replace(config.bus, config_hash=cell.config_hash if cell else "")


def _require_fed_cameras(cell, config: MonitorConfig, zones_file: str | None) -> None:
    """A protective or warning image zone of a camera that no [[camera]] feeds would never
    see anyone: refused (a zone file edited for a new camera, the config not yet)."""
    if cell is None:
        return
    fed = {c.id for c in config.cameras}
    unfed = [z for z in cell.zones if z.enabled and z.shape == "polygon"
             and z.kind in ("protective", "warning") and z.camera not in fed]
    if unfed:
        z = unfed[0]
        raise ConfigError(f"zone '{z.id}' of {zones_file} is on camera '{z.camera}', which no "
                          f"[[camera]] of the config feeds: it would never see a person (add "
                          f"the camera: 'monitor zones camera add ... --config')")


def build_pipeline(config: MonitorConfig):
    """Model, zones, health checker and pipeline from a validated config (I/O: files only);
    also the warning to carry when the synthetic test model is allowed on a live camera, and
    the detector's backend choice (``monitor.detector.choice.Choice``)."""
    from monitor.detector import visible
    from monitor.detector.choice import open_detector
    from monitor.detector.envelope import for_detector
    from monitor.health.build import camera_health
    from monitor.health.references import choose_references, load_chosen_reference
    from monitor.models import synthetic
    from monitor.zones import load_cell

    zones_file = zones_file_of(config)
    cell = load_cell(zones_file) if zones_file else None
    zone_checks(config, cell, zones_file)
    model = Path(config.model.path) if config.model.path else synthetic.ensure_model()
    # one model, shared by the cameras in turn, on the fastest backend whose persons agree
    # with onnxruntime's (measured once per model and host, cached beside the model)
    sizes = [(cell.cameras[c.id].width, cell.cameras[c.id].height) if cell else (1920, 1080)
             for c in config.cameras]
    detector, choice = open_detector(model, config.detector,
                                     max(sizes, key=lambda s: s[0] * s[1]),
                                     progress=lambda text: event(f"detector backend: {text}"))
    # the light, contrast, noise and blur the model still finds a person in (measured once
    # with the backend that runs and stored beside the model): a camera outside it is a
    # fault, not an empty cell
    envelope = for_detector(detector, config.health.envelope_min_recall)
    health, expected = {}, {}
    references = choose_references(config, cell)  # the zone file's wins over monitor.toml's
    references_bgr = {}
    for cam in config.cameras:
        reference = references_bgr[cam.id] = load_chosen_reference(references[cam.id], cell)
        health[cam.id] = camera_health(config.health, cam.id, reference, cell, envelope)
        expected[cam.id] = (cell.cameras[cam.id].width, cell.cameras[cam.id].height) \
            if cell else None
    test_model = require_real_model(detector.test_model, config.cameras,
                                    config.model.allow_test_model)
    pipeline = Pipeline(detector, [c.id for c in config.cameras], config.policy, cell, health,
                        linking=config.tracking, references=references_bgr)
    # the share of a person the model needs in view (measured once, stored beside the model):
    # floor where less of a crouching person shows is never seen free
    needed = visible.for_detector(detector, config.health.envelope_min_recall)
    pipeline.visible_fraction = needed.needed if needed is not None else None
    pipeline.prepared = prepared_zones(config, cell)
    return pipeline, cell, expected, test_model, choice


def zones_file_of(config: MonitorConfig) -> str | None:
    """The zone file the service runs with (the demo cell for the demo source), or None."""
    zones_file = config.zones.file
    if zones_file is None and all(c.source == DEMO_SOURCE for c in config.cameras):
        zones_file = str(demo_cell_path())
    return zones_file


def zone_checks(config: MonitorConfig, cell, zones_file: str | None) -> None:
    """What a zone set must pass to be decided with, at start and at a signed apply
    (monitor.service.zone_swap): a protective zone, every fed camera in it, no zone of an unfed
    camera, and a tool with a calibrated camera for separation monitoring. ConfigError."""
    require_protective_zone(cell, config.zones.allow_no_protective,
                            zones_file or "(no [zones] file)")
    for cam in config.cameras:
        if cell is not None and cam.id not in cell.cameras:
            raise ConfigError(f"camera {cam.id!r} is not in zone file {zones_file} "
                              f"(has {', '.join(cell.cameras)})")
    _require_fed_cameras(cell, config, zones_file)
    if config.policy.separation_monitoring:
        if cell is None:
            raise ConfigError("policy.separation_monitoring needs a zone file with a tool and a "
                              "calibrated camera ([zones] file)")
        require_separation_ready(cell)


def prepared_zones(config: MonitorConfig, cell):
    """The cell's prepared zones as the pipeline decides with them (None: no cell)."""
    if cell is None:
        return None
    if config.policy.separation_monitoring or cell.prepared.moving:
        # T_r is never smaller than the delays this configuration lets pass (ISO/TS 15066);
        # zones that grow with the tool speed use S_p too
        return with_reaction_time(cell.prepared, reaction_budget(config))
    return cell.prepared


def check_capacity(config: MonitorConfig, detector, expected: dict, mode: str,
                   stopped=lambda: False):
    """Time the detector on each camera's frame size (the zone file's, else 1920x1080) and
    refuse (or warn about) a host that cannot watch the cell within the limits."""
    demands = [CameraDemand(c.id, *(expected.get(c.id) or (1920, 1080)), c.max_fps)
               for c in config.cameras]
    limits = Limits(config.policy.frame_timeout, config.policy.max_frame_age,
                    config.bus.stall_timeout, config.health.lost_after_s)
    return capacity_check(detector.detect, demands, limits, mode, stopped)


def capacity_per_backend(config: MonitorConfig, expected: dict, capacity, choice) -> str | None:
    """"capacity per backend (1920x1080 cameras at 10 fps): openvino bf16 3 cameras at 10.0 fps,
    onnxruntime fp32 1 camera at 10.0 fps": the measured detection time scaled by each backend's
    inference time against the one that runs (monitor.detector.choice), for cameras like the
    largest configured one at its max_fps (10 fps when unset). None without other backends."""
    if capacity is None or choice.reference is None:
        return None
    times = {t.candidate.label: t.ms for t in choice.trials if t.ms is not None}
    ref = next((t.reference_ms for t in choice.trials if t.reference_ms is not None), None)
    if ref is None:
        return None
    times[choice.reference.label] = ref
    ran = times.get(choice.chosen.label, ref)
    sizes = {c.id: expected.get(c.id) or (1920, 1080) for c in config.cameras}
    biggest = max(config.cameras, key=lambda c: sizes[c.id][0] * sizes[c.id][1])
    width, height = sizes[biggest.id]
    fps = biggest.max_fps or 10.0
    limits = Limits(config.policy.frame_timeout, config.policy.max_frame_age,
                    config.bus.stall_timeout, config.health.lost_after_s)
    parts = []
    for label, ms in sorted(times.items(), key=lambda kv: kv[1]):
        n, each = cameras_served(capacity.detect_s * ms / ran, width, height, fps, limits)
        parts.append(f"{label} {n} camera{'' if n == 1 else 's'} at {each:.1f} fps")
    return f"capacity per backend ({width}x{height} cameras at {fps:g} fps): " + ", ".join(parts)


def reaction_budget(config: MonitorConfig) -> ReactionBudget:
    """The worst-case delays of this configuration (seconds): a frame may arrive as late as
    ``frame_timeout`` before the cell STOPs anyway, be ``max_frame_age`` old when decided on, a
    lost STOP leaves the consumer on the last RUN for ``ttl_ms``, and the pose may be
    ``pose_timeout`` old."""
    policy = config.policy
    return ReactionBudget(frame_interval_s=policy.frame_timeout,
                          max_frame_age_s=policy.max_frame_age,
                          processing_s=config.service.tick_s,
                          command_ttl_s=config.bus.ttl_ms / 1000.0,
                          consumer_reaction_s=config.reaction.consumer_reaction_ms / 1000.0,
                          pose_age_s=policy.pose_timeout)


def int8_at_start(config: MonitorConfig, detector, expected: dict, stopped):
    """The int8 model beside the configured one, timed against it here
    (monitor/service/int8hint.py); None without one. Never switches the model."""
    from monitor.detector.choice import open_detector
    from monitor.errors import MonitorError
    from monitor.service.int8hint import int8_hint

    size = max((expected.get(c.id) or (1920, 1080) for c in config.cameras),
               key=lambda s: s[0] * s[1])
    try:  # the int8 file on its own fastest agreeing backend, as it would run
        return int8_hint(detector.model_path, detector.detect,
                         lambda path: open_detector(path, config.detector, size)[0].detect,
                         size, stopped)
    except MonitorError as exc:  # an unusable int8 file is no reason not to start
        event(f"int8 model beside the model not usable: {exc}", logging.WARNING)
        return None


def reaction_sink(config: MonitorConfig, pipeline: Pipeline, capacity, bus: SafetyBus,
                  metrics: Metrics, alert) -> ReactionSink:
    """The measured reaction budget (monitor/geometry/reaction.py) against the T_r that S_p was
    computed with (without separation monitoring: this configuration's T_r, and a warning
    only): judged at start from the capacity check's figures (log, alert, status), then live
    from the steps."""
    separation = (pipeline.prepared.separation if config.policy.separation_monitoring
                  and pipeline.prepared is not None else None)
    configured = (separation.reaction_time_s if separation is not None
                  else reaction_budget(config).total_s())
    speed = (pipeline.prepared.cell.spec.separation.programmed_speed_mps
             if separation is not None else None)
    allowances = Allowances(
        bus_hop_s=config.reaction.bus_hop_ms / 1000.0, command_ttl_s=config.bus.ttl_ms / 1000.0,
        consumer_reaction_s=config.reaction.consumer_reaction_ms / 1000.0,
        pose_age_s=config.policy.pose_timeout if separation is not None else 0.0)
    watch = ReactionWatch(configured, config.reaction.alert_repeat_s, separation, speed,
                          "critical" if separation is not None else "warning")
    verdicts: dict = {}
    if capacity is not None:
        start = at_start(capacity.frame_s, capacity.processed_fps, capacity.frame_age_s,
                         allowances)
        verdicts, alerts = watch.update(start, time.monotonic())
        for v in verdicts.values():
            event(f"reaction budget{' EXCEEDED' if v.exceeded else ''}: {v.message}",
                  logging.ERROR if v.exceeded else logging.INFO)
        for a in alerts:
            alert(a)
    return ReactionSink(MeasuredBudget(allowances), watch, alert, bus.update_status,
                        metrics.registry, config.reaction.check_period_s, verdicts)


def no_reference_note(pipeline, cameras) -> str | None:
    """The start-up and status note for cameras without a commissioning reference: neither
    objects put into the zones since commissioning nor fixtures the zone file leaves out are
    noticed there (docs/occlusion.md, "What seen means"). None: every camera has one."""
    missing = [c.id for c in cameras if c.id not in pipeline.references]
    if not missing or pipeline.cell is None:
        return None
    return (f"camera {', '.join(missing)}: no commissioning reference: objects put into the "
            "protective and warning zones since commissioning are not noticed, and a fixture "
            "the zone file leaves out does not tell cut-off feet (make one with 'monitor "
            "reference capture' and set it with 'monitor zones camera set --reference')")
