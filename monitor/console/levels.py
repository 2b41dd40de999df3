"""User levels of the console: who may do what (pure functions, no I/O).

Three levels, each including the one below (issue 32; compare the user levels of a safety
configurator such as SICK Safety Designer):

* ``viewer``: may look (the pages and every ``GET``), nothing else. Viewing needs a login only
  when the console listens off loopback (``view_login``: TLS and passwords are required there
  anyway); on loopback the pages stay open as before (whoever can reach 127.0.0.1 can read the
  zone file and the recorder's files too).
* ``operator``: may also edit the image polygons of the zone file (drafts): what a password
  holder could do before levels existed; and confirm the cell clear after looking at the
  fresh live pictures (``monitor/console/confirm_clear.py``), or send a plain reset (which the
  monitor accepts only when it sees the cell clear), each signed with that operator's own
  reset key, which the console holds only when started with ``--reset-key NAME=FILE``. A
  passwords-file line without a level (the format before levels, ``name:scrypt$...``) is an
  operator: an upgrade takes no right away.
* ``admin``: may also change the cell's setup: a zone's mute setting (who may mute it, for how
  long, as what), the zone sets' switching rules, and the corners of cell-space volumes.
  Why these need more than an operator: a mute setting decides who may switch protection off,
  and a volume or a set rule changes where and when protection applies for every camera at
  once; a polygon edit changes one camera's view of one zone.

No level grants a mute, a zone set selection or an apply, and the reset and confirm-clear are
not granted by the level alone: those stay with the signed requests of the monitor's operators
file (Ed25519 keys, ``bus.operators_file``), the one source
of truth for who may reset. The console only shows that file (names and key fingerprints,
read-only; ``monitor/console/resetters.py``), and every saved edit stays a draft on disk until an
operator applies it with ``monitor zones apply`` (signed).

``may(level, action)`` answers; ``refusal(name, level, action)`` is the one-line reason of a 403
naming the level needed.
"""

from __future__ import annotations

LEVELS = ("viewer", "operator", "admin")  # each includes the rights of those before it
DEFAULT_LEVEL = "operator"  # a line without a level (the format before levels)

# action -> (the lowest level allowed, what it is in a sentence)
ACTIONS: dict[str, tuple[str, str]] = {
    "view": ("viewer", "view the console"),
    "edit_zone": ("operator", "edit zone polygons"),
    "mark_reviewed": ("operator", "mark an incident reviewed"),
    "confirm_clear": ("operator", "confirm the cell clear after looking at the live picture"),
    "reset": ("operator", "reset the monitor"),
    "edit_mute": ("admin", "change a zone's mute setting"),
    "edit_sets": ("admin", "change the zone sets' switching rules"),
    "edit_volume": ("admin", "change a cell-space volume"),
}
# asked for by no level: only the signed requests of the monitor's operators file do these
NEVER = {
    "apply": "apply the zone file to the running monitor (signed: monitor zones apply)",
    "mute": "mute a zone (signed: monitor mute)",
    "select_set": "select a zone set (signed: monitor case select)",
}


class LevelError(ValueError):
    """Not one of ``LEVELS`` (one line)."""


def parse_level(text: str) -> str:
    """``text`` as a level; ``admin``'s spelling ``administrator`` is accepted."""
    level = "admin" if text == "administrator" else text
    if level not in LEVELS:
        shown = text if len(text) <= 24 else f"{text[:20]}... ({len(text)} characters)"
        raise LevelError(f"level {shown!r}: one of {', '.join(LEVELS)}")
    return level


def rank(level: str) -> int:
    """0 viewer, 1 operator, 2 admin; -1 for anything else (it may do nothing)."""
    return LEVELS.index(level) if level in LEVELS else -1


def may(level: str | None, action: str) -> bool:
    """Whether ``level`` may do ``action``. Unknown levels and unknown actions: never."""
    if level is None or action not in ACTIONS:
        return False
    return rank(level) >= rank(ACTIONS[action][0])


def needed(action: str) -> str | None:
    """The lowest level allowed to do ``action`` (None: no level of the console may)."""
    return ACTIONS[action][0] if action in ACTIONS else None


def refusal(name: str, level: str | None, action: str) -> str | None:
    """The one-line reason ``name`` (at ``level``) may not do ``action``; None when allowed."""
    if may(level, action):
        return None
    if action in NEVER:
        return (f"no console user may {NEVER[action]}: the console never grants that, the "
                "monitor's operators file does")
    if action not in ACTIONS:
        return f"unknown action {action!r}"
    low = ACTIONS[action][0]
    higher = LEVELS[rank(low):]
    return (f"{level or 'no level'} {name!r} may not {ACTIONS[action][1]}: it needs the "
            f"{' or '.join(higher)} level")


def table() -> list[dict]:
    """The rights for the setup page: each action, its sentence and the levels allowed."""
    rows = [{"action": a, "what": what, "levels": [lv for lv in LEVELS if may(lv, a)]}
            for a, (_, what) in ACTIONS.items()]
    rows += [{"action": a, "what": what, "levels": []} for a, what in NEVER.items()]
    return rows
