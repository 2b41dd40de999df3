"""Zone sets (monitoring cases) switched by the robot program: which zones apply when.

``sets.py`` is the pure switch-over logic (the union of old and new set while switching, the
selector's ttl, faults for unknown and disallowed sets); ``requests.py`` the signed selection
request and its gate; ``receiver.py`` takes requests off Zenoh. docs/cases.md.

Also here: bounded muting of named zones (``muting.py``: the zone file's mute rules and the pure
``Mutes`` state), operator mute requests (``mute_requests.py``) and signed zone applies
(``zone_apply.py``). May import: ``monitor.wire`` (signatures, requests, answers) and the bottom
layer; ``monitor.zones`` reads its mute rules, so nothing here imports the zones.
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
