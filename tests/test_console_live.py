"""The live picture (monitor/bus/preview.py, docs/console.md "The live picture"): the monitor's
preview sink never waits (a publisher that hangs costs the loop nothing but the offer), its
pictures are signed, scaled down and at most ``fps`` per camera on a real Zenoh bus; the
console shows only a picture signed with the pinned key; and, end to end, a real `monitor run`
with a real `monitor console` shows a moving live picture in a real headless chromium."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time

import cv2
import numpy as np
import pytest

from monitor.bus.preview import PreviewConfig, PreviewSink, read_preview, start_preview
from monitor.bus.session import BusConfig, SafetyBus, open_session
from monitor.console.live import NO_LIVE_BAR_PX, LiveRenderer, LiveState, subscribe_live
from monitor.frames import Frame
from monitor.types import Alert, FrameInfo
from monitor.wire.alerts import alert_to_dict, read_signed_alert, signed_attachment
from monitor.wire.signing import load_private_key, load_public_key, new_key_pair
from monitor.zones import load_cell
from tests.console_kit import CHROMIUM, ROOT, chromium, wait_http, zone_file
from tests.helpers import free_port, wait_for


def frame(camera: str, seq: int, t: float, colour=(200, 40, 40)) -> Frame:
    img = np.full((720, 1280, 3), colour, np.uint8)
    return Frame(img, FrameInfo(camera, seq, t, 1280, 720))


def test_the_loop_never_waits_for_a_stuck_preview():
    """The publisher hangs (a blocked link): every offer still returns, each camera keeps one
    picture (the newest), and the rate is ``fps`` per camera by the frames' capture times."""
    release, entered = threading.Event(), threading.Event()
    sent: list[bytes] = []

    def put(payload: bytes, signature: bytes | None) -> None:
        entered.set()
        release.wait(60)
        sent.append(payload)

    sink = PreviewSink(PreviewConfig(fps=2.0), put, "workcell/t/safety/preview",
                       lambda: {"cell": "t"})
    try:
        assert sink.offer(frame("cam0", 0, 0.0))
        wait_for(entered.is_set, what="the worker's first publication")
        taken: list[bool] = []
        # 10 s of 15 fps on two cameras while the worker is stuck in put(): all in a thread,
        # so a waiting offer fails the test instead of hanging it
        offers = threading.Thread(target=lambda: taken.extend(
            sink.offer(frame(cam, k, k / 15)) for k in range(1, 150) for cam in ("cam0", "cam1")))
        offers.start()
        offers.join(30)
        assert not offers.is_alive(), "an offer waited for the stuck publisher"
        # at most one picture in 0.5 s per camera: every 8th frame of 15 fps; cam0 from
        # frame 8 (8, 16, ... 144: 18), cam1 from its first (1, 9, ... 145: 19)
        assert sum(taken) == 18 + 19
        assert sink.counts["replaced"] == 17 + 18  # one slot per camera: newest wins
        release.set()
        wait_for(lambda: len(sent) == 3, what="the first picture and one per camera")
        newest = {json.loads(p)["camera"]: json.loads(p)["frame_seq"] for p in sent[1:]}
        assert newest == {"cam0": 144, "cam1": 145}
    finally:
        release.set()
        sink.close()


@pytest.fixture(scope="module")
def signed_bus(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("preview")
    private, public, _ = new_key_pair(tmp / "monitor.key")
    _, other, _ = new_key_pair(tmp / "other.key")
    port = free_port()
    cfg = BusConfig(cell="pv", instance="mon-pv", listen=(f"tcp/127.0.0.1:{port}",),
                    signing_key=str(private))
    with SafetyBus(cfg) as bus, open_session(BusConfig(
            cell="pv", instance="viewer", connect=(f"tcp/127.0.0.1:{port}",))) as viewer:
        yield {"bus": bus, "viewer": viewer, "public": load_public_key(public),
               "other": load_public_key(other)}


def test_pictures_are_signed_scaled_and_shown_only_with_the_pinned_key(signed_bus):
    bus, viewer = signed_bus["bus"], signed_bus["viewer"]
    got: list[tuple[bytes, bytes | None]] = []
    sub = viewer.declare_subscriber(bus.keys.preview, lambda s: got.append(
        (s.payload.to_bytes(), s.attachment.to_bytes() if s.attachment else None)))
    started = start_preview(PreviewConfig(fps=5.0, max_width=320), bus, lambda *a, **k: None)
    assert started is not None
    sink, close = started
    try:
        def offer_until_received() -> bool:  # the subscription reaches the bus a moment later
            t = time.monotonic()
            sink.offer(frame("cam0", int(t * 4), t))
            return bool(got)
        wait_for(offer_until_received, what="a preview on safety/preview")
    finally:
        close()
        sub.undeclare()
    payload, signature = got[0]
    key = bus.keys.preview
    mine = read_preview(payload, signature, key, (signed_bus["public"],), True)
    assert mine is not None and mine.signed and mine.camera == "cam0"
    img = cv2.imdecode(np.frombuffer(mine.jpeg, np.uint8), cv2.IMREAD_COLOR)
    assert img.shape == (180, 320, 3)  # 1280x720 scaled to max_width
    assert abs(int(img[90, 160, 2]) - 40) < 12 and abs(int(img[90, 160, 0]) - 200) < 12  # BGR
    # another key, or no signature: refused; --unauthenticated takes it unsigned
    assert read_preview(payload, signature, key, (signed_bus["other"],), True) is None
    assert read_preview(payload, None, key, (signed_bus["public"],), True) is None
    assert read_preview(payload, signature, key + "x", (signed_bus["public"],), True) is None
    assert read_preview(payload, None, key, (), False) is not None
    assert mine.capture_wall is not None and mine.boot == bus.boot  # both under the signature
    # a forged picture (right schema, no signature) never reaches the console's view
    live = LiveState(preview_keys=(signed_bus["public"],), preview_key=key,
                     wall=lambda: mine.capture_wall + 0.2)
    live.on_preview(payload_of(frame("cam0", 1, time.monotonic(), (0, 255, 0))), None)
    live.on_preview(b"x" * 3_000_000, None)
    assert live.preview("cam0") == (None, None) and live.previews_refused == 2
    live.on_preview(payload, signature)
    jpeg, age = live.preview("cam0")
    assert jpeg == mine.jpeg and age is not None and age >= 0


def test_the_drawn_view_uses_the_live_picture_and_then_falls_back(tmp_path):
    """Fresh: the picture (scaled back to the camera's size, zones drawn over it); older than
    a second by its signed capture time (the monitor stopped sending): the reference image
    under a red "NO LIVE PICTURE" bar, never an old picture as 'live'."""
    payload = payload_of(frame("cam0", 1, time.monotonic(), (255, 0, 0)))
    wall = [json.loads(payload)["capture_wall"] + 0.3]
    live = LiveState(require_signed=False, preview_key="k", wall=lambda: wall[0])
    cell_file = zone_file(tmp_path)
    renderer = LiveRenderer(live, lambda: load_cell(cell_file), {}, min_render_s=0.0)
    live.on_preview(payload, None)
    img = cv2.imdecode(np.frombuffer(renderer.jpeg("cam0"), np.uint8), cv2.IMREAD_COLOR)
    assert img.shape[:2] == (720, 1280)
    assert img[5, 5, 0] > 200 and img[5, 5, 2] < 50  # blue live picture (BGR), no red bar
    assert live.state()["live_picture"] == {"cam0": True}
    wall[0] += 1.0  # 1.3 s after its capture
    img = cv2.imdecode(np.frombuffer(renderer.jpeg("cam0"), np.uint8), cv2.IMREAD_COLOR)
    assert _no_live_bar(img)
    assert img[300, 5, 0] < 120  # the grey canvas (no --reference), not the blue picture
    assert live.state()["live_picture"] == {"cam0": False}


def _no_live_bar(img: np.ndarray) -> bool:
    """The red "NO LIVE PICTURE" bar across the top of a drawn view (BGR)."""
    bar = img[5:NO_LIVE_BAR_PX - 5, 600:620].reshape(-1, 3).mean(axis=0)
    return bar[2] > 180 and bar[0] < 60 and bar[1] < 60


def payload_of(f: Frame, signer=None, seq_clock=None) -> bytes:
    """The preview message of ``f``, as the worker makes it (``signer``: also its signature,
    returned as ``(payload, signature)``)."""
    out: list[tuple[bytes, bytes | None]] = []
    sink = PreviewSink(PreviewConfig(), lambda payload, signature: out.append(
        (payload, signature)), "k", lambda: {"boot": "boot-1", "instance": "mon"}, signer)
    try:
        sink.offer(f)
        payload, signature = wait_for(lambda: out, what="the worker's picture")[0]
        return (payload, signature) if signer is not None else payload
    finally:
        sink.close()


def signed_pictures(signer, shots) -> list:
    """Pictures of one monitor's boot, signed, as its worker sends them one after the other:
    ``shots`` = [(camera, frame seq, capture time on the monotonic clock, colour), ...];
    returns [(payload, signature), ...]."""
    out: list[tuple[bytes, bytes | None]] = []
    sink = PreviewSink(PreviewConfig(fps=2.0), lambda payload, signature: out.append(
        (payload, signature)), "k", lambda: {"boot": "boot-1", "instance": "mon"}, signer)
    try:
        for k, (camera, seq, t, colour) in enumerate(shots):
            assert sink.offer(frame(camera, seq, t, colour))
            wait_for(lambda k=k: len(out) > k, what="the worker's picture")
        return out
    finally:
        sink.close()


def test_replayed_signed_pictures_older_than_a_second_are_never_shown_as_live(tmp_path):
    """Issue 48: the console aged a picture by its arrival, so genuinely signed pictures of the
    empty cell, recorded earlier and replayed at 10-50/s, showed in 3-5 of 8 samples while a
    person stood inside. Now the signed capture time must be within a second of the console's
    clock and each camera's sequence must grow."""
    private, public, _ = new_key_pair(tmp_path / "monitor.key")
    signer, key = load_private_key(private), load_public_key(public)
    # one boot of the monitor: 20 s ago the empty cell (green), recorded by the attacker;
    # now a person stands inside (magenta). All genuinely signed, their sequence growing
    t0 = time.monotonic()
    # (the last empty picture 0.6 s before the person came: within a second of the first
    # picture with the person, so only its lower sequence refuses it)
    shots = [("cam0", k, t0 - 20.0 + 0.6 * k, (0, 200, 0)) for k in range(8)] + \
        [("cam0", 8, t0 - 4.8, (0, 200, 0))] + \
        [("cam0", 100 + k, t0 - 4.2 + 0.6 * k, (255, 0, 255)) for k in range(8)]
    pictures = signed_pictures(signer, shots)
    empty, person = pictures[:9], pictures[9:]
    live = LiveState(preview_keys=(key,), preview_key="k")
    renderer = LiveRenderer(live, lambda: load_cell(zone_file(tmp_path)), {}, min_render_s=0.0)
    samples = []
    for k, (payload, signature) in enumerate(person):
        arrival = json.loads(payload)["capture_wall"] + 0.05  # the console's clock, 50 ms on
        live.wall = lambda arrival=arrival: arrival
        live.on_preview(payload, signature)
        live.on_preview(payload, signature)  # the genuine one sent again: no growing sequence
        if k:
            live.on_preview(*person[k - 1])  # and the one before it, still within the second
        for old in empty:  # the attacker's replay between two genuine pictures (50/s)
            live.on_preview(*old)
        img = cv2.imdecode(np.frombuffer(renderer.jpeg("cam0"), np.uint8), cv2.IMREAD_COLOR)
        samples.append(img[300, 5].tolist())
    assert all(s[0] > 150 and s[1] < 60 and s[2] > 150 for s in samples), samples  # magenta
    counts = live.state()
    # every replayed empty picture refused: by its time, and the one within the second by its
    # sequence; the genuine ones sent again by their sequence
    assert counts["previews_stale"] == 8 * len(empty) - 1 and counts["previews_refused"] == 0
    assert counts["previews_replayed"] == 8 + 7 + 1
    # the monitor stops sending; the recorded pictures go on: none is ever live
    last = json.loads(person[-1][0])["capture_wall"]
    live.wall = lambda: last + 1.2
    for old in empty:
        live.on_preview(*old)
    assert live.preview("cam0") == (None, None)
    img = cv2.imdecode(np.frombuffer(renderer.jpeg("cam0"), np.uint8), cv2.IMREAD_COLOR)
    assert _no_live_bar(img) and img[300, 5, 1] < 120  # red bar over the grey canvas
    assert live.state()["live_picture"] == {"cam0": False}


def test_unsigned_alerts_are_dropped_and_counted_never_listed(signed_bus):
    """Issue 48: forged alerts were listed beside the real ones. The monitor signs its alerts
    (the snapshot's sha256 in the payload); the console lists only those."""
    bus, viewer = signed_bus["bus"], signed_bus["viewer"]
    live = LiveState(preview_keys=(signed_bus["public"],), preview_key=bus.keys.preview,
                     alert_key=bus.keys.alert)
    entities = subscribe_live(viewer, bus.keys, live)
    try:
        jpeg = cv2.imencode(".jpg", np.zeros((8, 8, 3), np.uint8))[1].tobytes()
        genuine = json.dumps({"kind": "reset_refused", "severity": "warning",
                              "message": "forged: reset accepted", "source": "cam0"}).encode()
        pub = viewer.declare_publisher(bus.keys.alert)
        sent = [0]

        def publish_until_listed() -> list:  # the subscription reaches the bus a moment later
            sent[0] += 1  # a new kind each time: never held back by the alert rate limit
            bus.publish_alert(Alert(f"test_alert_{sent[0]}", "warning", "cover fell", "cam0",
                                    1.0, snapshot_jpeg=jpeg))
            return live.state()["alerts"]
        wait_for(publish_until_listed, what="the monitor's signed alert")
        pub.put(genuine)  # unsigned
        pub.put(genuine, attachment=b"\0" * 64 + jpeg)  # a signature that is not one
        wait_for(lambda: live.state()["alerts_refused"] >= 2, what="the forged alerts")
        pub.undeclare()
    finally:
        for e in entities:
            e.undeclare()
    state = live.state()
    assert state["alerts"] and all(a["kind"].startswith("test_alert_") for a in state["alerts"])
    assert "forged" not in json.dumps(state["alerts"])
    assert live.alert_image("cam0")[0] == jpeg


def test_a_signed_alert_with_another_picture_is_refused(tmp_path):
    private, public, _ = new_key_pair(tmp_path / "monitor.key")
    signer, key = load_private_key(private), load_public_key(public)
    jpeg = b"\xff\xd8picture\xff\xd9"
    payload = json.dumps(alert_to_dict(Alert("x", "info", "m", "cam0", 1.0,
                                             snapshot_jpeg=jpeg))).encode()
    signature = signer.sign("k/alert", payload)
    assert read_signed_alert(payload, signed_attachment(signature, jpeg), "k/alert", (key,))
    assert read_signed_alert(payload, signed_attachment(signature, b"\xff\xd8other"),
                             "k/alert", (key,)) is None  # the picture swapped
    assert read_signed_alert(payload, jpeg, "k/alert", (key,)) is None  # unsigned
    assert read_signed_alert(payload, signed_attachment(signature, jpeg), "k/other",
                             (key,)) is None


JS_MEAN = """
const img = document.getElementById('live-cam0');
if (!img || !img.complete || !img.naturalWidth) return null;
const c = document.createElement('canvas');
c.width = 64; c.height = 36;
const g = c.getContext('2d');
g.drawImage(img, 0, 0, 64, 36);
const d = g.getImageData(0, 0, 64, 36).data;
let s = [];
for (let i = 0; i < d.length; i += 4 * 37) s.push(d[i], d[i + 1], d[i + 2]);
return s;
"""


@pytest.mark.slow
@pytest.mark.skipif(not CHROMIUM.exists(), reason="/usr/bin/chromium missing (apt-get install "
                    "chromium chromium-driver; .ci/run installs it)")
def test_a_real_monitor_shows_its_live_picture_in_the_console(tmp_path, synthetic_model):
    """`monitor run` (the demo scene, [preview] fps = 2) and `monitor console` following it: the
    live page's camera image is the monitor's moving picture (not the grey canvas drawn without
    a reference image), and it changes as the scene moves."""
    from tests.processes import Service

    hport = free_port()
    with Service(tmp_path, synthetic_model, "synthetic:demo",
                 "[preview]\nfps = 2.0\n") as svc:
        log = (tmp_path / "console.log").open("w")
        proc = subprocess.Popen(
            [sys.executable, "-m", "monitor", "console", "--cell", "t5", "--unauthenticated",
             "--connect", f"tcp/127.0.0.1:{svc.bus_port}", "--zones",
             str(ROOT / "zones" / "demo-cell.yaml"), "--listen", f"127.0.0.1:{hport}"],
            stdout=log, stderr=subprocess.STDOUT, cwd=tmp_path,
            env={**os.environ, "PYTHONPATH": str(ROOT)})
        try:
            base = f"http://127.0.0.1:{hport}"
            wait_http(base + "/api/state", proc, tmp_path / "console.log")
            with chromium(tmp_path / "profile") as browser:
                browser.get(base + "/")

                def picture() -> list[int] | None:
                    pixels = browser.execute_script(JS_MEAN)
                    # the canvas without a reference image is uniform grey (64): the demo
                    # scene is not
                    return pixels if pixels and max(pixels) - min(pixels) > 60 else None
                first = wait_for(picture, 60, lambda: (svc.log()[-300:], browser.execute_script(
                    "return fetch('/api/state').then(r => r.json())")))
                wait_for(lambda: (p := picture()) is not None and p != first, 60,
                         "a changed live picture")
                state = browser.execute_script("return fetch('/api/state').then(r => r.json())")
                assert "cam0" in state["preview_age_s"] and state["previews_refused"] == 0
                shots = ROOT / "docs" / "console" if os.environ.get(
                    "UPDATE_CONSOLE_SHOTS") == "1" else tmp_path
                browser.save_screenshot(str(shots / "live-picture.png"))
            status = svc.status()
            assert status["preview"]["published"] > 0 and status["preview"]["errors"] == 0
        finally:
            proc.terminate()
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
            log.close()
