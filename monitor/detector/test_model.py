"""The synthetic test model never guards a real cell by accident.

The synthetic tiny-YOLOv3 (``monitor model build``) detects only the saturated-magenta test
figures that ``monitor.scene`` draws; on a real camera it sees nobody, and its built-in
self-test passes anyway (it tests the test model). So ``monitor run`` refuses it on a live
source (a camera index or a stream URL) unless the config says ``[model] allow_test_model =
true``; then the log, the status and every command's reasons say so.
"""

from __future__ import annotations

from collections.abc import Iterable

from monitor.errors import ConfigError
from monitor.frames import redact_url, source_kind

TEST_MODEL_NOTE = ("the synthetic TEST model: it detects only the magenta test figures of the "
                   "demo scene, never a real person")
# the reason every command carries while a test model watches a live source
TEST_MODEL_REASON = "test_model"
LIVE_KINDS = ("camera", "url")


def live_cameras(cameras: Iterable) -> list:
    """The cameras (config ``[[camera]]`` tables) whose source is a live camera or stream."""
    return [c for c in cameras if source_kind(c.source) in LIVE_KINDS]


def require_real_model(test_model: bool, cameras: Iterable, allowed: bool) -> str | None:
    """Refuse the test model on a live source (one-line ``ConfigError``) unless ``allowed``.

    Returns the warning to log, put in the status and add to every command when the test model
    watches a live source because the config allows it; None when there is nothing to say."""
    live = live_cameras(cameras)
    if not test_model or not live:
        return None
    names = ", ".join(f"{c.id} ({redact_url(str(c.source))})" for c in live)
    if not allowed:
        raise ConfigError(
            f"[model]: no model path is given, or it is the synthetic test model, and camera "
            f"{names} is a live source: the test model detects only the demo's magenta test "
            f"figures, never a real person; set [model] path to a person detector, or [model] "
            f"allow_test_model = true for a test bench")
    return f"the synthetic TEST model watches live camera {names}: it cannot see real persons " \
           f"(allowed by allow_test_model)"
