// The field page's "Now": polls /api/status once a second and says, in plain words with
// units, what the daemon is doing; a fault as sentences; and, when the daemon stops
// answering, the last state it reported and how old it is (kept across a reload).
// Read-only: it only ever sends GET.
import { depthTime } from "./draw.js";
import {
  ago, clock, faultSentences, latlon, metres, num, phaseWords, plural, probeWhere, stateSentence,
  unknownAlarms, utc, withUnit, words,
} from "./words.js";
import { drawMap, drawProfile, el, getJSON, loadSurveys, prose, today } from "./today.js";

const $ = (sel) => document.querySelector(sel);
const POLL_MS = 1000;
const KEPT = "cc-daemon:last-state";  // the last state heard, in this browser
const live = { cast: null, points: [] };  // the running cast: {t (wall s), depth, low, high}
let latest = null;  // the sonde's and the sonar's last readings (/api/latest)
let heard = kept();  // {doc, at}: the last state the daemon reported

function kept() {
  try { return JSON.parse(localStorage.getItem(KEPT)) || null; } catch (e) { return null; }
}
function keep(doc) {
  heard = { doc, at: doc.read_at || Date.now() / 1000 };
  try { localStorage.setItem(KEPT, JSON.stringify(heard)); } catch (e) { /* private mode: memory only */ }
}

function card(title, rows, bad) {
  const dl = el("dl");
  for (const [k, v] of rows) dl.append(el("dt", {}, k), el("dd", {}, prose(v)));
  return el("div", { class: bad ? "card bad" : "card" }, el("h3", {}, title), dl);
}
function sentence(text) { return /[.!?]$/.test(text) ? text : `${text}.`; }
function simulated(doc) {
  const d = doc.daemon || {};
  if (typeof d.simulated === "boolean") return d.simulated;
  const backend = (doc.winch || {}).backend;
  return backend ? backend === "sim" || backend.endsWith("-mock") : null;
}
function stationOf(castId) {
  const found = today.casts.find((c) => c.id === castId);
  return found ? found.station : null;
}

function render(doc) {
  if (doc.reachable) keep(doc);
  const shown = doc.reachable ? doc : heard && heard.doc;
  const stale = doc.reachable ? 0 : heard ? Date.now() / 1000 - heard.at : null;
  header(doc, shown, stale);
  banner(doc, shown, stale);
  now(shown, stale);
}

function header(doc, shown, stale) {
  const mode = $("#mode");
  if (!doc.reachable) {
    mode.textContent = "DAEMON NOT ANSWERING";
    mode.className = "mode down";
  } else {
    const sim = simulated(doc);
    mode.textContent = sim === null ? "real or simulated: unknown" : sim ? "SIMULATED: no probe moves"
      : "REAL winch";
    mode.className = `mode ${sim ? "sim" : "real"}`;
  }
  const d = (shown && shown.daemon) || {}, c = (shown && shown.clock) || {};
  const sync = c.synchronised === true ? ", synchronised" : c.synchronised === false ? ", NOT synchronised" : "";
  $("#clock").textContent = doc.reachable
    ? `${utc(d.wall_time || doc.read_at)} UTC${sync}`
    : heard ? `last heard ${utc(heard.at)} UTC, ${ago(stale)} ago` : "never heard";
}

function banner(doc, shown, stale) {
  const blocks = [];
  if (!doc.reachable) {
    blocks.push({ title: "The daemon does not answer.", lines: [
      sentence(doc.reason || "no reason given"),
      heard ? `Below is the last state it reported, ${ago(stale)} old (at ${clock(heard.at)} UTC): `
        + "it may have changed since." : "It has not answered since this page opened; "
        + "the journal's surveys are below (Today).",
    ] });
  }
  if (shown) {
    const when = doc.reachable ? "" : `Last known, ${ago(stale)} ago: `;
    for (const f of faultSentences(shown)) blocks.push({ title: when + f.title, lines: f.lines });
    const others = unknownAlarms(shown);
    if (others.length) blocks.push({ title: `${when}The daemon reports a fault.`, lines: others });
  }
  const box = $("#banner");
  box.hidden = blocks.length === 0;
  box.replaceChildren(...blocks.map((b) => el("div", { class: "fault" }, el("p", { class: "fault-title" },
    b.title), ...b.lines.map((line) => el("p", {}, prose(line))))));
}

function now(doc, stale) {
  if (!doc) {
    $("#state").textContent = "The daemon has not answered since this page opened.";
    $("#state").className = "state stale";  // nothing known: never the green of a good state
    $("#summary").replaceChildren();
    return;
  }
  const cast = doc.cast || {}, winch = doc.winch || {}, link = doc.link || {}, fix = doc.fix;
  const journal = doc.journal || {};
  const station = stationOf(cast.cast_id);
  const old = stale ? ` (as of ${clock(heard.at)} UTC, ${ago(stale)} ago)` : "";
  $("#state").textContent = stateSentence(doc, station) + old;
  $("#state").className = stale ? "state stale" : cast.fault_reported ? "state bad" : "state";
  const cards = [
    card("Autopilot link", [
      ["port", link.up ? `up: ${link.port} at ${link.baudrate} bit/s` : `DOWN: ${link.port || "?"}`],
      ["last frame", fix ? `${fix.frame}, ${ago(fix.age_s)} ago` : "none yet"],
      ["port losses", String(link.port_losses ?? "–")],
    ], link.up === false),
    card("Position (last fix)", fix ? [
      ["where", latlon(fix.lat_e7 / 1e7, fix.lon_e7 / 1e7)],
      ["water depth", `${metres(fix.sonar_distance_mm / 1000)} by the sonar, ${fix.sonar_confidence_pct} % sure`],
      ["altitude", metres(fix.alt_mm / 1000)],
      ["autopilot time", `${fix.timestamp_s} s (its bytes read ${fix.timestamp_order || "big"}-endian`
        + `${fix.timestamp_order_settled === false ? ", not yet settled" : ""})`],
    ] : [["where", "no fix yet"]]),
    card("Cast", [
      ["now", cast.phase && cast.phase !== "idle" ? `cast ${cast.cast_id}${station ? " at " + station : ""}: `
        + phaseWords(cast.phase) : "no cast running"],
      ["probe", probeWhere(cast.depth_m, winch.depth_low_m, winch.depth_high_m)],
      ["planned", cast.planned_depth_m > 0 ? metres(cast.planned_depth_m) : "–"],
    ], Boolean(cast.fault_reported)),
    card("Winch", [
      ["kind", `${winch.backend || "?"}${simulated(doc) ? " (simulated: no probe moves)" : ""}`],
      ["state", `${winch.moving ? "moving" : "stopped"}, ${winch.at_home ? "at home" : "not at home"}`],
      ["fault", winch.fault || "none"],
    ], Boolean(winch.fault || winch.sensor_fault)),
    card("Journal", [
      ["writes", journal.writable === false ? "NOT WRITABLE" : "writable"],
      ["waiting", plural(journal.pending_rows || 0, "row")],
      ["free space", typeof journal.disk_free_bytes === "number"
        ? `${num(journal.disk_free_bytes / 1e9, 1)} GB` : "–"],
    ], journal.writable === false),
  ];
  cards.push(...readings());
  $("#summary").replaceChildren(...cards);
  $("#summary").classList.toggle("stale", Boolean(stale));
  everything(doc);
  follow(doc);
}

// The sonde's and the sonar's last readings: from the journal, every 5 s.
function readings() {
  if (!latest) return [];
  const out = [], s = latest.sonde, p = latest.sonar;
  if (s) {
    const units = Object.fromEntries((latest.parameters || []).map((q) => [q.name, q]));
    const rows = [["taken", `${ago(s.age_s)} ago`], ["status", s.status],
      ["depth", metres(s.depth_m ?? s.line_out_m)]];
    for (const [k, v] of Object.entries(s.values || {})) {
      if (v === null || k === "depth") continue;
      rows.push([units[k] ? units[k].long_name : words(k), withUnit(v, units[k] ? units[k].unit : "")]);
    }
    if (s.error) rows.push(["error", s.error]);
    out.push(card("Sonde (last reading)", rows, s.status !== "ok"));
  }
  if (p) {
    out.push(card("Sonar (last reading)", [["taken", `${ago(p.age_s)} ago`],
      ["distance", metres(p.distance_m)], ["confidence", `${p.confidence_pct} %`],
      ["can be true", p.valid ? "yes" : "NO"]], !p.valid));
  }
  return out;
}

function everything(doc) {
  const all = [];
  for (const [name, section] of Object.entries(doc)) {
    const rows = section && typeof section === "object"
      ? Object.entries(section).map(([k, v]) => [words(k), typeof v === "object" && v !== null
        ? JSON.stringify(v) : String(v)])
      : [["value", String(section)]];
    all.push(card(name, rows));
  }
  $("#sections").replaceChildren(...all);
}

// The running cast's depth against time, drawn as it goes.
function follow(doc) {
  const cast = doc.cast || {}, winch = doc.winch || {};
  const t = (doc.daemon || {}).wall_time || doc.read_at;
  if (doc.reachable !== false && cast.cast_id !== null && cast.cast_id !== undefined
    && cast.phase && cast.phase !== "idle") {
    if (cast.cast_id !== live.cast) {
      live.cast = cast.cast_id;
      live.points = [];
      backfill(cast.cast_id);
      if (!stationOf(cast.cast_id)) loadSurveys(false);  // a new cast: its station's name
    }
    const last = live.points[live.points.length - 1];
    if (!last || t > last.t) {
      live.points.push({ t, depth: cast.depth_m || 0, low: winch.depth_low_m ?? null,
        high: winch.depth_high_m ?? null, sampled: true });
    }
    if (live.points.length > 7200) live.points.shift();
    live.planned = cast.planned_depth_m;
  }
  drawLive();
}
function drawLive() {
  const cap = $("#live-caption");
  cap.parentElement.classList.toggle("empty", live.cast === null);
  if (live.cast === null) {
    cap.textContent = "The running cast's depth against time: no cast since this page opened.";
    $("#live-chart").replaceChildren();
    return;
  }
  const station = stationOf(live.cast);
  cap.textContent = `Cast ${live.cast}${station ? " at " + station : ""}: depth against time`;
  const t0 = live.points.length ? live.points[0].t : 0;
  depthTime($("#live-chart"), live.points.map((p) => ({ ...p, t: p.t - t0 })), { planned: live.planned });
}
async function backfill(castId) {
  try {
    const p = await getJSON(`/api/casts/${castId}/profile`);
    if (live.cast !== castId) return;
    const first = live.points.length ? live.points[0].t : Infinity;
    const earlier = p.samples.filter((s) => s.sampled && s.t_s < first)
      .map((s) => ({ t: s.t_s, depth: s.depth_m, low: s.low_m, high: s.high_m, sampled: true }));
    live.points = earlier.concat(live.points);
  } catch (e) { /* the journal may not have the cast yet: the live points suffice */ }
}

async function poll() {
  let doc;
  try { doc = await getJSON("/api/status"); }
  catch (e) { doc = { reachable: false, reason: `the page's server does not answer: ${e.message}` }; }
  render(doc);
}
async function pollReadings() {
  try { latest = await getJSON("/api/latest"); } catch (e) { latest = null; }
}

// Each drawing is made at the width it is shown: drawn again when that changes (a phone
// turned, a window resized), once the change has settled.
function redrawn(selector, draw) {
  let width = 0, timer = null;
  new ResizeObserver(([entry]) => {
    const now = Math.round(entry.contentRect.width);
    if (now === width) return;
    width = now;
    clearTimeout(timer);
    timer = setTimeout(draw, 100);
  }).observe($(selector));
}
redrawn("#live-chart", drawLive);
redrawn("#map", drawMap);
redrawn("#profiles", drawProfile);

poll();
setInterval(poll, POLL_MS);
pollReadings();
setInterval(pollReadings, 5000);
loadSurveys(true);
setInterval(() => loadSurveys(false), 30000);
