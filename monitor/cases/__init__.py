"""Zone sets (monitoring cases) switched by the robot program: which zones apply when.

``sets.py`` is the pure switch-over logic (the union of old and new set while switching, the
selector's ttl, faults for unknown and disallowed sets); ``requests.py`` the signed selection
request and its gate; ``receiver.py`` takes requests off Zenoh. docs/cases.md.
"""

from monitor.cases.sets import (
    CasePlan,
    CaseState,
    Refusal,
    Selection,
    ZonesInForce,
    advance,
    apply_event,
    apply_events,
    filter_report,
    in_force,
    initial_case,
    plan_of,
)

__all__ = ["CasePlan", "CaseState", "Refusal", "Selection", "ZonesInForce", "advance",
           "apply_event", "apply_events", "filter_report", "in_force", "initial_case", "plan_of"]
