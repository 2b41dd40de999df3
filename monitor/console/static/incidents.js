// The incident review page: filters, a timeline of the listed incidents, repeated alerts
// grouped into one row, mark reviewed (an operator's password), export. Loaded after
// console.js (uses its $, el, getJSON, svgEl); no libraries, nothing from the internet.
"use strict";

(() => {
  const review = { rows: [], groups: [], selected: null };

  // the timeline's colour of an incident (console.css: .mark.safety, .fault, ...)
  function category(row) {
    const k = row.kinds || [];
    if (k.some((c) => c === "stop" || c === "latch" || c === "reset_refused")) return "safety";
    if (k.includes("fault")) return "fault";
    if (k.includes("reset_accepted")) return "reset";
    if (k.includes("zone_edit")) return "edit";
    return "alert";
  }

  function say(text, isError) {
    const m = $("message");
    m.hidden = !text;
    m.textContent = text || "";
    m.className = isError ? "error" : "ok";
  }

  function query() {
    const q = new URLSearchParams();
    for (const [k, v] of new FormData($("filters")).entries()) {
      if (!v) continue;
      q.set(k, k === "since" ? String(Date.parse(v) / 1000) : v);
    }
    return q;
  }

  function fill(select, values) {
    const keep = select.value;
    select.replaceChildren(el("option", "any", { value: "" }),
      ...values.map((v) => el("option", v, { value: v })));
    select.value = values.includes(keep) ? keep : "";
  }

  async function loadFacets() {
    const f = await getJSON("/api/incidents/facets");
    fill($("f-kind"), f.kinds || []);
    fill($("f-camera"), f.cameras || []);
  }

  async function load(ev) {
    if (ev) ev.preventDefault();
    const q = query();
    $("csv").setAttribute("href", "/api/incidents.csv?" + q.toString());
    q.set("grouped", "1");
    const r = await fetch("/api/incidents?" + q.toString(), { cache: "no-store" });
    const body = await r.json();
    if (!r.ok) { say("filter refused: " + body.error, true); return; }
    say("");
    review.rows = body.incidents || [];
    review.groups = body.groups || [];
    $("count").textContent = review.rows.length + " incident(s) in " +
      review.groups.length + " row(s)";
    drawTimeline();
    drawRows();
    if (review.selected) select(review.selected, false);
  }

  // --- timeline: one mark per listed incident over the listed time range -----------------
  function drawTimeline() {
    const svg = $("timeline");
    const rows = review.rows;
    if (!rows.length) { svg.replaceChildren(); return; }
    const times = rows.map((r) => r.started);
    const t0 = Math.min(...times), t1 = Math.max(...times);
    const x = (t) => (t1 === t0 ? 500 : 10 + 980 * (t - t0) / (t1 - t0));
    const kids = [svgEl("line", { x1: 10, x2: 990, y1: 30, y2: 30, class: "axis" })];
    const label = (t, anchor, at) => {
      const e = svgEl("text", { x: at, y: 44, "text-anchor": anchor });
      e.textContent = new Date(t * 1000).toLocaleString();
      return e;
    };
    kids.push(label(t0, "start", 10));
    if (t1 !== t0) kids.push(label(t1, "end", 990));
    for (const r of rows) {
      const mark = svgEl("rect", { x: x(r.started) - 2, y: 6, width: 4, height: 24,
        class: "mark " + category(r) + (r.reviewed ? " reviewed" : ""), "data-id": r.id });
      const tip = svgEl("title", {});
      tip.textContent = new Date(r.started * 1000).toLocaleString() + " " + r.kind +
        " " + r.camera + (r.zone ? " " + r.zone : "");
      mark.appendChild(tip);
      mark.addEventListener("click", () => select(r.id, true));
      kids.push(mark);
    }
    svg.replaceChildren(...kids);
  }

  // --- rows: one per group; a group of several expands to its incidents ------------------
  function incidentRow(i, member) {
    const tr = el("tr", null, { "data-id": i.id, class: member ? "member" : "" });
    const thumb = el("td");
    if (i.has_clip) {  // the clip's frame at the incident's moment, fetched when shown
      thumb.appendChild(el("img", null, { class: "thumb", alt: "", loading: "lazy",
        src: "/api/incidents/" + encodeURIComponent(i.id) + "/thumb.jpg" }));
    }
    tr.appendChild(thumb);
    tr.appendChild(el("td", new Date(i.started * 1000).toLocaleString()));
    for (const k of ["kind", "state", "camera", "zone"]) tr.appendChild(el("td", i[k]));
    tr.appendChild(el("td", i.reviewed ? "by " + i.review.operator : "no",
                      { class: i.reviewed ? "reviewed" : "" }));
    const td = el("td");
    if (i.has_clip) {
      const b = el("button", "play", { type: "button", class: "play" });
      b.addEventListener("click", () => play(i, tr));
      td.appendChild(b);
    }
    td.appendChild(el("a", "zip", { href: "/api/incidents/" + encodeURIComponent(i.id) +
                                            "/export", class: "export", download: "" }));
    if (!i.reviewed) {
      const m = el("button", "mark reviewed", { type: "button", class: "mark-reviewed" });
      m.addEventListener("click", () => markReviewed(i.id));
      td.appendChild(m);
    }
    tr.appendChild(td);
    tr.addEventListener("click", (e) => { if (e.target === tr || e.target.tagName === "TD")
      select(i.id, false); });
    return tr;
  }

  function drawRows() {
    const byId = new Map(review.rows.map((r) => [r.id, r]));
    const out = [];
    review.groups.forEach((g, k) => {
      if (g.count === 1) { out.push(incidentRow(byId.get(g.ids[0]), false)); return; }
      const head = el("tr", null, { class: "group", "data-group": k });
      const toggle = el("button", "expand", { type: "button", class: "expand" });
      head.appendChild(el("td")).appendChild(toggle);
      head.appendChild(el("td", new Date(g.first * 1000).toLocaleString() + " – " +
                                new Date(g.last * 1000).toLocaleTimeString()));
      head.appendChild(el("td", g.title));
      head.appendChild(el("td", byId.get(g.ids[0]).state));
      head.appendChild(el("td", g.camera));
      head.appendChild(el("td", g.zone));
      head.appendChild(el("td", g.reviewed + " of " + g.count));
      head.appendChild(el("td"));
      const members = g.ids.map((id) => {
        const tr = incidentRow(byId.get(id), true);
        tr.hidden = true;
        tr.dataset.member = k;
        return tr;
      });
      toggle.addEventListener("click", () => expand(k, members[0].hidden));
      out.push(head, ...members);
    });
    $("rows").replaceChildren(...out);
  }

  function expand(k, open) {
    for (const tr of document.querySelectorAll("#rows tr[data-member='" + k + "']")) {
      tr.hidden = !open;
    }
    const head = document.querySelector("#rows tr[data-group='" + k + "'] button.expand");
    if (head) head.textContent = open ? "collapse" : "expand";
  }

  function select(id, scroll) {
    review.selected = id;
    for (const e of document.querySelectorAll("tr.sel, #timeline .sel")) {
      e.classList.remove("sel");
    }
    const tr = document.querySelector("#rows tr[data-id='" + CSS.escape(id) + "']");
    if (tr && tr.hidden) expand(tr.dataset.member, true);
    if (tr) {
      tr.classList.add("sel");
      if (scroll) tr.scrollIntoView({ block: "nearest" });
    }
    const mark = document.querySelector("#timeline [data-id='" + CSS.escape(id) + "']");
    if (mark) mark.classList.add("sel");
    const row = review.rows.find((r) => r.id === id);
    if (row) $("playing").textContent = "incident " + row.id + ": " + row.describe;
  }

  function play(incident, tr) {
    select(incident.id, false);
    const v = $("player");
    v.hidden = false;
    v.src = "/api/incidents/" + encodeURIComponent(incident.id) + "/clip";
    v.play().catch(() => {});
  }

  async function markReviewed(id) {
    const auth = "Basic " + btoa(unescape(encodeURIComponent(
      $("operator").value + ":" + $("password").value)));
    const r = await fetch("/api/incidents/" + encodeURIComponent(id) + "/reviewed", {
      method: "POST", headers: { authorization: auth } });
    const out = await r.json();
    if (!r.ok) { say("not marked: " + out.error, true); return; }
    review.selected = id;
    await load();
    say("incident " + id + " marked reviewed by " + out.review.operator, false);
  }

  $("filters").addEventListener("submit", load);
  $("login").addEventListener("submit", (e) => e.preventDefault());
  loadFacets().then(() => load());
})();
