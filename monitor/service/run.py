"""`monitor run`: the headless service beside the pose tracker.

Start order: signal handlers -> config (validated, nothing opened yet) -> zones (an enabled
protective zone is required unless ``[zones] allow_no_protective = true``) -> model -> Zenoh bus
-> pose subscriber -> frame grabbers -> the driver loop (``monitor.driver``). Shutdown runs in
reverse with bounded joins; the bus sends a last STOP (reason ``shutdown``) before it closes.
SIGINT and SIGTERM stop the loop (exit 0); a process still there 1.5 s later, or a second
signal, publishes STOP best effort and exits at once.

The loop never waits for a frame longer than ``service.tick_s``: without frames the policy still
runs its timers, so a lost camera gives STOP within ``policy.frame_timeout``. A gap in the loop
itself longer than ``frame_timeout`` (process frozen) is a latched ``monitor_stalled`` STOP.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from pathlib import Path

from monitor.bus.preview import start_preview
from monitor.bus.session import SafetyBus
from monitor.cases.receiver import CaseReceiver
from monitor.config import MonitorConfig, load_config
from monitor.driver import Driver, protective_warning, settle_heap
from monitor.geometry import describe_separation
from monitor.health.build import inplace_check, protective_regions
from monitor.health.references import (
    missing_reference_warnings,
    reference_warnings,
    without_reference,
)
from monitor.pipeline import Pipeline
from monitor.policy import STOP, Command, Reason
from monitor.service.commission_watch import CommissionWatch
from monitor.service.log import event, setup_logging
from monitor.service.loop import LiveFeed, ServiceSink
from monitor.service.metrics import Metrics
from monitor.service.setup import (
    build_pipeline,
    bus_config_for,
    capacity_per_backend,
    check_capacity,
    int8_at_start,
    no_reference_note,
    reaction_budget,
    reaction_sink,
    zones_file_of,
)
from monitor.signals import StopSignals
from monitor.timetext import wall_clock
from monitor.wire.resets import LatchNonces


def run_service(config_path: str | Path | None, log_json: bool = False,
                duration: float | None = None, stop: threading.Event | None = None,
                signals: StopSignals | None = None, capacity_check: str | None = None) -> int:
    """The service until ``duration`` has passed or a signal (or ``stop``) ends it.

    ``signals``: handlers the caller installed as early as it could (``monitor run`` does so
    before the model runtime is imported); without them they are installed here.
    ``capacity_check``: overrides ``[service] capacity_check`` ("refuse", "warn", "off").
    """
    own_signals = signals is None
    signals = signals or StopSignals(name="monitor run", stop=stop).install()
    try:
        return _run(config_path, log_json, duration, signals, capacity_check)
    finally:
        if own_signals:
            signals.restore()


def _run(config_path, log_json: bool, duration: float | None, signals: StopSignals,
         capacity_check: str | None = None) -> int:
    from monitor.frames import LatestFrameGrabber, SourceOptions, open_source

    stop = signals.stop
    setup_logging(log_json)
    config = load_config(config_path)
    if log_json is False and config.service.log_json:
        setup_logging(True)
    pipeline, cell, expected, test_model, choice = build_pipeline(config)
    if stop.is_set():  # told to stop while the model loaded: nothing opened yet
        event("stopped before start")
        return 0
    event("started", config=str(config_path or "embedded demo"),
          cameras=",".join(f"{c.id}={c.source}" for c in config.cameras),
          zones=cell.label if cell else "none",
          config_hash=cell.config_hash if cell else "")
    event(choice.line())
    warning = protective_warning(cell)
    if warning:
        event(warning, logging.WARNING)
    if test_model:
        event(test_model, logging.WARNING)
    for doubt in cell.warnings if cell else ():  # e.g. zone floor accepted as unobserved
        event(f"zone file {cell.label}: {doubt}", logging.WARNING)
    for doubt in reference_warnings(config, cell):  # two references for one camera
        event(doubt, logging.WARNING)
    for doubt in missing_reference_warnings(config, cell):  # a real camera without one
        event(doubt, logging.WARNING)
    unwatched = no_reference_note(pipeline, config.cameras)
    if unwatched:  # what changed since commissioning is not noticed (docs/occlusion.md)
        event(unwatched, logging.WARNING)
    if config.bus.allow_unsigned_resets:
        event("resets are accepted without an operator key (embedded demo on 127.0.0.1, or "
              "allow_unsigned_resets = true): not for a production cell", logging.WARNING)
    if config.policy.separation_monitoring and pipeline.prepared is not None:
        event(describe_separation(pipeline.prepared.separation,
                                  cell.spec.separation.programmed_speed_mps,
                                  reaction_budget(config)))
    metrics = Metrics(config.service.metrics_port, config.service.metrics_host)
    metrics.set_backend(choice.chosen.backend, choice.chosen.precision,
                        choice.agreement.agreement if choice.agreement is not None else 1.0)
    closers: list = []  # the recorder's, run after the bus's final STOP (bounded)
    try:
        with SafetyBus(bus_config_for(config, cell), alert_limits=config.alerts) as bus:
            forget = signals.on_force(lambda: bus.publish_command(shutdown_forced()))
            pipeline.latch_nonces = LatchNonces(bus.boot)  # resets name this run's latches
            pipeline.when = wall_clock()  # mute reasons say "until 14:03:12"
            event("bus open", key_prefix=bus.config.key_prefix, zid=bus.boot,
                  listen=",".join(bus.config.listen), connect=",".join(bus.config.connect))
            if warning:
                bus.update_status(protective_zone=False, warning=warning)
            if test_model:
                bus.update_status(test_model=test_model)
            missing = without_reference(config, cell)
            if missing:  # said once at start (above) and for as long as it runs here
                bus.update_status(without_reference=missing)
            bus.update_status(detector=choice.to_dict())
            bus.update_status(changes_watched=sorted(pipeline.objects),
                              changes_unwatched=unwatched or None)

            # which commissioned configuration runs (docs/commissioning.md): checked now,
            # then again on its own thread whenever the record or a fingerprinted file changes
            def commissioned(state: dict) -> None:
                bus.update_status(commissioned=state)
                if state.get("matches"):
                    event("commissioned", by=state.get("by"), key=state.get("key"),
                          report=state.get("report"))
                else:
                    event(f"not commissioned: {state.get('reason')}", logging.WARNING)
            watch = CommissionWatch(config_path, config, cell, pipeline.detector.model_path,
                                    cell.config_hash if cell else "", commissioned)
            watch.start()
            closers.append(watch.close)
            # zone set selections (monitor/cases/): only with sets in the zone file
            cases = (CaseReceiver.for_bus(bus.session, bus.config, pipeline.case_plan,
                                          bus.signed_answer)
                     if pipeline.case_plan is not None else None)
            if cases is not None:
                cases.__enter__()
                closers.append(cases.close)
                event("zone sets", default=pipeline.case_plan.default, key=cases.key_expr,
                      selectors=bus.config.selectors_file or "none (every selection refused)")
            try:
                # the embedded demo's capacity only warns: a demonstration, not a cell
                _serve(config, pipeline, bus, expected, metrics, stop, duration,
                       LatestFrameGrabber, SourceOptions, open_source, test_model,
                       capacity_check or ("warn" if config_path is None
                                          else config.service.capacity_check),
                       closers, cases, watch.zones_changed, choice)
            finally:
                forget()
            event("shutting down: final STOP published")
    finally:
        for close in closers:
            with contextlib.suppress(Exception):
                close()
        metrics.close()
    event("stopped")
    return 0


def shutdown_forced() -> Command:
    return Command(STOP, 0.0, (Reason("shutdown", "monitor shutting down (forced)"),),
                   since=time.monotonic())


def _serve(config: MonitorConfig, pipeline: Pipeline, bus: SafetyBus, expected: dict, metrics,
           stop: threading.Event, duration: float | None, grabber_cls, options_cls,
           open_source, test_model: str | None = None, capacity_mode: str = "refuse",
           closers: list | None = None, cases=None, commissioned=None, choice=None) -> None:
    # zones that follow the tool need the pose too (without it they stay at their maximum)
    following = pipeline.prepared is not None and bool(pipeline.prepared.moving)
    pose = (bus.pose_subscriber(tracker_clock=config.tracker_clock,
                                tracker=config.tracker)
            if config.policy.separation_monitoring or following else None)
    if pose is not None:
        pose.__enter__()
    grabbers: list = []
    closers = closers if closers is not None else []
    try:
        for cam in config.cameras:
            if stop.is_set():
                return
            source = open_source(cam.source, cam.id, realtime=cam.realtime,
                                 options=options_cls(loop=cam.loop), stop=stop)
            grabbers.append(grabber_cls(source, stop=stop,
                                        expected_size=expected[cam.id]).start())
        # after every file and camera opened (their errors come first), with the grabbers
        # already decoding: the load the loop will see
        capacity = check_capacity(config, pipeline.detector, expected, capacity_mode,
                                  stop.is_set)
        if capacity is not None:
            event(capacity.describe())
            for line in capacity.warnings:
                event(f"capacity: {line}", logging.WARNING)
            bus.update_status(capacity=capacity.to_dict())
            per_backend = (capacity_per_backend(config, expected, capacity, choice)
                           if choice is not None else None)
            if per_backend is not None:
                event(per_backend)
            int8 = int8_at_start(config, pipeline.detector, expected, stop.is_set)
            if int8 is not None:
                event(int8.message())
                bus.update_status(int8=int8.to_dict())
        sink = ServiceSink(bus, metrics, grabbers, notice=test_model)
        sink.objects = pipeline.objects  # what changed since commissioning, in the status
        recorder = None
        if config.recorder.enabled:  # an optional extra: never a reason not to command
            from monitor.incidents.live import start_recorder

            recorder = start_recorder(config, pipeline.cell, bus, metrics, sink.alert, event)
        if recorder is not None:
            sink.recorder = recorder[0]
            closers.append(recorder[1])
        feed = LiveFeed(grabbers, bus, pose, config.service.tick_s, stop, duration,
                        sink.alert, pipeline.prepared,
                        max_fps={c.id: c.max_fps for c in config.cameras})
        # signed zone applies: checked on the bus, swapped in by the loop between two steps
        from monitor.bus.holds import start_handover
        from monitor.service.zone_swap import LiveZones, ZoneApplies

        applies = ZoneApplies(bus)
        closers.insert(0, applies.close)
        rec = recorder[0] if recorder is not None else None

        def applied(cell) -> None:
            feed.use_zones(pipeline.prepared)
            if inplace is not None:  # the new protective zones are the check's targets
                inplace.zones = protective_regions(cell, [c.id for c in config.cameras])
            if rec is not None:
                rec.zones_changed(cell)
            if commissioned is not None:  # the zones may differ from the commissioned ones
                commissioned(cell)

        feed.zones = LiveZones(config, zones_file_of(config), pipeline, bus, applies,
                               sink.alert, event, on_applied=applied)
        bus.update_status(zones_file=zones_file_of(config) or "")
        feed.cases = cases
        # after the service's sink: the command of a step is published when it times it
        reaction = reaction_sink(config, pipeline, capacity, bus, metrics, sink.alert)
        # the safety sink first; the recorder and the live preview (optional extras) last
        sinks = [sink, reaction] if recorder is None else [sink, reaction, recorder[0]]
        preview = start_preview(config.preview, bus, event)
        if preview is not None:
            sinks.append(preview[0])
            closers.insert(0, preview[1])
        handover = start_handover(config, pipeline, bus)  # holds of the cell's other monitors
        if handover is not None:
            sinks.insert(1, handover)
            feed.handover = handover
            closers.insert(0, handover.close)
        inplace = inplace_check(pipeline.detector, pipeline.cell,
                                [c.id for c in config.cameras], config.health.inplace_period_s)
        driver = Driver(pipeline, sinks, stall_after_s=config.policy.frame_timeout,
                        self_test_period_s=getattr(config.detector, "self_test_period_s", None),
                        inplace=inplace)
        # cameras whose frames are ready together share one inference (dynamic-batch models)
        batch = config.detector.batch_cameras and len(grabbers) > 1 \
            and pipeline.detector.batchable
        if len(grabbers) > 1:
            event("batching the cameras' frames" if batch else "cameras' frames run in turn",
                  cameras=len(grabbers))
        event("start-up objects frozen out of garbage collection", objects=settle_heap())
        driver.run(feed, stop, batch=batch)
    finally:
        stop.set()
        for grabber in reversed(grabbers):
            if not grabber.stop(timeout=0.5):  # a read blocked in a driver: daemon thread
                event("frame grabber did not stop in time", logging.WARNING,
                      camera=grabber.camera_id)
        if pose is not None:
            pose.__exit__(None, None, None)

