"""Cross-field checks of a zone file's zone sets (``sets:``, docs/cases.md): one line each."""

from __future__ import annotations

from monitor.zones.schema import CellSpec

SWITCHED_KINDS = ("protective", "warning")


def check_sets(spec: CellSpec) -> list[str]:
    """Faults of the ``sets`` / ``default_set`` / ``transitions`` / ``selector_ttl_s`` keys."""
    out: list[str] = []
    ids = [s.id for s in spec.sets]
    if not spec.sets:
        for key, value in (("default_set", spec.default_set),
                           ("transitions", spec.transitions),
                           ("selector_ttl_s", spec.selector_ttl_s)):
            if value is not None:
                out.append(f"{key}: given but the file declares no sets")
        return out
    known = set(ids)
    seen: set[str] = set()
    for s in spec.sets:
        if s.id in seen:
            out.append(f"set '{s.id}': duplicate set id")
        seen.add(s.id)
    zones = {z.id: z for z in spec.zones}
    for s in spec.sets:
        for zid in s.zones:
            z = zones.get(zid)
            if z is None:
                out.append(f"set '{s.id}': no zone '{zid}'")
            elif z.kind not in SWITCHED_KINDS:
                out.append(f"set '{s.id}': zone '{zid}' is a {z.kind} zone; sets switch "
                           "protective and warning zones only")
        if len(set(s.zones)) != len(s.zones):
            out.append(f"set '{s.id}': a zone is named twice")
    if spec.default_set is None:
        out.append("default_set: missing (the set in force at start; one of "
                   f"{', '.join(ids)})")
    elif spec.default_set not in known:
        out.append(f"default_set: no set '{spec.default_set}' (sets: {', '.join(ids)})")
    for pair in spec.transitions or ():
        for sid in pair:
            if sid not in known:
                out.append(f"transitions: [{pair[0]}, {pair[1]}] names no set '{sid}' "
                           f"(sets: {', '.join(ids)})")
        if pair[0] == pair[1]:
            out.append(f"transitions: [{pair[0]}, {pair[1]}] goes nowhere")
    return out
