"""Zones: the zone file and the per-frame zone query.

A zone file (YAML, ``version: 1``) describes one robot cell: its cameras (with an optional
calibration) and its zones. See ``zones/README.md`` for the format. Zone kinds:

* ``protective``: a person inside leads to STOP;
* ``warning``: a person inside leads to SLOW at ``speed_scale``;
* ``mask``: persons anchored inside are ignored (a poster, a mannequin);
* ``watch``: a region whose scene changes raise alerts (the health stage uses it).

A zone is an image polygon of one camera (pixels at that camera's full resolution) or a cell
volume (metres, z up, origin at the robot base on the floor): an extruded floor polygon, a box, a
vertical cylinder or a closed mesh file.

One module per job:

* ``schema``: the file's pydantic models (unknown keys refused);
* ``files``: reading, validating, hashing, atomic saving; the validated ``Cell``;
* ``validate``: one-line messages and the cross-field checks;
* ``prepare``: geometry built once per cell for the per-frame query;
* ``check``: the per-frame query (``check_persons``), answers only, no state;
* ``draw``: outlines in an image (watch regions, zone drawing).

``load_cell`` validates everything before anything runs and raises ``ConfigError`` with one line
naming the file, the zone and the fault.

May import: ``monitor.geometry``, ``monitor.cases`` (mute rules) and the bottom layer; never a stage
that runs the zones (tracking, health, pipeline).
"""

from monitor.zones.check import check_persons, merge_towards_danger, volume_distances
from monitor.zones.draw import draw_zones, volume_outline_m, volume_region_px, watch_regions
from monitor.zones.files import (
    Cell,
    ZoneDumper,
    cell_faults,
    cell_to_data,
    config_hash,
    dump_cell_document,
    dump_cell_yaml,
    load_cell,
    parse_cell,
    read_cell_data,
    read_cell_document,
    save_cell,
    write_cell_data,
)
from monitor.zones.prepare import PreparedCell, prepare_cell, tool_object
from monitor.zones.schema import (
    ANCHORS,
    KINDS,
    SCHEMA_VERSION,
    VOLUME_SHAPES,
    BoxZone,
    CameraSpec,
    CellSpec,
    CylinderZone,
    ExtrudeZone,
    HomographyCalibration,
    MeshZone,
    PersonSpec,
    PinholeCalibration,
    PolygonZone,
    SeparationSpec,
    ToolBox,
    ToolCylinder,
    ToolMesh,
    ToolOffset,
    ToolSphere,
)
from monitor.zones.volumes import prepare_volume

__all__ = [
    "ANCHORS", "KINDS", "SCHEMA_VERSION", "VOLUME_SHAPES", "BoxZone", "CameraSpec", "Cell",
    "CellSpec", "CylinderZone", "ExtrudeZone", "HomographyCalibration", "MeshZone", "PersonSpec",
    "PinholeCalibration", "PolygonZone", "PreparedCell", "SeparationSpec", "ToolBox",
    "ToolCylinder", "ToolMesh", "ToolOffset", "ToolSphere", "ZoneDumper", "cell_faults",
    "cell_to_data", "check_persons", "config_hash", "draw_zones", "dump_cell_document",
    "dump_cell_yaml", "load_cell", "merge_towards_danger", "parse_cell", "prepare_cell",
    "prepare_volume", "read_cell_data", "read_cell_document", "save_cell", "tool_object",
    "volume_distances", "volume_outline_m", "volume_region_px", "watch_regions", "write_cell_data"
]
