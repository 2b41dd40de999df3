"""``monitor status`` as text for an operator (pure: a status answer in, lines out).

The answer comes from the network: every field may be missing or of another type, and none of
that reads as "all clear". A missing command reads STOP; a field of the wrong type is shown as
unknown, never skipped silently where it matters (state, latch, cameras).
"""

from __future__ import annotations

from datetime import datetime
from typing import Any

DANGER = ("STOP", "SLOW")


def _dict(value: Any) -> dict:
    return value if isinstance(value, dict) else {}


def _list(value: Any) -> list:
    return value if isinstance(value, list) else []


def _num(value: Any) -> float | None:
    return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) \
        else None


def duration(s: float | None) -> str:
    """``3 h 04 min``, ``4 min 05 s``, ``12 s``; ``?`` when unknown."""
    if s is None or not s >= 0:
        return "?"
    s = int(s)
    if s >= 3600:
        return f"{s // 3600} h {s % 3600 // 60:02d} min"
    if s >= 60:
        return f"{s // 60} min {s % 60:02d} s"
    return f"{s} s"


def _wall(t: Any) -> str:
    t = _num(t)
    return datetime.fromtimestamp(t).strftime("%Y-%m-%d %H:%M:%S") if t is not None else "?"


def _reason(r: dict) -> str:
    code = str(r.get("code", "?"))
    where = f" [{r['zone_id']}]" if r.get("zone_id") else ""
    return f"{code}{where}: {r.get('message', '')}"


def _command_lines(command: dict | None) -> list[str]:
    if not command:  # whatever else the answer says: nothing decided is STOP
        return ["command: STOP (no command decided yet)"]
    scale = _num(command.get("speed_scale"))
    head = str(command.get("state", "?"))
    if head == "SLOW" and scale is not None:
        head += f" x{scale:.2f}"
    if command.get("latched"):
        head += ", LATCHED: " + ("reset possible" if command.get("reset_possible")
                                 else "no reset until the causes clear")
    lines = [f"command: {head}"]
    reasons = [r for r in _list(command.get("reasons")) if isinstance(r, dict)]
    lines += [f"  {_reason(r)}" for r in reasons] or ["  (no reason)"]
    faults = [f"{r['fault']}" + (f" ({r['source']})" if r.get("source") else "")
              for r in reasons if r.get("fault")]
    lines.append(f"faults: {', '.join(faults) if faults else 'none'}")
    sets = _list(command.get("zone_sets"))
    if sets:
        lines.append(f"zone sets in force: {', '.join(map(str, sets))}"
                     + (" (switching: their union applies)" if len(sets) > 1 else ""))
    return lines


def _camera(c: dict) -> str:
    name = str(c.get("id", "?"))
    if c.get("connected") is not True:
        error = f": {c['last_error']}" if c.get("last_error") else ""
        return f"  {name}: NOT CONNECTED{error}"
    fps = _num(c.get("fps"))
    extra = [f"{fps:.1f} fps" if fps is not None else "fps ?"]
    for key in ("dropped", "reconnects"):
        if _num(c.get(key)):
            extra.append(f"{key} {int(c[key])}")
    return f"  {name}: connected, {', '.join(extra)}"


def _mute(m: dict) -> str:
    kind = "warning zone" if m.get("as") == "warning" else str(m.get("as") or "off")
    scale = _num(m.get("speed_scale"))
    if scale is not None:
        kind += f" x{scale:.2f}"
    return (f"  {m.get('zone', '?')} as {kind} by {m.get('operator', '?')} until "
            f"{m.get('until') or _wall(m.get('until_wall'))}")


def _commissioned(value: Any) -> str:
    c = _dict(value)
    if not c:
        return "commissioned: unknown (not reported)"
    if c.get("matches") is True:
        by = f" by {c['by']}" if c.get("by") else ""
        key = f" (key {c['key']})" if c.get("key") else ""
        return f"commissioned: yes, checksum {str(c.get('checksum', '?'))[:16]}{by}{key}"
    differs = [str(d) for d in _list(c.get("differs"))]
    reason = c.get("reason") or (f"not commissioned: {', '.join(differs)} differ from the "
                                 "record" if differs else "the configuration differs from the "
                                 "record")
    return f"commissioned: NO ({reason})"


def changed_lines(value: Any) -> list[str]:
    """The objects standing since commissioning (``changed_since_commissioning``): one line
    each, accepted or not; nothing when none stands."""
    out = []
    for o in (o for o in _list(value) if isinstance(o, dict)):
        floor = _list(o.get("floor_m"))
        at = (f"x {_num(floor[0]):.1f} m, y {_num(floor[1]):.1f} m" if len(floor) == 2
              and _num(floor[0]) is not None and _num(floor[1]) is not None
              else f"image box {o.get('box_px', '?')}")
        zones = ", ".join(map(str, _list(o.get("zones")))) or "?"
        if o.get("accepted_by"):
            how = f"accepted by {o['accepted_by']} at {_wall(o.get('accepted_wall'))}"
        elif o.get("protective"):
            how = f"NOT accepted: STOP, resets refused until `{o.get('accept') or '?'}`"
        else:
            how = f"not accepted: `{o.get('accept') or '?'}`"
        out.append(f"cell changed since commissioning: object at {at} in {zones} on "
                   f"{o.get('camera', '?')} ({how})")
    return out


def _detector(value: Any) -> str:
    d = _dict(value)
    if not d:
        return "detector backend: unknown (not reported)"
    agreement = _num(d.get("agreement"))
    agrees = f", agreement {agreement:.3f} with onnxruntime" if agreement is not None else ""
    return (f"detector backend: {d.get('backend', '?')} {d.get('precision', '?')}{agrees} "
            f"({d.get('reason', '?')})")


def status_text(status: dict) -> str:
    """The lines an operator reads of one monitor's status answer (``SafetyBus.status``)."""
    s = _dict(status)
    command = s.get("command") if isinstance(s.get("command"), dict) else None
    role = f", role {s['role']}" if s.get("role") else ""
    signed = "signed" if s.get("signed") is True else "NOT SIGNED"
    lines = [f"monitor {s.get('instance', '?')} (cell {s.get('cell', '?')}{role}), "
             f"boot {str(s.get('boot', '?'))[:8]}, up {duration(_num(s.get('uptime_s')))} "
             f"(since {_wall(s.get('started_wall'))}), commands {signed}"]
    lines += _command_lines(command)
    cameras = [c for c in _list(s.get("cameras")) if isinstance(c, dict)]
    fps, inference = _num(s.get("fps")), _num(s.get("inference_ms"))
    rate = (f" ({fps:.1f} fps" + (f", inference {inference:.1f} ms" if inference is not None
                                  else "") + ")") if fps is not None else ""
    lines.append(f"cameras{rate}:" if cameras else "cameras: none reported yet")
    lines += [_camera(c) for c in cameras]
    mutes = [m for m in _list(s.get("muted")) if isinstance(m, dict)]
    lines.append("muted zones:" if mutes else "muted zones: none")
    lines += [_mute(m) for m in mutes]
    lines.append(_detector(s.get("detector")))
    zones = s.get("zones_file") or "?"
    lines.append(f"zones: {zones}, config hash {s.get('config_hash') or '?'}")
    lines.append(_commissioned(s.get("commissioned")))
    lines += changed_lines(s.get("changed_since_commissioning"))
    reset = _dict(s.get("last_reset"))
    if reset:
        verdict = "accepted" if reset.get("accepted") is True else "refused"
        lines.append(f"last reset: {reset.get('operator', '?')} {verdict} at "
                     f"{_wall(reset.get('wall'))}: {reset.get('message', '')}")
    for warning in _warnings(s):
        lines.append(f"WARNING: {warning}")
    return "\n".join(lines)


def _warnings(s: dict) -> list[str]:
    out = []
    others = _list(s.get("other_monitors"))
    if others:
        out.append(f"other monitors answer for this cell: {', '.join(map(str, others))}")
    if s.get("test_model"):
        out.append(str(s["test_model"]))
    missing = _list(s.get("without_reference"))
    if missing:  # glare and image conditions judged by the envelope's absolute limits only
        out.append(f"no reference image for {', '.join(map(str, missing))}: glare and image "
                   "conditions judged by the model envelope's absolute limits only")
    if s.get("changes_unwatched"):  # no commissioning reference (docs/occlusion.md)
        out.append(str(s["changes_unwatched"]))
    if s.get("warning"):
        out.append(str(s["warning"]))
    if s.get("protective_zone") is False and not s.get("warning"):
        out.append("no enabled protective zone: no person can cause a STOP")
    return out
