// The field page: polls /api/status once a second, draws the running cast, and
// reads the journal's surveys on demand. Read-only: it only ever sends GET.
"use strict";
const $ = (sel) => document.querySelector(sel);
const NS = "http://www.w3.org/2000/svg";
const POLL_MS = 1000;
const live = { cast: null, points: [] };  // the running cast's [wall s, depth m]
let latestSonde = null;  // a card: the sonde's last reading, from the journal
let latestSonar = null;  // a card: the daemon's own sonar's last reading, from the journal
let chosenSurvey = null, chosenCast = null;  // a late answer for an earlier choice is dropped

function el(tag, attrs, text) {
  const node = tag.startsWith("svg:") ? document.createElementNS(NS, tag.slice(4))
    : document.createElement(tag);
  for (const [k, v] of Object.entries(attrs || {})) node.setAttribute(k, v);
  if (text !== undefined) node.textContent = text;
  return node;
}
function show(v) {
  if (v === null || v === undefined) return "–";
  if (typeof v === "number") return Number.isInteger(v) ? String(v) : v.toFixed(3).replace(/0+$/, "");
  if (typeof v === "boolean") return v ? "yes" : "no";
  if (typeof v === "object") return JSON.stringify(v);
  return String(v);
}
function utc(s) { return s ? new Date(s * 1000).toISOString().replace("T", " ").slice(0, 19) : "–"; }
async function getJSON(url) {
  const r = await fetch(url, { cache: "no-store" });
  const body = await r.json().catch(() => ({ error: r.statusText }));
  if (!r.ok) throw new Error(body.error || r.statusText);
  return body;
}
function card(title, rows, bad) {
  const c = el("div", { class: bad ? "card bad" : "card" });
  c.append(el("h4", {}, title));
  const dl = el("dl");
  for (const [k, v] of rows) { dl.append(el("dt", {}, k), el("dd", {}, show(v))); }
  c.append(dl);
  return c;
}
// Every true-ish key naming a fault, a stranded probe or an error, wherever it is:
// sections the daemon adds later raise the banner without this page changing.
function alarms(doc, path, out) {
  for (const [k, v] of Object.entries(doc || {})) {
    const where = path ? path + "." + k : k;
    if (v && typeof v === "object" && !Array.isArray(v)) alarms(v, where, out);
    // A text or `true`: a fault said, or a probe stranded. A number is a count of
    // faults past (faults_total: 3), which must not cry wolf for ever.
    else if (/fault|stranded|^error$|last_error/.test(k) && (v === true || typeof v === "string") && v) {
      out.push(where + ": " + show(v));
    }
  }
  return out;
}
function simulated(doc) {
  const d = doc.daemon || {};
  if (typeof d.simulated === "boolean") return d.simulated;
  const backend = (doc.winch || {}).backend;
  return backend ? backend === "sim" || backend.endsWith("-mock") : null;
}

function renderStatus(doc) {
  const mode = $("#mode"), banner = $("#banner");
  const problems = [];
  if (!doc.reachable) {
    mode.textContent = "DAEMON NOT REACHABLE"; mode.className = "mode down";
    problems.push("The daemon does not answer: " + (doc.reason || "unknown reason"));
  } else {
    const sim = simulated(doc);
    mode.textContent = sim === null ? "real or simulated: unknown" : sim ? "SIMULATED: no probe moves" : "REAL winch";
    mode.className = "mode " + (sim ? "sim" : "real");
    problems.push(...alarms(doc, "", []));
  }
  banner.hidden = problems.length === 0;
  banner.replaceChildren(...problems.map((p) => el("p", {}, p)));
  const d = doc.daemon || {};
  $("#clock").textContent = (d.wall_time ? utc(d.wall_time) + " UTC" : utc(doc.read_at) + " UTC (page)")
    + (doc.clock ? (doc.clock.synchronised ? ", synchronised" : ", NOT synchronised") : "");
  const link = doc.link || {}, fix = doc.fix || {}, cast = doc.cast || {}, winch = doc.winch || {};
  const journal = doc.journal || {};
  const summary = [
    card("Link", [["port", link.port], ["up", link.up], ["last frame age s", fix.age_s],
      ["port losses", link.port_losses]], link.up === false),
    card("Last fix", [["lat °", fix.lat_e7 !== undefined ? fix.lat_e7 / 1e7 : null],
      ["lon °", fix.lon_e7 !== undefined ? fix.lon_e7 / 1e7 : null],
      ["sonar m", fix.sonar_distance_mm !== undefined ? fix.sonar_distance_mm / 1000 : null],
      ["confidence %", fix.sonar_confidence_pct]]),
    card("Cast", [["phase", cast.phase], ["cast", cast.cast_id], ["planned m", cast.planned_depth_m],
      ["depth m", cast.depth_m]]),
    card("Winch", [["backend", winch.backend], ["at home", winch.at_home], ["moving", winch.moving],
      ["fault", winch.fault], ["sensor fault", winch.sensor_fault]],
      Boolean(winch.fault || winch.sensor_fault)),
    card("Journal", [["writable", journal.writable], ["pending rows", journal.pending_rows],
      ["free MB", journal.disk_free_bytes ? Math.round(journal.disk_free_bytes / 1e6) : null]],
      journal.writable === false),
  ];
  for (const name of ["sonde", "sonar"]) {
    if (doc[name] && typeof doc[name] === "object") summary.push(card(name[0].toUpperCase() + name.slice(1),
      Object.entries(doc[name])));
  }
  if (latestSonde) summary.push(latestSonde);
  if (latestSonar) summary.push(latestSonar);
  $("#summary").replaceChildren(...summary);
  const all = [];
  for (const [name, section] of Object.entries(doc)) {
    if (section && typeof section === "object") all.push(card(name, Object.entries(section)));
    else all.push(card(name, [["value", section]]));
  }
  $("#sections").replaceChildren(...all);
  track(cast, d.wall_time || doc.read_at);
}

function track(cast, now) {
  if (cast.cast_id !== null && cast.cast_id !== undefined && cast.phase && cast.phase !== "idle") {
    if (cast.cast_id !== live.cast) {
      live.cast = cast.cast_id; live.points = [];
      backfill(cast.cast_id);
    }
    live.points.push([now, cast.depth_m || 0]);
    if (live.points.length > 7200) live.points.shift();
    $("#live-caption").textContent = `Cast ${cast.cast_id}: ${cast.phase}, ${show(cast.depth_m)} m`
      + ` of ${show(cast.planned_depth_m)} m planned`;
  } else if (live.cast !== null) {
    $("#live-caption").textContent = `Cast ${live.cast} (last): depth against time`;
  }
  chart($("#live-chart"), live.points, live.points.length ? live.points[0][0] : 0);
}
async function backfill(castId) {
  try {
    const p = await getJSON(`/api/casts/${castId}/profile`);
    if (live.cast !== castId) return;
    const earlier = p.samples.map((s) => [s.t_s, s.depth_m]).filter((s) => !live.points.length || s[0] < live.points[0][0]);
    live.points = earlier.concat(live.points);
  } catch (e) { /* the journal may not have the cast yet: the live points suffice */ }
}

// Depth (down) against time (s since the first point), as a polyline in an SVG.
function chart(svg, points, t0) {
  const W = 360, H = 200, L = 34, B = 18, T = 6, R = 6;
  const xs = points.map((p) => p[0] - t0), ys = points.map((p) => p[1]);
  const xmax = Math.max(10, ...xs), ymax = Math.max(1, ...ys);
  const x = (v) => L + (v / xmax) * (W - L - R), y = (v) => T + (v / ymax) * (H - T - B);
  const nodes = [el("svg:line", { x1: L, y1: T, x2: L, y2: H - B, stroke: "#789" }),
    el("svg:line", { x1: L, y1: H - B, x2: W - R, y2: H - B, stroke: "#789" }),
    el("svg:text", { x: 2, y: T + 8 }, "0 m"), el("svg:text", { x: 2, y: H - B }, ymax.toFixed(1) + " m"),
    el("svg:text", { x: W - R - 40, y: H - 4 }, Math.round(xmax) + " s")];
  if (points.length) {
    nodes.push(el("svg:polyline", { id: svg.id + "-line", fill: "none", stroke: "#06c", "stroke-width": 2,
      points: points.map((p) => `${x(p[0] - t0).toFixed(1)},${y(p[1]).toFixed(1)}`).join(" ") }));
  }
  svg.replaceChildren(...nodes);
}

async function poll() {
  let doc;
  try { doc = await getJSON("/api/status"); }
  catch (e) { doc = { reachable: false, reason: "the page's server does not answer: " + e.message }; }
  renderStatus(doc);
}

async function loadSurveys() {
  let list;
  try { list = (await getJSON("/api/surveys")).surveys; }
  catch (e) { $("#surveys tbody").replaceChildren(row([e.message], 6)); return; }
  const body = $("#surveys tbody");
  body.replaceChildren(...list.slice().reverse().map((s) => {
    const tr = row([s.id, utc(s.start_wall_s), utc(s.end_wall_s).slice(11), s.stations, s.measured,
      s.simulated === null ? "?" : s.simulated ? "simulated" : "real"]);
    tr.dataset.survey = s.id;
    if (s.id === chosenSurvey) tr.className = "chosen";
    tr.addEventListener("click", () => chooseSurvey(s.id));
    return tr;
  }));
  if (chosenSurvey === null && list.length) chooseSurvey(list[list.length - 1].id);
}
function row(cells, span) {
  const tr = el("tr");
  for (const c of cells) tr.append(span ? el("td", { colspan: span }, show(c)) : el("td", {}, show(c)));
  return tr;
}

async function chooseSurvey(id) {
  chosenSurvey = id;
  for (const tr of document.querySelectorAll("#surveys tbody tr")) {
    tr.className = Number(tr.dataset.survey) === id ? "chosen" : "";
  }
  const dl = $("#downloads");
  dl.replaceChildren(`Survey ${id}: `);
  for (const [fmt, what] of [["csv", "CSV samples"], ["geojson", "GeoJSON"], ["nc", "NetCDF-CF"]]) {
    dl.append(el("a", { href: `/download/survey/${id}.${fmt}`, download: `survey-${id}.${fmt}` }, what), " ");
  }
  try {
    const data = await getJSON(`/api/surveys/${id}/casts`);
    if (chosenSurvey !== id) return;
    drawMap(data);
    $("#casts tbody").replaceChildren(...data.casts.map((c) => {
      const tr = row([c.id, utc(c.start_wall_s), c.outcome || "running", c.planned_depth_m, c.reached_depth_m]);
      tr.dataset.cast = c.id;
      tr.addEventListener("click", () => chooseCast(c.id));
      return tr;
    }));
    const measured = data.casts.filter((c) => c.samples > 0);
    if (measured.length) chooseCast(measured[measured.length - 1].id);
  } catch (e) { $("#map-title").textContent = "Stations: " + e.message; }
  try {
    const ev = await getJSON(`/api/events?survey=${id}`);
    if (chosenSurvey !== id) return;
    $("#events").replaceChildren(...ev.events.slice(-200).reverse().map((e) =>
      el("li", {}, `${utc(e.wall_s).slice(11)} ${e.kind} ${Object.keys(e.detail).length ? show(e.detail) : ""}`)));
  } catch (e) { $("#events").replaceChildren(el("li", {}, e.message)); }
}

// Stations in metres east and north of the survey's south-west corner, one
// scale both ways (a metre is a metre), no tiles: the boat is offline.
function drawMap(data) {
  const svg = $("#map"), W = 360, H = 260, pad = 24;
  $("#map-title").textContent = data.origin ? `Stations: metres from ${data.origin}` : "Stations: none yet";
  const cs = data.casts;
  const ex = Math.max(1, ...cs.map((c) => c.east_m)), ny = Math.max(1, ...cs.map((c) => c.north_m));
  const k = Math.min((W - 2 * pad) / ex, (H - 2 * pad) / ny);
  const nodes = [el("svg:text", { x: pad, y: H - 4 }, "0"),
    el("svg:text", { x: W - 70, y: H - 4 }, `${Math.round(ex)} m east`),
    el("svg:text", { x: 2, y: 12 }, `${Math.round(ny)} m north`)];
  for (const c of cs) {
    const cx = pad + c.east_m * k, cy = H - pad - c.north_m * k;
    const done = c.outcome === "completed";
    const dot = el("svg:circle", { cx: cx.toFixed(1), cy: cy.toFixed(1), r: 5, fill: done ? "#06c" : "#fff",
      stroke: "#06c", class: "station" });
    dot.append(el("svg:title", {}, `cast ${c.id}: ${c.outcome || "running"}`));
    dot.addEventListener("click", () => chooseCast(c.id));
    nodes.push(dot, el("svg:text", { x: (cx + 7).toFixed(1), y: (cy + 3).toFixed(1) }, String(c.id)));
  }
  svg.replaceChildren(...nodes);
}

async function chooseCast(id) {
  chosenCast = id;
  for (const tr of document.querySelectorAll("#casts tbody tr")) {
    tr.className = Number(tr.dataset.cast) === id ? "chosen" : "";
  }
  const box = $("#profile");
  let p;
  try { p = await getJSON(`/api/casts/${id}/profile`); }
  catch (e) { if (chosenCast === id) box.replaceChildren(el("p", {}, e.message)); return; }
  if (chosenCast !== id) return;
  $("#profile-title").textContent = `Profile of cast ${id}: ${p.samples.length} depth samples, `
    + `${p.sonde.length} sonde readings`;
  const plots = [];
  const t0 = p.samples.length ? p.samples[0].t_s : 0;
  plots.push(profilePlot("depth (winch) against time, s", p.samples.map((s) => [s.t_s - t0, s.depth_m])));
  const names = new Set();
  for (const s of p.sonde) for (const n of Object.keys(s.values || {})) names.add(n);
  for (const n of names) {
    const pts = p.sonde.filter((s) => s.values[n] !== null && s.values[n] !== undefined && s.depth_m !== null)
      .map((s) => [s.values[n], s.depth_m]);
    plots.push(profilePlot(n, pts));
  }
  box.replaceChildren(...plots);
}
// One parameter (x) against depth (y, down): a small SVG with its range written.
function profilePlot(name, pts) {
  const fig = el("figure", { class: "profile" });
  fig.append(el("figcaption", {}, name));
  const svg = el("svg:svg", { viewBox: "0 0 160 160", role: "img", "aria-label": name + " against depth" });
  if (pts.length) {
    const xs = pts.map((q) => q[0]), ys = pts.map((q) => q[1]);
    const x0 = Math.min(...xs), x1 = Math.max(...xs), y1 = Math.max(0.1, ...ys);
    const sx = (v) => 8 + ((v - x0) / ((x1 - x0) || 1)) * 144, sy = (v) => 14 + (v / y1) * 130;
    svg.append(el("svg:polyline", { fill: "none", stroke: "#a40", "stroke-width": 1.5, class: "profile-line",
      points: pts.map((q) => `${sx(q[0]).toFixed(1)},${sy(q[1]).toFixed(1)}`).join(" ") }),
      el("svg:text", { x: 4, y: 10 }, `${show(x0)} … ${show(x1)}`),
      el("svg:text", { x: 4, y: 157 }, `0 … ${y1.toFixed(1)} m`));
  } else svg.append(el("svg:text", { x: 4, y: 80 }, "no readings"));
  fig.append(svg);
  return fig;
}

// The sonde's and the sonar's last readings are in the journal, not the status:
// every 5 s is enough.
async function pollSonde() {
  try {
    const got = await getJSON("/api/latest");
    const p = got.sonar;
    latestSonar = p ? card("Sonar (last reading)", [["age s", p.age_s], ["distance m", p.distance_m],
      ["confidence %", p.confidence_pct], ["valid", p.valid]], !p.valid) : null;
    const s = got.sonde;
    if (!s) { latestSonde = null; return; }
    const rows = [["age s", s.age_s], ["status", s.status], ["depth m", s.depth_m]];
    for (const [k, v] of Object.entries(s.values || {})) if (v !== null && k !== "depth") rows.push([k, v]);
    if (s.error) rows.push(["error", s.error]);
    latestSonde = card("Sonde (last reading)", rows, s.status !== "ok");
  } catch (e) { latestSonde = null; }
}

poll();
setInterval(poll, POLL_MS);
pollSonde();
setInterval(pollSonde, 5000);
loadSurveys();
setInterval(loadSurveys, 30000);
