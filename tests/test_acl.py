"""The shipped secure router configs grant each role exactly what it needs, for every key the
monitor uses (the keys come from ``BusKeys``, not from a list here): checked through a real
Zenoh router started from deploy/zenoh/router-secure.json5 and router-cell.json5 on 127.0.0.1,
with one TLS client per user. A zone set selection signed by a selector is answered and
applied through it (docs/cases.md, docs/security.md)."""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import pytest
import zenoh

from monitor.bus.session import BusConfig, BusKeys, SafetyBus, open_session
from monitor.cases import sets as cs
from monitor.cases.receiver import CaseReceiver, request_case
from monitor.cases.requests import case_payload
from monitor.wire.signing import load_private_key, new_key_pair
from tests.helpers import free_port, put_until, wait_for
from tests.tls import secure_router

DEPLOY = Path(__file__).resolve().parents[1] / "deploy" / "zenoh"
USERS = {"monitor": "m-pw", "operator1": "o-pw", "robot": "r-pw", "otus-bridge": "b-pw",
         "viewer": "v-pw", "rogue": "x-pw", "listener": "l-pw"}
LISTENER = "listener"  # only listens: a session's own puts reach its own subscriber directly

# BusKeys field -> (users who may put on it, users who may query it, users who may answer it)
# "*" = every authenticated user. A key the code adds without a line here fails the test.
ACCESS = {
    "command": ({"monitor"}, set(), set()),
    "alert": ({"monitor", "otus-bridge"}, set(), set()),  # the bridge: the cell's key only
    "detections": ({"monitor"}, set(), set()),
    "holds": ({"monitor"}, set(), set()),
    "preview": ({"monitor"}, set(), set()),  # the console's live pictures (monitor.bus.preview)
    "pose": ({"otus-bridge"}, set(), set()),
    "status": (set(), {"*"}, {"monitor"}),
    "reset": ({"operator1"}, {"operator1"}, {"monitor"}),
    "mute": (set(), {"operator1"}, {"monitor"}),
    "zones_apply": (set(), {"operator1"}, {"monitor"}),
    "objects_accept": (set(), {"operator1"}, {"monitor"}),
    "case": ({"robot"}, {"robot"}, {"monitor"}),
    "alive": (set(), set(), set()),  # liveliness tokens: checked on their own
}
NOT_KEYS = {"role"}


def _allowed(who: set[str], user: str) -> bool:
    return "*" in who or user in who


def _writers(name: str, role: str) -> set[str]:
    # the tracker bridge alerts on the cell's alert key, never in a monitor role's name
    return ACCESS[name][0] - ({"otus-bridge"} if role and name == "alert" else set())


@pytest.fixture(scope="module", params=["router-secure.json5", "router-cell.json5"])
def cell(request, tmp_path_factory):
    """A router from the shipped config and one TLS client session per user."""
    tmp = tmp_path_factory.mktemp("acl")
    port = free_port()
    conf, tls = secure_router(tmp, DEPLOY / request.param, USERS, port)

    def client(user: str, **kw) -> BusConfig:
        return BusConfig(cell="cell1", mode="client", instance=user.replace("-", ""),
                         zenoh_config_file=str(DEPLOY / "client-secure.json5"),
                         connect=(f"tls/localhost:{port}",), tls_root_ca=str(tls["ca"]),
                         user=user, password=USERS[user], **kw)

    with zenoh.open(conf) as router:
        sessions = {u: open_session(client(u)) for u in USERS}
        try:
            yield {"router": router, "sessions": sessions, "client": client, "tmp": tmp}
        finally:
            for s in sessions.values():
                s.close()


def test_every_key_of_busKeys_has_its_access_written_down():
    fields = {f.name for f in dataclasses.fields(BusKeys)} - NOT_KEYS
    assert fields == set(ACCESS), f"keys without access rules: {fields ^ set(ACCESS)}"


@pytest.mark.parametrize("role", ["", "monitor-a"])
def test_only_the_listed_users_put_on_each_key(cell, role):
    keys = BusKeys.of("workcell/cell1/", role)
    s = cell["sessions"]
    seen: set[tuple[str, str]] = set()
    sub = s[LISTENER].declare_subscriber("workcell/cell1/**", lambda x: seen.add(
        (str(x.key_expr), x.payload.to_bytes().decode())))
    try:
        puts = [(name, getattr(keys, name)) for name, (writers, _, _) in ACCESS.items()
                if name != "alive"]
        # the denied first: by the time the allowed ones arrived, the denied ones had their turn
        order = sorted(((n, k, u) for n, k in puts for u in USERS if u != LISTENER),
                       key=lambda t: _allowed(_writers(t[0], role), t[2]))
        expected = {(k, u) for n, k, u in order if _allowed(_writers(n, role), u)}

        def put_round() -> None:
            for _name, key, user in order:
                s[user].put(key, user)
        put_until(put_round, lambda: expected <= seen,
                  what=lambda: f"allowed puts that never arrived: {sorted(expected - seen)}")
        put_round()
        time.sleep(0.3)  # the denied ones had longer than the allowed ones to arrive
        mine = {(k, u) for k, u in seen if k in dict(puts).values()}
        assert mine == expected, f"puts the ACL let through: {sorted(mine - expected)}"
    finally:
        sub.undeclare()


@pytest.mark.parametrize("role", ["", "monitor-a"])
def test_only_the_monitor_answers_and_only_the_listed_users_ask(cell, role):
    keys = BusKeys.of("workcell/cell1/", role)
    s = cell["sessions"]
    asked = [(n, getattr(keys, n)) for n, (_, q, _) in ACCESS.items() if q]
    # the monitor and a rogue answer every queried key; the monitor also asks, from a second
    # session (its own queryables would answer it without the router)
    monitor2 = open_session(cell["client"]("monitor"))
    entities = [sess.declare_queryable(key, lambda q, who=who: q.reply(q.key_expr, who))
                for _, key in asked for sess, who in ((s["monitor"], "monitor"),
                                                       (s["rogue"], "rogue"))]
    try:
        askers = {**{u: s[u] for u in USERS if u not in ("monitor", "rogue")},
                  "monitor": monitor2}
        def ask(key: str, sess: zenoh.Session) -> set[str]:
            return {r.ok.payload.to_bytes().decode()
                    for r in sess.get(key, timeout=3.0,
                                      consolidation=zenoh.ConsolidationMode.NONE)
                    if r.ok is not None}
        # the queryables reach the router a moment after they are declared (longer on a loaded
        # host): wait until the operator's status query is answered before judging anyone
        wait_for(lambda: ask(keys.status, s["operator1"]), what="the monitor's status answer")
        for name, key in asked:
            _, queriers, answerers = ACCESS[name]
            for user, sess in askers.items():
                want = answerers if _allowed(queriers, user) else set()
                got = ask(key, sess)
                for _ in range(3):  # a late declaration can only lose answers, never add one
                    if got >= want:
                        break
                    got |= ask(key, sess)
                assert got == want, f"{user} asking {name}: answered by {got or 'nobody'}, " \
                                    f"expected {want or 'nobody'}"
    finally:
        for e in entities:
            e.undeclare()
        monitor2.close()


def test_only_the_monitor_holds_liveliness_tokens(cell):
    s = cell["sessions"]
    alive = BusKeys.of("workcell/cell1/").alive
    tokens = [s["monitor"].liveliness().declare_token(f"{alive}/mon"),
              s["rogue"].liveliness().declare_token(f"{alive}/rogue"),
              s["robot"].liveliness().declare_token(f"{alive}/robot")]
    try:
        def seen():
            return {str(r.ok.key_expr) for r in s["viewer"].liveliness().get(
                f"{alive}/**", timeout=2.0) if r.ok is not None}
        assert wait_for(lambda: f"{alive}/mon" in seen(), timeout=20)
        assert seen() == {f"{alive}/mon"}
    finally:
        for t in tokens:
            t.undeclare()


def test_a_signed_selection_through_the_secure_router_is_answered_and_applied(cell):
    tmp = cell["tmp"]
    private, _, public = new_key_pair(tmp / f"robot-{time.monotonic_ns()}.key")
    selectors = tmp / "selectors"
    selectors.write_text(f"robot {public}\n")
    plan = cs.CasePlan((cs.ZoneSet("A", frozenset({"za"})), cs.ZoneSet("B", frozenset({"zb"}))),
                       "A")
    key = BusKeys.of("workcell/cell1/").case
    signer = load_private_key(private)
    robot, viewer = cell["sessions"]["robot"], cell["sessions"]["viewer"]
    with SafetyBus(cell["client"]("monitor", selectors_file=str(selectors)),
                   startup_check_s=0.2) as bus, \
            CaseReceiver.for_bus(bus.session, bus.config, plan) as receiver:
        body = case_payload("robot", "B", 1, cell="cell1")
        answer = wait_for(lambda: request_case(robot, key, body, signer.sign(key, body), 3.0),
                          timeout=20)
        assert answer["accepted"] and answer["set"] == "B", answer
        events = receiver.poll()
        state = cs.apply_events(plan, cs.initial_case(plan, 0.0), events, 1.0)
        assert state.selected == "B" and state.applied == ("A", "B")  # switching over
        # the right signature from a user who is no selector: the router drops it
        late = case_payload("robot", "A", 2, cell="cell1")
        assert request_case(viewer, key, late, signer.sign(key, late), 1.0) is None
        # an unsigned one from the selector's user: refused, and nothing changes
        answer = request_case(robot, key, case_payload("robot", "A", 3, cell="cell1"), None,
                              3.0)
        assert answer is not None and not answer["accepted"] and "unsigned" in answer["reason"]
        assert receiver.poll() == ()
        assert receiver.refused == 1 and receiver.accepted == 1
