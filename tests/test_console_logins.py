"""Issue 31, part 2: password guessing against the console. A real uvicorn on 127.0.0.1 serving
the real app, real HTTP clients (httpx), the real scrypt passwords file: 100 wrong passwords
lock the operator out (then even the right password is refused, with the seconds left, until
the lock-out ends) and raise one alert; guesses from one client at many names lock the client;
``/api/state`` stays responsive while passwords are checked (scrypt runs off the event loop)."""

from __future__ import annotations

import json
import statistics
import threading
import time

import httpx

from monitor.console.app import LOCKOUT_ALERT
from monitor.console.logins import LoginGuard, LoginLimits
from tests.console_kit import OPERATOR, PASSWORD, basic, make_console, serving

SQUARE = [[900, 150], [1200, 150], [1200, 400], [900, 400]]
GUESSERS = 16  # at once: with scrypt on the event loop, a state request waited for them all
BODY = {"camera": "cam0", "kind": "protective", "points_px": SQUARE}


class Clock:
    def __init__(self) -> None:
        self.now = 5000.0

    def __call__(self) -> float:
        return self.now


def test_100_wrong_passwords_lock_the_operator_out_until_the_lockout_ends(tmp_path):
    clock = Clock()
    alerts = []
    limits = LoginLimits()
    console = make_console(tmp_path, logins=LoginGuard(limits, clock), on_alert=alerts.append)
    cell = tmp_path / "cell.yaml"
    before = cell.read_bytes()
    with serving(console) as url, httpx.Client(base_url=url, timeout=30.0) as http:
        codes = []
        for k in range(100):
            r = http.put("/api/zones/aisle", json=BODY, headers=basic(OPERATOR, f"guess {k}"))
            codes.append(r.status_code)
        assert codes == [401] * (limits.user_failures - 1) + [429] * (101 - limits.user_failures)
        assert r.headers["retry-after"]
        # the right password is refused too, with a message that says why and for how long
        r = http.put("/api/zones/aisle", json=BODY, headers=basic(OPERATOR, PASSWORD))
        assert r.status_code == 429
        assert r.json()["error"] == (f"operator '{OPERATOR}' is locked out for 300 s more after "
                                     "5 wrong passwords within 300 s; even the right password "
                                     "is refused until then")
        assert cell.read_bytes() == before
        clock.now += limits.lockout_s - 1
        r = http.put("/api/zones/aisle", json=BODY, headers=basic(OPERATOR, PASSWORD))
        assert r.status_code == 429 and "for 1 s more" in r.json()["error"]
        clock.now += 1.5  # the lock-out has ended
        r = http.put("/api/zones/aisle", json=BODY, headers=basic(OPERATOR, PASSWORD))
        assert r.status_code == 200, r.text
        # reading never needed a login and was never locked
        assert http.get("/api/state").status_code == 200
    assert [a.kind for a in alerts] == [LOCKOUT_ALERT]  # one alert, for the one lock-out
    assert f"operator '{OPERATOR}' is locked out" in alerts[0].message
    audit = [json.loads(line) for line in (tmp_path / "audit.jsonl").read_text().splitlines()]
    assert [e["client"] for e in audit if e["event"] == "login_lockout"] == ["127.0.0.1"]
    assert all(PASSWORD not in json.dumps(e) and "guess" not in json.dumps(e) for e in audit)
    assert audit[-1]["result"] == "saved"


def test_guesses_at_many_names_lock_the_client_out(tmp_path):
    clock = Clock()
    limits = LoginLimits()
    console = make_console(tmp_path, logins=LoginGuard(limits, clock))
    with serving(console) as url, httpx.Client(base_url=url, timeout=30.0) as http:
        codes = [http.put("/api/zones/aisle", json=BODY,
                          headers=basic(f"name{k}", PASSWORD)).status_code
                 for k in range(limits.client_failures + 5)]
        assert codes == [401] * (limits.client_failures - 1) + [429] * 6
        r = http.put("/api/zones/aisle", json=BODY, headers=basic(OPERATOR, PASSWORD))
        assert r.status_code == 429 and "client 127.0.0.1 is locked out" in r.json()["error"]
        clock.now += limits.lockout_s + 0.5
        r = http.put("/api/zones/aisle", json=BODY, headers=basic(OPERATOR, PASSWORD))
        assert r.status_code == 200, r.text


def test_state_stays_responsive_while_100_passwords_are_checked(tmp_path):
    """No lock-out here (limits out of reach): every one of the 100 guesses costs a scrypt,
    sixteen at a time. The loose bound (1 s) is for a loaded CI machine; the issue's 100 ms target
    is measured by benchmarks/console_logins.py."""
    never = LoginLimits(user_failures=10**6, client_failures=10**6)
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
