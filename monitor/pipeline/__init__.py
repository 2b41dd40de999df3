"""The pipeline: one processing step per frame (detect, mask, zones, tracks, health) and the
cell's decision over every camera's newest answer (``monitor.policy``).

Persons are tracked per camera (``monitor.tracking.tracks``): a person lost inside a protective or
warning zone keeps it occupied (``ZoneHit(lost=True)``) until seen again or until an operator's
``confirm_clear`` reset. Mask zones act on the detector's raw boxes before merging
(``monitor.zones.masks``), so a masked look-alike never swallows a real person.

The same ``Pipeline`` serves the live service and replay; only the clock differs (monotonic
seconds live, the video's own timestamps in replay), and it is always passed in, so replay is
deterministic. I/O (cameras, Zenoh, files) stays outside: the caller hands in frames, the newest
tool pose and reset requests, and publishes what comes out.

Modules: ``core`` (``Pipeline``: the step per frame and the decision handed on), ``data``
(``StepResult``, per-camera state), ``masking`` (mask zones on raw boxes), ``locate`` (zones,
tracks, cell persons of a frame), ``evidence`` (every camera's answer merged for the policy),
``holds`` (lost persons, confirm-clear), ``area_views`` (the lost persons' areas and the unseen
cells each step hands on for the screen), ``pocket_views`` (the hidden pockets with their counts,
likewise), ``fault_alerts``, ``mutes``, ``zone_sets``.

May import: the stages it runs (``detector``, ``frames``, ``tracking``, ``health``),
``monitor.zones``, ``monitor.cases``, the building blocks and the bottom layer; never the driver,
the bus or their callers.
"""

from monitor.pipeline.core import Pipeline
from monitor.pipeline.data import StepResult
from monitor.pipeline.evidence import ZONES_APPLYING
from monitor.pipeline.fault_alerts import QUIET_FAULTS

__all__ = ["QUIET_FAULTS", "ZONES_APPLYING", "Pipeline", "StepResult"]
