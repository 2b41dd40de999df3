"""Errors the monitor raises on purpose; the CLI prints them as one line, no traceback."""


class MonitorError(Exception):
    """A problem the user can fix (bad file, bad config, missing model). Message is one line."""


class ModelError(MonitorError):
    """The ONNX model is missing, corrupt or has no known output layout."""


class InputError(MonitorError):
    """An image, video, stream or packet could not be read."""


class ConfigError(MonitorError):
    """A config or zone file is invalid."""


class DetectorError(MonitorError):
    """The detector's answer cannot be trusted (NaN or infinite model outputs, a broken model).

    The pipeline turns it into a STOP (``detector_error``): never "no persons"."""
