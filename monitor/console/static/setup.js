// The setup page: login, who may do what, who may reset (read-only), zone sets and their
// rules, mute settings, and the cell-space volumes on a floor plan (top view). No libraries.
"use strict";

const $ = (id) => document.getElementById(id);
const SVG = "http://www.w3.org/2000/svg";
const COLOURS = { protective: "#e53935", warning: "#fbc02d", mask: "#8e24aa",
                  watch: "#1e88e5", occluder: "#757575" };
const setup = { data: null };

function el(tag, text, attrs) {
  const e = document.createElement(tag);
  if (text !== undefined && text !== null) e.textContent = String(text);
  for (const [k, v] of Object.entries(attrs || {})) e.setAttribute(k, v);
  return e;
}

function svgEl(tag, attrs, text) {
  const e = document.createElementNS(SVG, tag);
  for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, v);
  if (text !== undefined) e.textContent = text;
  return e;
}

function message(text, isError) {
  const m = $("message");
  m.textContent = text;
  m.className = isError ? "error" : "ok";
  m.scrollIntoView({ block: "nearest" });
}

function auth() {
  return "Basic " + btoa(unescape(encodeURIComponent($("user").value + ":" +
                                                    $("password").value)));
}

async function getJSON(url) {
  const r = await fetch(url, { cache: "no-store" });
  const body = await r.json();
  if (!r.ok) throw new Error(body.error || ("HTTP " + r.status));
  return body;
}

// --- login --------------------------------------------------------------------------------
async function whoami() {
  const me = await getJSON("/api/me");
  $("whoami").textContent = me.name ? me.name + " (" + me.level + ")" :
    (me.view_login ? "not logged in" : "viewing without login (loopback)");
  return me;
}

async function login() {
  const r = await fetch("/api/login", { method: "POST", headers: { authorization: auth() } });
  const out = await r.json();
  if (!r.ok) { message("refused: " + out.error, true); return; }
  message("logged in as " + out.name + " (" + out.level + ")", false);
  await refresh();
}

async function logout() {
  await fetch("/api/logout", { method: "POST" });
  message("logged out", false);
  await refresh();
}

// --- rights and resetters -----------------------------------------------------------------
function showAccess(access) {
  $("rights").replaceChildren(...access.rights.map((r) => {
    const tr = el("tr");
    tr.appendChild(el("td", r.what));
    tr.appendChild(el("td", r.levels.length ? r.levels.join(", ") : "no console user"));
    return tr;
  }));
  const reset = access.reset;
  $("resetfile").textContent = reset.error ? reset.error : "(" + reset.file + ")";
  $("resetters").replaceChildren(...reset.operators.map((o) => {
    const tr = el("tr", null, { "data-name": o.name });
    tr.appendChild(el("td", o.name));
    tr.appendChild(el("td", o.fingerprint));
    return tr;
  }));
}

// --- saving (every edit sends its own credential) -------------------------------------------
async function put(url, body) {
  body.base = setup.data.sha;
  const r = await fetch(url, { method: "PUT", body: JSON.stringify(body),
    headers: { "content-type": "application/json", authorization: auth() } });
  const out = await r.json();
  if (!r.ok) { message("refused: " + out.error, true); return false; }
  message("saved " + out.saved + "; config hash " + out.config_hash + ". " + out.note, false);
  await loadSetup();
  return true;
}

function numberOrNull(input) {
  return input.value.trim() === "" ? null : Number(input.value);
}

// --- zone sets ----------------------------------------------------------------------------
function showSets(d) {
  $("fileinfo").textContent = d.file + " — config hash " + d.config_hash;
  $("sets").replaceChildren(...(d.sets.length ? d.sets.map((s) => {
    const tr = el("tr", null, { "data-set": s.id });
    tr.appendChild(el("td", s.id + (s.default ? " (default)" : "")));
    tr.appendChild(el("td", s.name));
    tr.appendChild(el("td", s.zones.join(", ")));
    tr.appendChild(el("td", s.speed_scale == null ? "-" : s.speed_scale));
    return tr;
  }) : [el("tr", null, {})].map((tr) => {
    tr.appendChild(el("td", "no zone sets: every zone applies always", { colspan: 4 }));
    return tr;
  })));
  const sel = $("default_set");
  sel.replaceChildren(...d.sets.map((s) => el("option", s.id, { value: s.id })));
  sel.value = d.rules.default_set || "";
  const t = d.rules.transitions;
  $("transitions").value = t === null ? "any" : (t.length ? t.map((m) => m.join(":"))
    .join(", ") : "none");
  $("switch_over_s").value = d.rules.switch_over_s;
  $("selector_ttl_s").value = d.rules.selector_ttl_s == null ? "" : d.rules.selector_ttl_s;
}

async function saveRules() {
  const body = { switch_over_s: numberOrNull($("switch_over_s")) };
  if ($("default_set").value) body.default_set = $("default_set").value;
  const text = $("transitions").value.trim();
  if (text === "any") body.any = true;
  else if (text === "none") body.none = true;
  else body.allow = text.split(",").map((m) => m.split(":").map((s) => s.trim()));
  const ttl = numberOrNull($("selector_ttl_s"));
  if (ttl === null) body.no_selector_ttl = true; else body.selector_ttl_s = ttl;
  await put("/api/setup/rules", body);
}

// --- mutes --------------------------------------------------------------------------------
function showMutes(d) {
  $("mutes").replaceChildren(...d.mutes.map((m) => {
    const tr = el("tr", null, { "data-zone": m.id });
    tr.appendChild(el("td", m.id));
    tr.appendChild(el("td", m.kind));
    tr.appendChild(el("td", m.describe, { class: "describe" }));
    const mute = m.mute || {};
    const ops = el("input", null, { class: "names", name: "operators",
                                    value: (mute.operators || []).join(", ") });
    const maxS = el("input", null, { type: "number", name: "max_s", step: "1",
                                     value: mute.max_s == null ? "" : mute.max_s });
    const as = el("select", null, { name: "as" });
    as.replaceChildren(el("option", "warning"), el("option", "none"));
    as.value = mute.as || "warning";
    const speed = el("input", null, { type: "number", name: "speed_scale", step: "0.05",
                                      value: mute.speed_scale == null ? "" : mute.speed_scale });
    for (const input of [ops, maxS, as, speed]) {
      const td = el("td");
      td.appendChild(input);
      tr.appendChild(td);
    }
    const td = el("td");
    const save = el("button", "Save", { type: "button", class: "save" });
    save.addEventListener("click", () => {
      const body = { operators: ops.value.split(",").map((s) => s.trim()).filter((s) => s),
                     max_s: numberOrNull(maxS), as: as.value };
      const s = numberOrNull(speed);
      if (s !== null) body.speed_scale = s;
      put("/api/setup/mute/" + encodeURIComponent(m.id), body);
    });
    const never = el("button", "Unmutable", { type: "button" });
    never.addEventListener("click", () =>
      put("/api/setup/mute/" + encodeURIComponent(m.id), { unmutable: true }));
    const remove = el("button", "Remove", { type: "button" });
    remove.addEventListener("click", () =>
      put("/api/setup/mute/" + encodeURIComponent(m.id), { remove: true }));
    td.append(save, never, remove);
    tr.appendChild(td);
    return tr;
  }));
}

// --- volumes: floor plan (x right, y up) and the boxes' corners ---------------------------
const AXES = ["x", "y", "z"];

function boxRing(min, max, yawDeg) {
  const cx = (min[0] + max[0]) / 2, cy = (min[1] + max[1]) / 2;
  const hx = (max[0] - min[0]) / 2, hy = (max[1] - min[1]) / 2;
  const a = (yawDeg || 0) * Math.PI / 180, c = Math.cos(a), s = Math.sin(a);
  return [[-hx, -hy], [hx, -hy], [hx, hy], [-hx, hy]].map(([x, y]) =>
    [cx + c * x - s * y, cy + s * x + c * y]);
}

function drawPlan() {
  const d = setup.data;
  const rings = d.volumes.map((v) => {
    if (v.editable) {
      const inputs = document.querySelectorAll("#boxes tr[data-zone='" + v.id + "'] input");
      if (inputs.length === 6) {
        const n = [...inputs].map((i) => Number(i.value));
        if (n.every(Number.isFinite)) return boxRing(n.slice(0, 3), n.slice(3), v.yaw_deg);
      }
    }
    return v.outline_m;
  });
  const pts = rings.flat().concat([[0, 0]]);
  const xs = pts.map((p) => p[0]), ys = pts.map((p) => p[1]);
  const pad = 0.5;
  const x0 = Math.min(...xs) - pad, x1 = Math.max(...xs) + pad;
  const y0 = Math.min(...ys) - pad, y1 = Math.max(...ys) + pad;
  const size = Math.max(x1 - x0, y1 - y0);
  const svg = $("plan");
  // y up: the view box runs over -y (cell y becomes -y in SVG)
  svg.setAttribute("viewBox", x0 + " " + (-(y0 + size)) + " " + size + " " + size);
  const kids = [];
  const grid = size > 20 ? 5 : 1;
  for (let g = Math.ceil(x0 / grid) * grid; g <= x0 + size; g += grid) {
    kids.push(svgEl("line", { x1: g, x2: g, y1: -(y0 + size), y2: -y0, stroke: "#ddd",
                              "stroke-width": size / 500 }));
  }
  for (let g = Math.ceil(y0 / grid) * grid; g <= y0 + size; g += grid) {
    kids.push(svgEl("line", { y1: -g, y2: -g, x1: x0, x2: x0 + size, stroke: "#ddd",
                              "stroke-width": size / 500 }));
  }
  kids.push(svgEl("circle", { cx: 0, cy: 0, r: size / 100, fill: "#263238",
                              class: "origin" }));
  kids.push(svgEl("text", { x: x0 + size / 80, y: -y0 - size / 80, "font-size": size / 36,
                            fill: "#555" }, "x \u2192, y \u2191; grid " + grid + " m; \u25cf origin"));
  d.volumes.forEach((v, k) => {
    const ring = rings[k];
    if (!ring || ring.length < 3) return;
    kids.push(svgEl("polygon", { points: ring.map((p) => p[0] + "," + (-p[1])).join(" "),
      fill: COLOURS[v.kind] || "#999", "fill-opacity": v.editable ? 0.3 : 0.12,
      stroke: COLOURS[v.kind] || "#999", "stroke-width": size / 250,
      "stroke-dasharray": v.enabled ? "none" : size / 80,
      class: "volume", "data-id": v.id }));
    // the label inside the outline's top-left corner: nested volumes keep theirs apart
    const left = Math.min(...ring.map((p) => p[0])), top = Math.max(...ring.map((p) => p[1]));
    kids.push(svgEl("text", { x: left + size / 80, y: -top + size / 28, "font-size": size / 36,
                              fill: "#222" }, v.id));
  });
  svg.replaceChildren(...kids);
}

function showBoxes(d) {
  const boxes = d.volumes.filter((v) => v.editable);
  $("boxes").replaceChildren(...boxes.map((v) => {
    const tr = el("tr", null, { "data-zone": v.id });
    tr.appendChild(el("td", v.id + " (" + v.kind + ")"));
    for (const [name, corner] of [["min", v.min_m], ["max", v.max_m]]) {
      corner.forEach((value, k) => {
        const td = el("td");
        const input = el("input", null, { type: "number", step: "0.05", value,
                                          name: name + "_" + AXES[k] });
        input.addEventListener("input", drawPlan);
        td.appendChild(input);
        tr.appendChild(td);
      });
    }
    const td = el("td");
    const save = el("button", "Save", { type: "button", class: "save" });
    save.addEventListener("click", () => {
      const n = [...tr.querySelectorAll("input")].map((i) => Number(i.value));
      put("/api/setup/volume/" + encodeURIComponent(v.id),
          { min_m: n.slice(0, 3), max_m: n.slice(3) });
    });
    td.appendChild(save);
    tr.appendChild(td);
    return tr;
  }));
}

// --- start --------------------------------------------------------------------------------
async function loadSetup() {
  setup.data = await getJSON("/api/setup");
  showSets(setup.data);
  showMutes(setup.data);
  showBoxes(setup.data);
  drawPlan();
}

async function refresh() {
  try {
    await whoami();
    showAccess(await getJSON("/api/access"));
    await loadSetup();
  } catch (err) {
    message(String(err.message || err), true);
  }
}

$("login").addEventListener("click", login);
$("logout").addEventListener("click", logout);
$("save_rules").addEventListener("click", saveRules);
refresh();
