"""What the geometry builders read of a zone file and of its prepared geometry, as protocols.

``files.Cell`` (a validated zone file) builds its ``prepared`` geometry with
``prepare.prepare_cell``, which builds volumes (``volumes``) and the zones that follow the tool
(``moving_check``). Those builders only read a few fields of the cell and of the prepared cell,
so they name these protocols instead of ``Cell`` and ``PreparedCell``: the modules then import
downwards only (no circle files -> prepare -> moving_check -> volumes -> files, not even for the
type checker). Read-only properties: both real classes are frozen dataclasses.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Protocol

import fcl
import numpy as np

from monitor import geometry as geo
from monitor.zones.schema import CameraSpec, CellSpec


class CellData(Protocol):
    """The fields of a validated zone file (``monitor.zones.files.Cell``) the builders read."""

    @property
    def spec(self) -> CellSpec: ...

    @property
    def cameras(self) -> Mapping[str, CameraSpec]: ...

    @property
    def zones(self) -> tuple[Any, ...]: ...

    @property
    def camera_models(self) -> Mapping[str, geo.CameraModel]: ...

    @property
    def meshes(self) -> Mapping[str, tuple[np.ndarray, np.ndarray]]: ...


class PreparedData(Protocol):
    """The fields of a cell's prepared geometry (``monitor.zones.prepare.PreparedCell``) the
    volume and following-zone checks read."""

    @property
    def cell(self) -> CellData: ...

    @property
    def person(self) -> geo.PersonModel: ...

    @property
    def separation(self) -> geo.SeparationParams: ...

    @property
    def zone_cylinder(self) -> fcl.Cylinder: ...

    @property
    def moving(self) -> tuple[Any, ...]: ...
