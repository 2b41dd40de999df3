"""The report's detail pages (after the first page's verdict and warnings): identity, model,
zones in numbers with their mute rules, zone sets, pictures, calibration, settings, keys,
person and separation, capacity, reaction budget, the walks, and what was not tested. Pure:
``inputs.gather``'s content in, HTML out."""

from __future__ import annotations

from html import escape

from monitor.commission.html import Raw, code, items, points, section, table


def identity(c: dict) -> str:
    f = c["fingerprint"]
    rows = [("product", f"{c['product']['name']} {c['product']['version']}"),
            ("configuration file", c["config"]["file"]),
            ("configuration file SHA-256", c["config"]["sha256"]),
            ("zone set (config_hash)", f["zones_hash"]), ("model SHA-256", f["model_sha256"]),
            ("changed settings SHA-256", f["settings_sha256"])]
    files = table([(name, Raw(code(digest))) for name, digest in sorted(f["files"].items())],
                  ("file the configuration names", "SHA-256")) if f.get("files") else ""
    return section("identity", "Identity",
                   "<p>The running monitor compares these digests with the signed record "
                   "(<code>commissioned.json</code>) and names any that differs "
                   "(<code>monitor status</code>: <code>commissioned</code>).</p>",
                   table(rows), files)


def model(m: dict) -> str:
    rows = [("file", m["file"]), ("SHA-256", m["sha256"]),
            ("measured envelope", m["envelope_file"] or "none measured"),
            ("backend that runs it", _backend(m.get("backend")))]
    env = m.get("envelope") or {}
    rows += [(f"envelope: {k}", v) for k, v in sorted(env.items())]
    return section("model", "Detector model", table(rows))


def _backend(b: dict | None) -> str:
    if not b:
        return "not given (pass the running service's status: --status status.json)"
    agreement = b.get("agreement")
    agrees = (f", agreement {agreement:.3f} with onnxruntime's persons"
              if isinstance(agreement, int | float) else "")
    return f"{b.get('backend')} {b.get('precision')}{agrees} ({b.get('reason') or '?'})"


def _geometry(g: dict) -> str:
    if "corners_m" in g:
        text = f"corners {points(g['corners_m'])} m"
    elif "radius_m" in g:
        text = f"centre ({g['centre_m'][0]:g}, {g['centre_m'][1]:g}) m, radius {g['radius_m']:g} m"
    elif "points_px" in g:
        text = f"camera {g['camera']}, points {points(g['points_px'])} px, anchor {g['anchor']}"
    else:
        text = f"mesh {g.get('file')} x {g.get('scale')}"
    if "z_m" in g:
        text += f"; height {g['z_m'][0]:g} to {g['z_m'][1]:g} m"
    if g.get("yaw_deg"):
        text += f"; yaw {g['yaw_deg']:g} deg"
    return text


def _mute(z: dict) -> str:
    m = z.get("mute")
    if m is None:
        return "never (no mute rule)" if not z.get("unmutable") else "never (unmutable)"
    scale = f" x{m['speed_scale']:g}" if m.get("speed_scale") is not None else ""
    return (f"up to {m['max_s']:g} s as {m['as']}{scale}, by {', '.join(m['operators'])}")


def zones(z: dict | None, detail: list[dict]) -> str:
    if z is None:
        return section("zones", "Zones", '<p class="warn">No zone file.</p>')
    head = table([("file", z["file"]), ("file SHA-256", z["sha256"]),
                  ("zone set (config_hash)", z["config_hash"])])
    cams = table([(c["id"], c["size"], c["calibrated"]) for c in z["cameras"]],
                 ("camera", "size", "calibrated"))
    rows = [(d["id"], d["kind"], d["shape"], d["enabled"], _geometry(d["geometry"]),
             None if d.get("extent_m") is None else f"{d['extent_m']:g} m",
             d.get("speed_scale"), _mute(d), d.get("follows") or "")
            for d in detail]
    geometry = table(rows, ("zone", "kind", "shape", "enabled", "geometry (cell coordinates)",
                            "extent", "speed scale", "may be muted", "follows"), css="small")
    mutable = [d["id"] for d in detail if d["kind"] == "protective" and d.get("mute")]
    note = (f'<p class="warn">Protective zones an operator may mute: '
            f"{escape(', '.join(mutable))}.</p>") if mutable else ""
    return section("zones", "Zones", head, cams, geometry, note)


def zone_sets(s: dict | None) -> str:
    if s is None:
        return section("zone-sets", "Zone sets", "<p>The zone file declares no zone sets: "
                       "every enabled zone applies always.</p>")
    rows = [(x["id"], x.get("name") or "", ", ".join(x["zones"]), x.get("speed_scale"),
             "default" if x["id"] == s["default"] else "") for x in s["sets"]]
    who = (", ".join(s["selectors"]) if s["selectors"] else
           "nobody (no selectors file: every selection is refused, a STOP fault)")
    transitions = ("any" if s["transitions"] is None else
                   ", ".join(f"{a} -> {b}" for a, b in s["transitions"]))
    return section("zone-sets", "Zone sets",
                   table(rows, ("set", "name", "zones", "warning speed cap", "")),
                   table([("who may select a set (selectors file)", who),
                          ("allowed changes", transitions),
                          ("switch-over (s)", s["switch_over_s"]),
                          ("selector silence limit (s)", s.get("selector_ttl_s"))]))


def figures(pictures: dict[str, str]) -> list[str]:
    return [f'<figure><img alt="{escape(name)}" src="data:image/png;base64,{data}">'
            f"<figcaption>{escape(name)}</figcaption></figure>"
            for name, data in sorted(pictures.items())]


def pictures(p: dict[str, str]) -> str:
    return section("pictures", "Zones drawn", "<p>Every zone on each camera's reference image "
                   "and on the floor plan (cell coordinates, metres, x right, y up; the robot "
                   "base at the cross). Red: floor no camera can see a person on.</p>",
                   *figures(p))


def unseen(regions: list[dict]) -> str:
    """The unseen regions of the protective and warning zones (``monitor.commission.unseen``):
    what each costs in availability and the camera position that would see it."""
    if not regions:
        return section("unseen", "Unseen floor in the zones",
                       "<p>Every cell of the protective and warning zones' floor is seen by a "
                       "camera: a lost person's area there ends once it is seen free.</p>")
    rows = []
    for r in regions:
        cam = r.get("camera")
        where = (f"a camera at ({', '.join(f'{v:g}' for v in cam['position_m'])}) m looking "
                 f"at ({', '.join(f'{v:g}' for v in cam['looking_at_m'])}) from the "
                 f"{cam['from_side']} side would see {100 * cam['sees_share']:.0f} % of it"
                 if cam else "no calibrated camera to place another by")
        rows.append((r["zone"], r["kind"], r["hidden_by"], f"{r['area_m2']:g} m\u00b2",
                     f"{100 * r['share']:.0f} %",
                     f"({r['middle_m'][0]:g}, {r['middle_m'][1]:g})", where))
    return section("unseen", "Unseen floor in the zones",
                   "<p>Floor of a protective or warning zone no camera sees a person on. A "
                   "person lost there (walking behind the fixture) is never seen leaving: the "
                   "zone stays held, waiting does not end it, until a second camera sees the "
                   "spot free or an operator confirms the cell clear after looking at the live "
                   "picture. The larger its share of the zone, the more often the cell is "
                   "held for it. A camera at the suggested position (the highest calibrated "
                   "camera's lens and height, judged with the monitor's own visibility test) "
                   "would see it.</p>",
                   table(rows, ("zone", "kind", "unseen because", "floor", "share of the zone",
                                "middle (m)", "would be seen by"), css="small"))


def calibration(rows: list[dict]) -> str:
    if not rows:
        return section("calibration", "Calibration", "<p>No zone file.</p>")
    body = table([(r["camera"], r["type"] or "none (image zones only)", r["pairs"] or None,
                   r["residual_mean_m"], r["residual_max_m"]) for r in rows],
                 ("camera", "calibration", "point pairs", "mean residual (m)",
                  "worst residual (m)"))
    return section("calibration", "Calibration", "<p>Residuals: how far the monitor maps each "
                   "calibration pair's pixel from the floor point it was given (homography "
                   "calibrations; a pinhole calibration keeps no pairs).</p>", body)


def settings(s: dict) -> str:
    body = table(sorted(s.items()), ("setting", "value")) if s else \
        "<p>Every setting is at its default.</p>"
    return section("settings", "Settings that differ from the defaults", body)


def keys(k: dict) -> str:
    mon = k["monitor"]
    rows = [("monitor command key", f"{mon['fingerprint']} ({mon['public_key']})"
             if mon else "none: commands are not signed"),
            ("resets without a key", "accepted" if k["unsigned_resets"] else "refused")]
    ops = table([(o["operator"], o["fingerprint"]) for o in k["operators"]],
                ("operator", "key fingerprint")) if k["operators"] else \
        "<p>No operators file: nobody can reset with a key.</p>"
    return section("keys", "Keys and operators", table(rows), ops)


def separation(person: dict | None, reaction: dict, detail: list[dict]) -> str:
    if person is None:
        return section("separation", "Person and separation", "<p>No zone file.</p>")
    p, s = person["person"], person["separation"]
    rows = [(f"person: {k}", v) for k, v in sorted(p.items())]
    rows += [(f"separation: {k}", v) for k, v in sorted(s.items())]
    s_p = reaction["s_p_configured_m"]
    worst = max([s_p] + [m["s_p_m"] for m in reaction["measured"].values()])
    against = table([(d["id"], d["kind"], f"{d['extent_m']:g} m", f"{worst:g} m",
                      "S_p LARGER" if worst > d["extent_m"] else "ok")
                     for d in detail if d["kind"] in ("protective", "warning")
                     and d.get("extent_m")],
                    ("zone", "kind", "extent", "S_p (worst)", ""))
    return section("separation", "Person and separation", table(rows),
                   "<p>S_p (the protective separation distance at the programmed speed, "
                   "docs/separation.md) against each zone's largest horizontal extent: a zone "
                   "smaller than S_p lets a person at its edge come nearer the robot than it "
                   "can stop in.</p>", against)


def capacity(cap: dict | None) -> str:
    if not cap:
        return section("capacity", "Capacity check",
                       '<p class="warn">Not given: pass the running service\'s status '
                       "(<code>monitor status --json &gt; status.json</code>, "
                       "<code>--status status.json</code>).</p>")
    rows = [(k, v) for k, v in sorted(cap.items()) if k != "cameras"]
    cams = table([(c, v.get("fps"), v.get("frame_age_ms"))
                  for c, v in sorted((cap.get("cameras") or {}).items())],
                 ("camera", "processed fps", "worst frame age (ms)"))
    return section("capacity", "Capacity check", table(rows), cams)


def reaction(r: dict, budget: dict) -> str:
    parts = table([(k.removesuffix("_s").replace("_", " "), v)
                   for k, v in budget.items() if k != "total_s"]
                  + [("T_r (sum)", budget["total_s"])], ("part of T_r (s)", "value"))
    rows = [("T_r of this configuration (s)", r["configured_s"]),
            ("programmed tool speed (m/s)", r["programmed_speed_mps"]),
            ("S_p at that T_r (m)", r["s_p_configured_m"])]
    measured = table([(cam, m["measured_s"], m["s_p_m"], m["exceeded"])
                      for cam, m in sorted(r["measured"].items())],
                     ("camera", "measured T_r (s)", "S_p it implies (m)", "exceeds T_r")) \
        if r["measured"] else '<p class="warn">No measured reaction time (no status given).' \
        "</p>"
    return section("reaction", "Reaction budget and separation distance", parts, table(rows),
                   measured)


def _pct(z: dict, what: str) -> str:
    value = z.get(f"{what}_fraction")
    return "no floor" if value is None else f"{100 * value:.0f} %"


def _one_walk(k: int, w: dict) -> list[str]:
    rec = w.get("recording") or {}
    head = table([("video", w.get("video")), ("camera", w.get("camera")),
                  ("duration (s)", w.get("duration_s")), ("frames", w.get("frames")),
                  ("frames with a person detected", w.get("detected_frames")),
                  ("camera faults (frames)", w.get("camera_faults") or "none"),
                  ("recording: distinct frames", f"{rec['frames'] - rec['repeated']} of "
                   f"{rec['slots']} ({100 * rec['distinct_share']:.0f} %), camera "
                   f"{rec['camera_fps']:g} fps" if rec else "a given video"),
                  ("floor cell (m)", w.get("cell_m")), ("zone set", w.get("zones_hash")),
                  ("entries counted from", f"ground truth ({w['truth']}) and detections"
                   if w.get("truth") else "detections (time to STOP 0 by construction)")])
    body = [f"<h3>Walk {k + 1}: {escape(str(w.get('video')))}</h3>", head]
    for z in w.get("zones", []):
        cover = table([("floor cells", z["cells"]),
                       ("cells a camera sees", f"{z['visible_cells']} ({_pct(z, 'visible')})"),
                       ("cells the person was seen in", f"{z['seen_cells']} "
                        f"({_pct(z, 'seen')})"),
                       ("blind spots (cell centres, m)", len(z["blind_spots"])),
                       ("gaps in detection", len(z["gaps"]))])
        entries = table([(n + 1, e["entry_s"], e["exit_s"], e["stop_s"], e["time_to_stop_s"],
                          e["frames_inside"], e.get("detected_s"))
                         for n, e in enumerate(z["entries"])],
                        ("entry", "in at (s)", "out at (s)", "STOP at (s)", "time to STOP (s)",
                         "frames inside", "first detected in (s)")) \
            if z["entries"] else "<p>No entry.</p>"
        corners = table([(f"({c['corner_m'][0]:g}, {c['corner_m'][1]:g})", c["blind_cells"],
                          "-" if c["frames_near"] is None else c["frames_near"],
                          c["frames_seen"]) for c in z.get("corners", [])],
                        ("corner (m)", "blind cells within 0.5 m", "frames there (truth)",
                         "frames seen there")) if z.get("corners") else ""
        blind = (f"<p>Blind spots: {escape(points(z['blind_spots']))}</p>"
                 if z["blind_spots"] else "")
        gaps = table([(g["from_s"], g["to_s"], g["duration_s"], g["frames_missed"])
                      for g in z["gaps"]], ("from (s)", "to (s)", "length (s)",
                                            "frames missed")) if z["gaps"] else ""
        body += [f'<h4 id="walk{k + 1}-{escape(z["zone_id"])}">{escape(z["kind"])} zone '
                 f'{escape(z["zone_id"])}</h4>', cover, entries, corners, blind, gaps]
    return body + figures(w.get("pictures") or {})


def walks(ws: list[dict]) -> str:
    if not ws:
        return section("walk", "Walk test", '<p class="warn">No walk test given.</p>')
    body = [f"<p>{len(ws)} walk{'s' if len(ws) > 1 else ''}, merged in the first page's "
            "verdict.</p>"]
    for k, w in enumerate(ws):
        body += _one_walk(k, w)
    return section("walk", "Walk test", *body)


def not_tested(lines: list[str]) -> str:
    return section("not-tested", "What was not tested and what the monitor cannot see",
                   items(lines, "note"))
