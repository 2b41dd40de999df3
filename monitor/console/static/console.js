// The console's script (the incident review has its own, incidents.js, loaded after this
// one: it uses $, el and getJSON from here): polls the JSON API; no build step, no libraries.
"use strict";

const $ = (id) => document.getElementById(id);

function el(tag, text, attrs) {
  const e = document.createElement(tag);
  if (text !== undefined && text !== null) e.textContent = String(text);
  for (const [k, v] of Object.entries(attrs || {})) e.setAttribute(k, v);
  return e;
}

async function getJSON(url) {
  const r = await fetch(url, { cache: "no-store" });
  return r.json();
}

// --- live ---------------------------------------------------------------------------------
let liveCameras = [];

async function pollState() {
  let s;
  try {
    s = await getJSON("/api/state");
  } catch (err) {
    s = { state: "STOP", reason: "console not reachable" };
  }
  // refused (a login needed off loopback: /setup): never shown as anything but STOP
  if (!s.state) s = { state: "STOP", reason: s.error || "no state" };
  const banner = $("banner");
  banner.className = s.state;
  banner.textContent = s.state + (s.state === "SLOW" ? " " + s.speed_scale : "") +
    (s.latched ? " (latched)" : "");
  $("reason").textContent = s.reason || (s.state === "RUN" ? "all clear" : "");
  $("cell").textContent = "cell " + (s.cell || "");
  // why the cell is held: each lost person's area that holds a zone (drawn yellow in the view)
  const held = [];
  for (const [cam, areas] of Object.entries(s.areas || {})) {
    for (const a of areas) {
      if (!(a.zones || []).length) continue;
      held.push(el("li", cam + ": person " + a.person + " may be in " + a.zones.join(", ") +
        ((a.regions || []).length && a.leaving_ends
          ? " (behind " + a.regions.join(", ") + ", in counted pocket " +
            (a.pockets || []).join(", ") + ": waiting does not end it; each person seen " +
            "walking out of it takes one off its count, at 0 it ends; or a confirm-clear " +
            "after looking)"
          : (a.regions || []).length
          ? " (behind " + a.regions.join(", ") + ", not seen by any camera: waiting does " +
            "not end it; a camera that sees there, or a confirm-clear after looking, does)"
          : " (in view: waiting ends it once the camera sees the spot free)")));
    }
  }
  const areasHolding = held.length;  // a confirm-clear can end these (showConfirm)
  // the hidden pockets with their counts (outlined in the view): what ends a hold behind one
  for (const [cam, pockets] of Object.entries(s.pockets || {})) {
    for (const p of pockets) {
      held.push(el("li", cam + ": " + p.label +
        ((p.regions || []).length ? ", behind " + p.regions.join(", ") : "") +
        (p.why ? " (" + p.why + ")" : "")));
    }
  }
  $("held").replaceChildren(...held);
  $("details").textContent = "seq " + s.seq + ", command age " +
    (s.age_ms == null ? "-" : Math.round(s.age_ms) + " ms") + ", monitor " + (s.instance || "-") +
    ", zone set in force " + (s.zone_hash || "-") + ", zone file " + (s.zone_file_hash || "-") +
    (s.reset_possible ? ", reset possible" : "");
  const pending = $("pending");
  pending.hidden = !s.zone_file_pending;
  pending.textContent = "The zone file (" + s.zone_file_hash + ") differs from the zone set " +
    "the monitor decides with (" + s.zone_hash + "): it takes effect only when an operator " +
    "applies it (monitor zones apply, signed) or the monitor restarts with it.";
  const draft = s.zone_draft;
  if (draft) {  // an edit that weakens protection: never in force without a signed apply
    pending.hidden = false;
    pending.textContent = (s.zone_file_pending ? pending.textContent + " " : "") +
      "A zone edit that weakens protection waits as the draft " + draft.file + " (" +
      (draft.error || (draft.weakens || []).join("; ")) + "): it takes effect only when an " +
      "operator signs it (" + (draft.apply || "monitor zones apply") + "), not at a restart.";
  }
  const cams = s.camera_ids || [];
  showConfirm(s, cams, areasHolding > 0);
  if (cams.join() !== liveCameras.join()) {
    liveCameras = cams;
    const box = $("cams");
    box.replaceChildren(...cams.map((c) => el("img", null, { id: "live-" + c, alt: c })));
  }
  const tbody = $("alerts");
  tbody.replaceChildren(...(s.alerts || []).map((a) => {
    const tr = el("tr");
    for (const k of ["kind", "severity", "source", "message"]) tr.appendChild(el("td", a[k]));
    return tr;
  }));
}

// reset and confirm-clear (monitor/console/confirm_routes.py): the plain reset is offered
// while the cell is latched (the monitor accepts it only on its own evidence); the confirm-
// clear only while a lost person's area holds a zone or the monitor's reason asks for one
// (a confirm-clear as the only button is pressed by habit and empties the restart
// interlock), sendable only while every camera has a live picture and the operator says
// they looked
function showConfirm(s, cams, holds) {
  const box = $("confirm");
  if (!box) return;
  box.hidden = !(s.latched || s.state === "STOP");
  $("cc-block").hidden = !(holds || /confirm-clear/.test(s.reason || ""));
  const live = s.live_picture || {};
  const allLive = cams.length > 0 && cams.every((c) => live[c] === true);
  $("cc-send").disabled = !(allLive && $("cc-looked").checked);
  $("cc-send").title = allLive ? "" : "no live picture of every camera: the cell cannot be seen";
}

async function sendReset(confirm) {
  const msg = $("cc-message");
  const auth = "Basic " + btoa(unescape(encodeURIComponent(
    $("cc-operator").value + ":" + $("cc-password").value)));
  msg.className = ""; msg.textContent = "sending…";
  const body = confirm ? { looked_at: liveCameras, note: "confirmed from the console" }
    : { note: "reset from the console" };
  let r, answer;
  try {
    r = await fetch(confirm ? "/api/confirm-clear" : "/api/reset", {
      method: "POST", headers: { "content-type": "application/json", authorization: auth },
      body: JSON.stringify(body) });
    answer = await r.json();
  } catch (err) {
    msg.className = "error"; msg.textContent = "console not reachable"; return;
  }
  if (confirm) $("cc-looked").checked = false;  // each confirm-clear is a look of its own
  if (r.ok && answer.accepted) {
    msg.className = "ok"; msg.textContent = "accepted by the monitor: " + answer.reason;
  } else {
    msg.className = "error";
    msg.textContent = "REFUSED: " + (answer.error || answer.reason || r.status);
  }
}

function refreshImages() {
  for (const c of liveCameras) {
    const img = $("live-" + c);
    if (!img) continue;
    // the next picture is asked for once this one has arrived or failed: a new src cancels
    // the load under way, so on a loaded host or a slow link (an answer slower than the
    // 700 ms period) the picture would never show; a request hung for 10 s is given up
    const since = Number(img.dataset.asked || 0);
    if (since && Date.now() - since < 10000) continue;
    img.onload = img.onerror = () => { img.dataset.asked = ""; };
    img.dataset.asked = String(Date.now());
    img.src = "/api/live/" + encodeURIComponent(c) + ".jpg?t=" + Date.now();
  }
}

// --- zone editor --------------------------------------------------------------------------
const SVG = "http://www.w3.org/2000/svg";
const COLOURS = { protective: "#e53935", warning: "#fbc02d", mask: "#8e24aa",
                  watch: "#1e88e5", occluder: "#757575" };
const ed = { data: null, camera: null, zone: null, points: [], drag: null, isNew: false };

async function loadZones(keepZone) {
  ed.data = await getJSON("/api/zones");
  if (ed.data.error) { message(ed.data.error, true); return; }
  $("fileinfo").textContent = ed.data.file + " — config hash " + ed.data.config_hash;
  const camSel = $("camera");
  camSel.replaceChildren(...ed.data.cameras.map((c) => el("option", c.id, { value: c.id })));
  if (ed.camera) camSel.value = ed.camera;
  ed.camera = camSel.value;
  fillZoneList(keepZone);
}

function camSpec() { return ed.data.cameras.find((c) => c.id === ed.camera); }

function fillZoneList(keepZone) {
  const zones = ed.data.polygons.filter((z) => z.camera === ed.camera);
  const sel = $("zone");
  sel.replaceChildren(el("option", "(none)", { value: "" }),
    ...zones.map((z) => el("option", z.id + " (" + z.kind + ")", { value: z.id })));
  sel.value = keepZone && zones.some((z) => z.id === keepZone) ? keepZone : "";
  selectZone(sel.value);
}

function selectZone(id) {
  const z = ed.data.polygons.find((p) => p.id === id && p.camera === ed.camera);
  ed.zone = z ? z.id : null;
  ed.isNew = false;
  ed.points = z ? z.points_px.map((p) => p.slice()) : [];
  $("zid").value = z ? z.id : "";
  $("zname").value = z ? z.name : "";
  $("zkind").value = z ? z.kind : "protective";
  if (z && z.speed_scale != null) $("zspeed").value = z.speed_scale;
  draw();
}

function svgPoint(evt) {
  const svg = $("canvas");
  const p = svg.createSVGPoint();
  p.x = evt.clientX; p.y = evt.clientY;
  const q = p.matrixTransform(svg.getScreenCTM().inverse());
  const c = camSpec();
  return [Math.max(0, Math.min(c.width, Math.round(q.x * 10) / 10)),
          Math.max(0, Math.min(c.height, Math.round(q.y * 10) / 10))];
}

function svgEl(tag, attrs) {
  const e = document.createElementNS(SVG, tag);
  for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, v);
  return e;
}

function draw() {
  const svg = $("canvas");
  const c = camSpec();
  if (!c) return;
  svg.setAttribute("viewBox", "0 0 " + c.width + " " + c.height);
  const kids = [svgEl("image", { href: "/api/zones/" + encodeURIComponent(c.id) + "/image.jpg",
                                 x: 0, y: 0, width: c.width, height: c.height })];
  for (const f of ed.data.footprints.filter((f) => f.camera === c.id)) {
    kids.push(svgEl("polygon", { points: f.points_px.map((p) => p.join(",")).join(" "),
      fill: "none", stroke: COLOURS[f.kind], "stroke-width": 3, "stroke-dasharray": "12 8",
      class: "footprint", "data-id": f.id }));
  }
  for (const z of ed.data.polygons.filter((p) => p.camera === c.id && p.id !== ed.zone)) {
    kids.push(svgEl("polygon", { points: z.points_px.map((p) => p.join(",")).join(" "),
      fill: COLOURS[z.kind], "fill-opacity": 0.2, stroke: COLOURS[z.kind], "stroke-width": 2,
      class: "zone", "data-id": z.id }));
  }
  if (ed.points.length) {
    const kind = $("zkind").value;
    const shape = svgEl(ed.points.length > 2 ? "polygon" : "polyline", {
      points: ed.points.map((p) => p.join(",")).join(" "), fill: COLOURS[kind],
      "fill-opacity": ed.points.length > 2 ? 0.35 : 0, stroke: "#fff", "stroke-width": 3,
      id: "editing" });
    shape.addEventListener("mousedown", (e) => {
      if (ed.isNew) return;
      ed.drag = { whole: true, from: svgPoint(e), start: ed.points.map((p) => p.slice()) };
      e.stopPropagation();
    });
    kids.push(shape);
    ed.points.forEach((p, k) => {
      const h = svgEl("circle", { cx: p[0], cy: p[1], r: Math.max(6, c.width / 150),
        fill: "#fff", stroke: "#000", "stroke-width": 2, class: "handle", "data-k": k });
      h.addEventListener("mousedown", (e) => { ed.drag = { k }; e.stopPropagation(); });
      kids.push(h);
    });
  }
  svg.replaceChildren(...kids);
}

function onCanvasDown(e) {
  if (!ed.isNew) return;
  ed.points.push(svgPoint(e));
  draw();
}

function onMove(e) {
  if (!ed.drag) return;
  const p = svgPoint(e);
  if (ed.drag.whole) {
    const dx = p[0] - ed.drag.from[0], dy = p[1] - ed.drag.from[1];
    ed.points = ed.drag.start.map((q) => [Math.round((q[0] + dx) * 10) / 10,
                                          Math.round((q[1] + dy) * 10) / 10]);
  } else ed.points[ed.drag.k] = p;
  draw();
}

function message(text, isError) {
  const m = $("message");
  m.textContent = text;
  m.className = isError ? "error" : "ok";
}

async function save() {
  const id = $("zid").value.trim();
  if (!id) { message("give the zone an id", true); return; }
  const body = { camera: ed.camera, kind: $("zkind").value, name: $("zname").value,
                 points_px: ed.points, base: ed.data.sha };
  if (body.kind === "warning") body.speed_scale = parseFloat($("zspeed").value);
  const auth = "Basic " + btoa(unescape(encodeURIComponent(
    $("operator").value + ":" + $("password").value)));
  const r = await fetch("/api/zones/" + encodeURIComponent(id), {
    method: "PUT", headers: { "content-type": "application/json", authorization: auth },
    body: JSON.stringify(body) });
  const out = await r.json();
  if (!r.ok) { message("refused: " + out.error, true); return; }
  message("saved " + out.saved + "; config hash " + out.config_hash + ". " + out.note, false);
  await loadZones(id);
}

function initZones() {
  $("camera").addEventListener("change", (e) => { ed.camera = e.target.value; fillZoneList(); });
  $("zone").addEventListener("change", (e) => selectZone(e.target.value));
  $("zkind").addEventListener("change", draw);
  $("new").addEventListener("click", () => {
    ed.zone = null; ed.isNew = true; ed.points = [];
    $("zone").value = ""; $("zid").value = ""; $("zname").value = "";
    message("click on the image to add points", false);
    draw();
  });
  $("undo").addEventListener("click", () => { ed.points.pop(); draw(); });
  $("canvas").addEventListener("mousedown", onCanvasDown);
  window.addEventListener("mousemove", onMove);
  window.addEventListener("mouseup", () => { ed.drag = null; });
  $("save").addEventListener("click", save);
  loadZones();
}

// --- start --------------------------------------------------------------------------------
const page = document.body.dataset.page;
if (page === "live") {
  pollState(); setInterval(pollState, 300);
  setInterval(refreshImages, 700);
  $("cc-send").addEventListener("click", () => sendReset(true));
  $("rs-send").addEventListener("click", () => sendReset(false));
} else if (page === "incidents") {  // the review page's own script: incidents.js
  getJSON("/api/state").then((s) => { $("cell").textContent = "cell " + (s.cell || ""); });
} else if (page === "zones") {
  initZones();
  getJSON("/api/state").then((s) => { $("cell").textContent = "cell " + (s.cell || ""); });
}
