"""Password guessing against the console (issues 31 and 48). A real uvicorn on 127.0.0.1 serving
the real app with the console's own server options, real HTTP clients (httpx), the real scrypt
passwords file: wrong passwords are throttled per account and per source with delays that grow
(never a hard lock), no other login clears a count, a forged ``X-Forwarded-For`` changes
neither the throttle nor the audit, a user whose name is under attack still logs in from a
clean source, a full table keeps the count of the name under attack, one user's logins never
log another out, and ``/api/state`` stays responsive while passwords are checked."""

from __future__ import annotations

import json
import statistics
import threading
import time

import httpx
import pytest

from monitor.console.app import THROTTLE_ALERT
from monitor.console.auth import set_password
from monitor.console.logins import LoginGuard, LoginLimits
from monitor.console.sessions import Sessions
from monitor.console.sources import Source, TrustedProxies, source_key
from monitor.errors import ConfigError
from tests.console_kit import OPERATOR, PASSWORD, basic, make_console, serving

SQUARE = [[900, 150], [1200, 150], [1200, 400], [900, 400]]
GUESSERS = 16  # at once: with scrypt on the event loop, a state request waited for them all
BODY = {"camera": "cam0", "kind": "protective", "points_px": SQUARE}
OTHER_PASSWORD = "another long password"


class Clock:
    def __init__(self) -> None:
        self.now = 5000.0

    def __call__(self) -> float:
        return self.now


def _audit(tmp_path) -> list[dict]:
    return [json.loads(line) for line in (tmp_path / "audit.jsonl").read_text().splitlines()]


def _add_user(tmp_path, name: str, level: str) -> None:
    set_password(tmp_path / "console.passwords", name, OTHER_PASSWORD, level)


def test_wrong_passwords_are_throttled_with_delays_that_grow_never_a_lock(tmp_path):
    clock = Clock()
    alerts = []
    limits = LoginLimits()
    console = make_console(tmp_path, logins=LoginGuard(limits, clock), on_alert=alerts.append)
    cell = tmp_path / "cell.yaml"
    before = cell.read_bytes()
    with serving(console) as url, httpx.Client(base_url=url, timeout=30.0) as http:
        codes = [http.put("/api/zones/aisle", json=BODY,
                          headers=basic(OPERATOR, f"guess {k}")).status_code
                 for k in range(50)]
        # the free allowance, then every try before the delay ends is answered at once and
        # counts nothing (the clock stands still here)
        assert codes == [401] * limits.user_free + [429] * (50 - limits.user_free)
        r = http.put("/api/zones/aisle", json=BODY, headers=basic(OPERATOR, PASSWORD))
        assert r.status_code == 429 and r.headers["retry-after"]
        assert r.json()["error"] == (f"operator '{OPERATOR}': 3 wrong passwords within 900 s: "
                                     "the next try is accepted in 1 s")
        assert cell.read_bytes() == before
        clock.now += 1.01  # the delay is over: one more guess, and the next delay is longer
        assert http.put("/api/zones/aisle", json=BODY,
                        headers=basic(OPERATOR, "guess 4")).status_code == 401
        clock.now += 1.01
        r = http.put("/api/zones/aisle", json=BODY, headers=basic(OPERATOR, PASSWORD))
        assert r.status_code == 429 and "4 wrong passwords" in r.json()["error"]
        clock.now += 1.0  # 2 s after the 4th: the right password is accepted
        r = http.put("/api/zones/aisle", json=BODY, headers=basic(OPERATOR, PASSWORD))
        assert r.status_code == 200, r.text
        assert http.get("/api/state").status_code == 200  # reading was never held
    assert [a.kind for a in alerts] == [THROTTLE_ALERT]  # one alert, when the delays began
    assert f"operator '{OPERATOR}': 3 wrong passwords" in alerts[0].message
    audit = _audit(tmp_path)
    assert [e["client"] for e in audit if e["event"] == "login_throttled"] == ["127.0.0.1"]
    assert all(PASSWORD not in json.dumps(e) and "guess" not in json.dumps(e) for e in audit)
    assert audit[-1]["result"] == "saved"


def test_delays_grow_to_their_bound_and_never_beyond():
    clock = Clock()
    limits = LoginLimits()
    guard = LoginGuard(limits, clock)
    for _ in range(40):  # a patient guesser: one guess each time the delay ends
        waiting = guard.waiting("10.0.0.66", OPERATOR)
        if waiting is not None:
            clock.now += waiting.seconds_left + 0.01
        assert guard.waiting("10.0.0.66", OPERATOR) is None
        guard.failed("10.0.0.66", OPERATOR)
    waiting = guard.waiting("10.0.0.66", OPERATOR)
    assert waiting is not None and waiting.seconds_left == limits.max_delay_s
    assert guard.failures(name=OPERATOR) == 15  # 60 s apart: 15 within the 900 s window
    clock.now += limits.window_s + 1  # the window passes: every count is gone
    assert guard.waiting("10.0.0.66", OPERATOR) is None
    assert guard.failures(name=OPERATOR) == guard.failures(source="10.0.0.66") == 0


def test_guesses_at_many_names_throttle_the_source(tmp_path):
    clock = Clock()
    limits = LoginLimits()
    console = make_console(tmp_path, logins=LoginGuard(limits, clock))
    with serving(console) as url, httpx.Client(base_url=url, timeout=30.0) as http:
        codes = [http.put("/api/zones/aisle", json=BODY,
                          headers=basic(f"name{k}", PASSWORD)).status_code
                 for k in range(limits.client_free + 5)]
        assert codes == [401] * limits.client_free + [429] * 5
        r = http.put("/api/zones/aisle", json=BODY, headers=basic(OPERATOR, PASSWORD))
        assert r.status_code == 429 and "client loopback: 5 wrong" in r.json()["error"]
        clock.now += limits.first_delay_s + 0.01
        r = http.put("/api/zones/aisle", json=BODY, headers=basic(OPERATOR, PASSWORD))
        assert r.status_code == 200, r.text


def test_forwarded_headers_from_an_untrusted_client_change_neither_throttle_nor_audit(tmp_path):
    """Issue 48: uvicorn believed X-Forwarded-For from 127.0.0.1, so each guess chose a new
    address (never throttled) and the audit named the forged one."""
    clock = Clock()
    limits = LoginLimits()
    console = make_console(tmp_path, logins=LoginGuard(limits, clock))
    with serving(console) as url, httpx.Client(base_url=url, timeout=30.0) as http:
        codes = []
        for k in range(limits.client_free + 3):
            forged = {"x-forwarded-for": f"10.9.0.{k + 1}", **basic(f"name{k}", "wrong")}
            codes.append(http.put("/api/zones/aisle", json=BODY, headers=forged).status_code)
        assert codes == [401] * limits.client_free + [429] * 3
        r = http.post("/api/login", headers={"x-forwarded-for": "10.9.9.9",
                                             **basic(OPERATOR, PASSWORD)})
        assert r.status_code == 429 and "client loopback" in r.json()["error"]
    audit = _audit(tmp_path)
    refused = [e for e in audit if e.get("result") == "refused"]
    assert refused and {e["client"] for e in refused} == {"127.0.0.1"}
    assert "10.9." not in json.dumps(audit) and not any("forwarded_for" in e for e in audit)


def test_a_viewer_under_attack_logs_in_from_a_clean_source_behind_a_trusted_proxy(tmp_path):
    """Issue 48: 5 wrong passwords kept a named user from even viewing, renewable for ever.
    Through a trusted proxy (127.0.0.1 here) the attacker is 10.0.0.66, the viewer at her desk
    10.0.0.7; the audit keeps the peer and the proxy's word apart."""
    _add_user(tmp_path, "vera", "viewer")
    clock = Clock()
    limits = LoginLimits()
    console = make_console(tmp_path, logins=LoginGuard(limits, clock),
                           trusted_proxies=TrustedProxies(["127.0.0.1"]))
    attacker = {"x-forwarded-for": "203.0.113.5, 10.0.0.66"}  # its own entry: not believed
    with serving(console) as url, httpx.Client(base_url=url, timeout=30.0) as http:
        guesses = 0
        while guesses < 12:  # a patient attacker: every time the delay ends, one more guess
            r = http.post("/api/login", headers={**attacker, **basic("vera", f"g{guesses}")})
            if r.status_code == 429:
                clock.now += 60.0
                continue
            assert r.status_code == 401
            guesses += 1
        r = http.post("/api/login", headers={**attacker, **basic("vera", OTHER_PASSWORD)})
        assert r.status_code == 429 and "12 wrong passwords" in r.json()["error"]
        r = http.post("/api/login", headers={"x-forwarded-for": "10.0.0.7",
                                             **basic("vera", OTHER_PASSWORD)})
        assert r.status_code == 200, r.text
        assert http.get("/api/me").json()["name"] == "vera"
    audit = _audit(tmp_path)
    login = [e for e in audit if e["event"] == "login"]
    assert [(e["client"], e["forwarded_for"]) for e in login] == [("127.0.0.1", "10.0.0.7")]
    throttled = [e for e in audit if e["event"] == "login_throttled"]
    assert throttled and all(e["client"] == "127.0.0.1" and e["forwarded_for"] == "10.0.0.66"
                             for e in throttled)
    assert "203.0.113.5" not in json.dumps(audit)


def test_guesses_at_one_account_are_throttled_whatever_other_account_logs_in(tmp_path):
    """Issue 48: the attacker's own right password cleared its address's count (24 guesses at
    another account, no lock-out)."""
    _add_user(tmp_path, "mal", "viewer")
    clock = Clock()
    limits = LoginLimits()
    console = make_console(tmp_path, logins=LoginGuard(limits, clock))
    with serving(console) as url, httpx.Client(base_url=url, timeout=30.0) as http:
        def own_login() -> None:
            assert http.post("/api/login", headers=basic("mal", OTHER_PASSWORD)).status_code \
                == 200

        codes = []
        for k in range(limits.user_free + 2):
            own_login()
            codes.append(http.put("/api/zones/aisle", json=BODY,
                                  headers=basic(OPERATOR, f"guess {k}")).status_code)
        assert codes == [401] * limits.user_free + [429] * 2
        clock.now += limits.window_s + 1  # a fresh start: now one guess at each of many names
        codes = []
        for k in range(limits.client_free + 2):
            if k < limits.client_free:  # then the source is held: its own login too
                own_login()
            codes.append(http.put("/api/zones/aisle", json=BODY,
                                  headers=basic(f"name{k}", "wrong")).status_code)
        assert codes == [401] * limits.client_free + [429] * 2
        r = http.post("/api/login", headers=basic("mal", OTHER_PASSWORD))
        assert r.status_code == 429 and "client loopback" in r.json()["error"]


def test_filling_the_table_does_not_reset_a_count():
    """Issue 48: 14k cheap requests filled the 4,096-entry table and the admin's count was
    pushed out (12 wrong guesses, then his password accepted)."""
    clock = Clock()
    limits = LoginLimits()
    guard = LoginGuard(limits, clock)
    for k in range(12):  # three sources of the attacker, four guesses each
        guard.failed(f"10.0.1.{k % 3}", "admin")
        clock.now += 0.01
    for k in range(3 * limits.max_tracked):  # then one guess from each of many new sources
        guard.failed(f"10.{1 + k // 65536}.{k // 256 % 256}.{k % 256}", f"n{k}")
    assert len(guard) <= limits.max_tracked
    assert guard.failures(name="admin") == 12 and guard.failures(source="10.0.1.0") == 4
    waiting = guard.waiting("10.0.1.0", "admin")
    assert waiting is not None and waiting.who == "operator 'admin'"
    assert waiting.seconds_left > 50  # 12 wrong passwords: the longest delay
    assert guard.waiting("10.200.0.1", "admin") is None  # a clean source is not held


def test_one_user_logging_in_again_and_again_logs_nobody_else_out():
    sessions = Sessions(clock=lambda: 100.0)
    ada = sessions.open("ada")
    tokens = [sessions.open("vera") for _ in range(1100)]
    assert sessions.name(ada) == "ada"
    alive = [t for t in tokens if sessions.name(t) == "vera"]
    assert alive == tokens[-sessions.max_per_user:]  # her newest ones
    assert len(sessions) == sessions.max_per_user + 1


def test_sources_behind_proxies_and_their_keys():
    proxies = TrustedProxies(["127.0.0.1", "10.1.0.0/16"])
    assert proxies.source("127.0.0.1", ["1.2.3.4, 198.51.100.9, 10.1.2.3"]) == \
        Source("127.0.0.1", "198.51.100.9")  # the proxies' own hops skipped, from the end
    assert proxies.source("127.0.0.2", ["198.51.100.9"]) == Source("127.0.0.2")  # untrusted
    assert proxies.source("127.0.0.1", []) == Source("127.0.0.1")
    assert proxies.source("127.0.0.1", ["junk, 198.51.100.9"]).forwarded == "198.51.100.9"
    assert proxies.source("127.0.0.1", ["198.51.100.9, junk"]).forwarded is None
    assert TrustedProxies().source("127.0.0.1", ["198.51.100.9"]) == Source("127.0.0.1")
    assert source_key("127.0.0.1") == source_key("127.3.4.5") == "loopback"
    assert source_key("::ffff:127.0.0.1") == "loopback" and source_key("::1") == "loopback"
    assert source_key("2001:db8::1") == source_key("2001:db8::ffff") == "2001:db8::/64"
    assert source_key("192.0.2.7") == "192.0.2.7"
    with pytest.raises(ConfigError, match=r"--trusted-proxy 'proxy\.lan': not an IP address"):
        TrustedProxies(["proxy.lan"])


def test_state_stays_responsive_while_100_passwords_are_checked(tmp_path):
    """No throttle here (limits out of reach): every one of the 100 guesses costs a scrypt,
    sixteen at a time. The loose bound (1 s) is for a loaded CI machine; the issue's 100 ms target
    is measured by benchmarks/console_logins.py."""
    never = LoginLimits(user_free=10**6, client_free=10**6)
    console = make_console(tmp_path, logins=LoginGuard(never))
    latencies: list[float] = []
    guessed: list[int] = []
    with serving(console) as url:
        done = threading.Event()

        def guess(offset: int) -> None:
            with httpx.Client(base_url=url, timeout=60.0) as http:
                for k in range(offset, 100, GUESSERS):
                    r = http.put("/api/zones/aisle", json=BODY,
                                 headers=basic(OPERATOR, f"wrong {k}"))
                    guessed.append(r.status_code)

        guessers = [threading.Thread(target=guess, args=(j,)) for j in range(GUESSERS)]
        for t in guessers:
            t.start()

        def watch() -> None:
            for t in guessers:
                t.join(300.0)
            done.set()

        threading.Thread(target=watch, daemon=True).start()
        with httpx.Client(base_url=url, timeout=30.0) as http:
            while not done.is_set():
                started = time.perf_counter()
                assert http.get("/api/state").status_code == 200
                latencies.append(time.perf_counter() - started)
                time.sleep(0.05)
    assert sorted(set(guessed)) == [401] and len(guessed) == 100, guessed
    assert len(latencies) >= 10
    print(f"/api/state during 100 password checks: n={len(latencies)} "
          f"median={statistics.median(latencies) * 1000:.1f} ms "
          f"max={max(latencies) * 1000:.1f} ms")
    assert max(latencies) < 1.0
