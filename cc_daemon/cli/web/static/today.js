// "Today" and "Take it home": the journal's surveys, the chosen survey's map, casts,
// profiles and events, and its downloads. Read-only: it only ever sends GET.
import { depthTime, profile, surveyMap } from "./draw.js";
import { chunk, el, prose } from "./dom.js";
import { bedLayers, bedLegend, binnedLayers, scienceFiles, stationsTable, stratification } from "./science.js";
import { clock, eventSentence, metres, plural, unitText, utc, words } from "./words.js";

export { chunk, el, prose };

const $ = (sel) => document.querySelector(sel);
export const today = { survey: null, latest: null, cast: null, map: null, profile: null, casts: [],
  science: null, scienceTimer: null };

export async function getJSON(url) {
  const r = await fetch(url, { cache: "no-store" });
  const body = await r.json().catch(() => ({ error: r.statusText }));
  if (!r.ok) throw new Error(body.error || r.statusText);
  return body;
}

function counted(stations, castable, measured) {
  return [chunk(`${plural(stations, "station")} (${castable} castable)`, "stations"),
    chunk(`${measured} measured`, "measured")];
}
// The chosen survey's counts from its map, read just now: the list is read for every
// page at once and may be a few seconds older.
function recount(id, stations) {
  const row = document.querySelector(`#surveys button[data-survey="${id}"]`);
  if (!row) return;
  const [all, measured] = counted(stations.length, stations.filter((s) => s.castable).length,
    stations.filter((s) => s.measured).length);
  row.querySelector(".stations").replaceWith(all);
  row.querySelector(".measured").replaceWith(measured);
}

function kind(s) {
  return s.simulated === null ? "real or simulated: not recorded" : s.simulated ? "simulated" : "real";
}

export async function loadSurveys(first) {
  let list;
  try { list = (await getJSON("/api/surveys")).surveys; }
  catch (e) { $("#surveys").replaceChildren(el("li", {}, e.message)); return; }
  $("#surveys").replaceChildren(...list.slice().reverse().map((s) => {
    const item = el("li", {}, el("button", { type: "button", class: "row", "data-survey": s.id },
      chunk(`Survey ${s.id}`, "strong"), chunk(`${utc(s.start_wall_s)}–${clock(s.end_wall_s)} UTC`),
      ...counted(s.stations, s.castable, s.measured), chunk(kind(s))));
    item.firstChild.addEventListener("click", () => chooseSurvey(s.id));
    if (s.id === today.survey) item.firstChild.classList.add("chosen");
    return item;
  }));
  if (!list.length) $("#surveys").replaceChildren(el("li", {}, "No survey in the journal yet."));
  if (!list.length) return;
  const newest = list[list.length - 1].id;
  const following = first || today.survey === null || today.survey === today.latest;
  today.latest = newest;
  // Whoever looks at the latest survey follows the one under way, a new one included.
  if (following && today.survey !== newest) await chooseSurvey(newest);
  else if (today.survey === newest) await refreshSurvey(newest);  // its track and casts grow
}

export async function chooseSurvey(id) {
  today.survey = id;
  if (today.profile && today.profile.cast.session_id !== id) {  // another survey's cast
    today.cast = today.profile = null;
    $("#profile-title").textContent = "Profiles";
    $("#profiles").replaceChildren(el("p", {}, "No cast of this survey has readings yet."));
  }
  for (const b of document.querySelectorAll("#surveys button")) {
    b.classList.toggle("chosen", Number(b.dataset.survey) === id);
  }
  today.science = null;
  clearTimeout(today.scienceTimer);
  downloads(id);
  showScience();
  await refreshSurvey(id, true);
}

async function refreshSurvey(id, choose) {
  try {
    const data = await getJSON(`/api/surveys/${id}/casts`);
    if (today.survey !== id) return;
    today.casts = data.casts;
    recount(id, data.stations);
    today.map = prepareMap(data);
    drawMap();
    $("#casts").replaceChildren(...data.casts.map(castRow));
    const measured = data.casts.filter((c) => c.samples > 0);
    if (choose && measured.length) await chooseCast(measured[measured.length - 1].id);
    await loadEvents(id, data.casts);
    await loadScience(id);
  } catch (e) { $("#map-title").textContent = `Map: ${e.message}`; }
}

function outcomeWords(c) {
  if (!c.outcome) return "running";
  if (c.outcome === "completed") return "measured";
  if (c.outcome === "skipped-shallow") return "skipped: too shallow";
  if (c.outcome === "aborted") return `aborted${c.reason ? ": " + c.reason.replace(/^winch fault: /, "") : ""}`;
  if (c.outcome === "unfinished") return `unfinished: ${c.reason || "the probe did not come home"}`;
  return words(c.outcome);
}

function castRow(c) {
  const planned = c.planned_depth_m > 0 ? ` of ${metres(c.planned_depth_m)} planned` : "";
  const depth = c.outcome === "skipped-shallow" ? `planned ${metres(c.planned_depth_m)}: under the minimum`
    : `reached ${metres(c.reached_depth_m)}${planned || ", no cast planned"}`;
  const item = el("li", {}, el("button", { type: "button", class: "row", "data-cast": c.id },
    chunk(`${c.station || "?"} · cast ${c.id}`, "strong"), chunk(`${clock(c.start_wall_s)} UTC`),
    el("span", {}, outcomeWords(c)), chunk(depth), chunk(`water ${metres(c.water_depth_m)}`)));
  item.firstChild.addEventListener("click", () => chooseCast(c.id));
  if (c.id === today.cast) item.firstChild.classList.add("chosen");
  return item;
}

function prepareMap(data) {
  const byCast = new Map(data.casts.map((c) => [c.id, c]));
  const stations = data.stations.map((s) => {
    const casts = s.cast_ids.map((id) => byCast.get(id)).filter(Boolean);
    const last = casts[casts.length - 1];
    const what = !last ? "planned, no cast asked" : last.outcome === "completed"
      ? metres(last.reached_depth_m) : outcomeWords(last).split(":")[0];
    return { ...s, outcome: last ? last.outcome : null, label: `${s.name} ${what}`,
      summary: !last ? "planned, no cast asked" : `cast ${last.id}, ${outcomeWords(last)}`, casts };
  });
  return { origin: data.origin, frame: data.frame, track: data.track, stations };
}

export function drawMap() {
  const data = today.map;
  if (!data || !data.origin) {
    $("#map-title").textContent = "Map: no track or station yet";
    $("#map").replaceChildren();
    return;
  }
  $("#map-title").textContent = `Map of survey ${today.survey}: ${plural(data.stations.length, "station")}`;
  surveyMap($("#map"), { ...data, bed: bedLayers(today.science, data.frame) },
    { onStation: (s) => chooseCast(s.cast_ids[s.cast_ids.length - 1]) });
}

export async function chooseCast(id) {
  today.cast = id;
  for (const b of document.querySelectorAll("#casts button")) {
    b.classList.toggle("chosen", Number(b.dataset.cast) === id);
  }
  let p;
  try { p = await getJSON(`/api/casts/${id}/profile`); }
  catch (e) { if (today.cast === id) $("#profiles").replaceChildren(el("p", {}, e.message)); return; }
  if (today.cast !== id) return;
  today.profile = p;
  drawProfile();
}

// The way down (soaking, descents, dwells) until the first reading on the way up; a
// probe that could not come home is held where it stranded, neither down nor up.
function ways(readings) {
  const held = readings.filter((r) => r.phase === "stranded");
  const moving = readings.filter((r) => r.phase !== "stranded");
  const up = moving.findIndex((r) => r.phase === "ascending" || r.phase === "aborting");
  return up < 0 ? [moving, [], held] : [moving.slice(0, up), moving.slice(up), held];
}

// The layers of one parameter's profile: each a series the chart draws apart. More
// layers are drawn the same way.
export function profileLayers(p, name, binnedWays = new Set()) {
  const usable = (r) => typeof r.values[name] === "number" && typeof r.depth_m === "number";
  const [down, up, held] = ways(p.sonde.filter(usable));
  // Under its binned profile a way's readings are points; alone (no bins yet, or bins
  // made before the cast came up), a line joins them.
  const layer = (cls, label, rs) => {
    const under = binnedWays.has(cls);
    return { cls: under ? `${cls} raw` : cls, label: under ? `${label}: readings` : label, line: !under,
      points: rs.map((r) => [r.values[name], r.depth_m]) };
  };
  return [layer("down", "way down", down), layer("up", "way up", up), layer("held", "stranded", held)]
    .filter((l) => l.points.length);
}

export function drawProfile() {
  const p = today.profile;
  if (!p) return;
  const c = p.cast;
  $("#profile-title").textContent = `Profiles of cast ${c.id} at ${c.station || "?"}: `
    + `${plural(p.samples.filter((s) => s.sampled).length, "depth sample")}, `
    + `${plural(p.sonde.length, "sonde reading")}`;
  const t0 = p.samples.length ? p.samples[0].t_s : 0;
  const guessed = p.samples.some((s) => s.low_m !== null);
  const keys = [["measured", "measured-key"]];
  if (guessed) keys.push(["estimate, its range hatched", "estimate-key"]);
  if (p.samples.some((s) => !s.sampled)) keys.push(["at the fault, between samples", "fault-key"]);
  if (c.planned_depth_m > 0) keys.push(["planned", "planned-key"]);
  const drawn = [figure("The winch's depth against time", keys, (svg) => depthTime(svg,
    p.samples.map((s) => ({ t: s.t_s - t0, depth: s.depth_m, low: s.low_m, high: s.high_m,
      sampled: s.sampled })), { planned: c.planned_depth_m }))];
  for (const q of p.parameters || []) {
    if (q.name === "depth" || !p.sonde.some((r) => typeof r.values[q.name] === "number")) continue;
    const u = unitText(q.unit);
    const axis = `${q.name}${u ? ` (${u})` : ""}`;
    const binned = binnedLayers(today.science, c.id, q.name, p.sonde.length);
    const binnedWays = new Set(binned.map((l) => l.cls.split(" ")[0]));
    const layers = profileLayers(p, q.name, binnedWays).concat(binned);
    const marks = q.name === "temperature" ? stratification(today.science, c.id) : null;
    const keys = layers.map((l) => [l.label, l.cls.split(" ").map((k) => `${k}-key`).join(" ")]);
    if (marks && marks.thermocline !== null) keys.push([`thermocline ${metres(marks.thermocline)}`, "thermocline-key"]);
    if (marks && marks.top !== null && marks.bottom !== null) {
      keys.push([`metalimnion ${metres(marks.top)} to ${metres(marks.bottom)}`, "metalimnion-key"]);
    }
    const f = figure(`${q.long_name}${u ? ` (${u})` : ""}`, keys,
      (svg) => profile(svg, layers, { label: axis, marks }));
    f.svg.dataset.parameter = q.name;
    drawn.push(f);
  }
  $("#profiles").replaceChildren(...drawn.map((f) => f.fig));
  for (const f of drawn) f.draw(f.svg);  // once in the page: drawn at the width shown
}

function figure(title, keys, draw) {
  const svg = document.createElementNS("http://www.w3.org/2000/svg", "svg");
  svg.setAttribute("role", "img");
  svg.setAttribute("aria-label", title);
  const legend = el("p", { class: "legend" }, ...keys.map(([text, cls]) => chunk(text, `key ${cls}`)));
  const fig = el("figure", { class: "profile" }, el("figcaption", {}, title), svg, legend);
  return { fig, svg, draw };
}

async function loadEvents(id, casts) {
  let ev;
  try { ev = await getJSON(`/api/events?survey=${id}`); }
  catch (e) { $("#events").replaceChildren(el("li", {}, e.message)); return; }
  if (today.survey !== id) return;
  // The casts' beginnings and ends belong to the day's story too.
  const told = ev.events.map((e) => ({ t: e.wall_s, text: eventSentence(e), detail: e.detail }));
  for (const c of casts) {
    told.push({ t: c.start_wall_s, text: `Cast ${c.id} at ${c.station || "?"} started: `
      + `${c.planned_depth_m > 0 ? metres(c.planned_depth_m) + " planned" : "no cast planned"}, `
      + `water ${metres(c.water_depth_m)}.`, detail: { plan: c.plan } });
    if (c.end_wall_s) {
      told.push({ t: c.end_wall_s, text: `Cast ${c.id} at ${c.station || "?"} ended: `
        + `${outcomeWords(c)}, reached ${metres(c.reached_depth_m)}.`, detail: null });
    }
  }
  told.sort((a, b) => b.t - a.t);
  $("#events").replaceChildren(...told.slice(0, 300).map((e) => {
    const item = el("li", {}, chunk(`${clock(e.t)} UTC`, "time"), " ", prose(e.text));
    if (e.detail && Object.keys(e.detail).length) {
      item.append(el("details", {}, el("summary", {}, "details"),
        el("pre", {}, JSON.stringify(e.detail, null, 1))));
    }
    return item;
  }));
}

// Each download, and the command that writes the same file.
const FILES = [
  ["csv", "Depth samples (CSV)", "the winch's depth each second, with each cast's station; "
    + "an estimated depth comes with its range", ["export", "--format csv"]],
  ["sonde.csv", "The sonde's readings (CSV)", "temperature, pH, oxygen, chlorophyll: one row "
    + "per reading, the units in the header", ["sonde export", "--format csv"]],
  ["sonde.nc", "The sonde's profiles (NetCDF-CF)", "the same readings as CF profiles",
    ["sonde export", "--format netcdf", "-o FILE"]],
  ["geojson", "Stations, track and soundings (GeoJSON)", "for QGIS", ["export", "--format geojson"]],
  ["nc", "The winch's profiles (NetCDF-CF)", "depth against time, cast by cast",
    ["export", "--format netcdf", "-o FILE"]],
];

// The day's science: made by the server when asked (seconds on a long survey), then
// redrawn into the map, the stations table, the profiles and the files.
async function loadScience(id) {
  let doc;
  try { doc = await getJSON(`/api/surveys/${id}/science`); }
  catch (e) {
    if (today.survey !== id) return;
    for (const where of ["#numbers", "#science-files"]) $(where).replaceChildren(el("p", {}, `No science: ${e.message}`));
    $("#bed-legend").replaceChildren();
    return;
  }
  if (today.survey !== id) return;
  const fresh = !today.science || today.science.made_wall_s !== doc.made_wall_s;
  today.science = doc;
  clearTimeout(today.scienceTimer);
  if (!doc.current) {  // ask again when the server will make it again
    const wait = Math.max(1000, (doc.due_wall_s - Date.now() / 1000) * 1000 + 500);
    today.scienceTimer = setTimeout(() => { if (today.survey === id) loadScience(id); }, wait);
  }
  showScience();
  if (!fresh) return;
  drawMap();
  drawProfile();
}

function showScience() {
  const id = today.survey;
  $("#bed-legend").replaceChildren(...bedLegend(today.science));
  $("#numbers").replaceChildren(stationsTable(today.science, today.casts));
  $("#science-files").replaceChildren(el("p", {}, `The day's science of survey ${id}, as`
    + " cc-daemon map and cc-daemon profiles write it (JOURNAL: the journal this page reads):"),
  scienceFiles(today.science, id));
}

function downloads(id) {
  const list = el("ul", { class: "files" });
  for (const [fmt, title, what, [command, ...options]] of FILES) {
    const file = fmt.startsWith("sonde.") ? `${id}-${fmt}` : `${id}.${fmt}`;
    const line = el("span", { class: "command" }, chunk("The same file:"), " ", chunk("cc-daemon"), " ",
      chunk(command), " ", chunk("--db JOURNAL"), " ", chunk(`--survey ${id}`),
      ...options.flatMap((o) => [" ", chunk(o)]));
    list.append(el("li", {}, el("a", { href: `/download/survey/${file}`, download: `survey-${file}`,
      "data-format": fmt }, title), `: ${what}. `, line));
  }
  $("#downloads").replaceChildren(el("p", {}, `Survey ${id}, as the commands write it (JOURNAL: the`
    + " journal this page reads):"), list);
}
