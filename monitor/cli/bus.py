"""Former home of the bus commands, now one module per command group: ``monitor.cli.watch``,
``monitor.cli.bridge`` (otus), ``monitor.cli.router``, ``monitor.cli.operator`` (reset,
status), ``monitor.cli.keys``; shared Zenoh options in ``monitor.cli.zenoh_args``.

Kept only so that code written against the old names still imports; not a command module.
"""

from monitor.cli.watch import _latch_text, _watch_subscriptions, _watchdog
from monitor.cli.zenoh_args import add_zenoh_args as _add_zenoh_args
from monitor.cli.zenoh_args import bus_config as _bus_config

__all__ = ["_add_zenoh_args", "_bus_config", "_latch_text", "_watch_subscriptions", "_watchdog"]
