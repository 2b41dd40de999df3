"""The incident recorder (docs/incidents.md): an optional extra beside the safety loop.

For readers (the web console, the CLI, remote tools), the whole API is:

- ``IncidentIndex(data_dir)``: ``.list(since=, until=, cause=, limit=)`` -> ``[Incident]``
  newest first; ``.get(id)`` -> ``Incident | None``; ``.clip_path(id, camera=None)``.
- ``Incident``: the index row (``id``, ``wall``, ``time_s``, ``causes``, ``state``,
  ``operator``, ``reset_accepted``, ...), ``.record`` (events, commands, clips, hashes) and
  ``.clip_paths()`` (camera -> MP4, H.264).
- ``list_incidents(data_dir, **filters)``, ``clip_path(data_dir, id, camera=None)``.
- ``data_dir_of(RecorderConfig)``: where a config's incidents are.

Writers: ``IncidentRecorder`` (the driver sink), nothing else.

May import: the driver (it is one of its sinks), ``monitor.records`` (the records and the overlay it
shares with the replay), ``monitor.zones`` and the layers under them; never the service, the bus or
the adapters.
"""

from monitor.incidents.settings import RecorderConfig, data_dir_of, default_data_dir
from monitor.incidents.store import Incident, IncidentIndex, clip_path, list_incidents

__all__ = ["Incident", "IncidentIndex", "RecorderConfig", "clip_path", "data_dir_of",
           "default_data_dir", "list_incidents"]


def __getattr__(name: str):
    if name == "IncidentRecorder":  # heavy imports (video, the replay's overlay) on demand
        from monitor.incidents.recorder import IncidentRecorder

        return IncidentRecorder
    raise AttributeError(name)
