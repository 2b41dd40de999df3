"""``monitor run``: the headless service beside the pose tracker.

Owns: the entry and its start order (``run``), the start-up checks before the loop (``setup``:
pipeline, zone checks, capacity, int8 hint, reaction budget), the live feed and sink (``loop``),
one log line per event (``log``), Prometheus metrics (``metrics``), the host's capacity
(``capacity``), the int8 hint (``int8hint``), signed zone swaps (``zone_swap``), which
commissioned configuration runs (``commissioned``: the fingerprint and the signed record) and
keeping that current while it runs (``commission_watch``).

May import: ``monitor.config`` and everything under it (driver, bus, pipeline, stages, the
extras it starts). Never ``monitor.replay`` (they share the driver), the cli or the console.
"""
