"""workcell-monitor: a supplementary camera monitor for robot cells.

It detects persons, checks them against zones and publishes RUN / SLOW / STOP commands and
alerts over Eclipse Zenoh. It is not a certified protective device.
"""

__version__ = "0.1.0"
