// The day's science (GET /api/surveys/N/science, made by the page's server as
// `cc-daemon map` and `cc-daemon profiles` make it): the lake floor under the map, each
// station's numbers in a table, each cast's binned profile, and the science's files.
// Pure: documents in, elements and drawing data out; it never fetches anything.
import { chunk, el } from "./dom.js";
import { clock, metres, num, plural, words } from "./words.js";

// Longitude and latitude to the map's metres east and north (the server's LocalFrame).
export function toFrame(frame, point) {
  const k = (Math.PI / 180) * frame.radius_m;
  return [(point[0] - frame.lon0) * k * frame.cos_lat, (point[1] - frame.lat0) * k];
}

// The lake floor as the map draws it: shaded cells and contour lines in metres.
export function bedLayers(science, frame) {
  const bed = science && science.map;
  if (!bed || !frame || !bed.cells) return null;
  const cells = blocks(bed.cells).map(({ corners, depth }) => ({ points: corners.map((p) => toFrame(frame, p)), depth }));
  const contours = bed.contours.map((c) => ({
    depth: c.depth_m, lines: c.lines.map((line) => line.map((p) => toFrame(frame, p))) }));
  const deepest = Math.max(0.1, ...cells.map((c) => c.depth), ...contours.map((c) => c.depth));
  return { cells, contours, deepest };
}

// The grid's blocks, each with its corners in longitude and latitude: corner (i, j) of the
// fine grid is origin + i * di + j * dj; a block at the grid's edge ends with the grid.
export function blocks(g) {
  const at = (i, j) => [g.origin[0] + i * g.di[0] + j * g.dj[0], g.origin[1] + i * g.di[1] + j * g.dj[1]];
  const out = [];
  g.depths.forEach((row, bj) => row.forEach((depth, bi) => {
    if (depth === null) return;
    const i0 = bi * g.step, i1 = Math.min(i0 + g.step, g.nx), j0 = bj * g.step, j1 = Math.min(j0 + g.step, g.ny);
    out.push({ depth, corners: [at(i0, j0), at(i1, j0), at(i1, j1), at(i0, j1)] });
  }));
  return out;
}

// What the map's lake floor is: its shades' bar, and a sentence with its units and how
// far to trust it.
export function bedLegend(science) {
  const bed = science && science.map;
  if (!bed) return [];
  if (bed.why) return [`Lake floor: not mapped: ${bed.why}.`];
  const depths = blocks(bed.cells).map((b) => b.depth);
  if (!depths.length) {
    return [`Lake floor: no cell mapped yet from ${plural(bed.figures.soundings.kept, "sounding")}`
      + ` (${madeWords(science)}): a second line gives the first cells.`];
  }
  const bar = el("span", { class: "chunk" }, metres(Math.min(...depths), 1), " ",
    el("span", { class: "depth-bar" }), " ", metres(Math.max(...depths), 1));
  return [el("span", { class: "bar-line" }, "Depth: ", bar), bedWords(science)];
}

// When the science was made and, if the journal has grown since, when it is made again.
export function madeWords(science) {
  if (!science) return "";
  const made = `made ${clock(science.made_wall_s)} UTC`;
  return science.current ? made
    : `${made}; the journal has grown since: made again from ${clock(science.due_wall_s)} UTC`;
}

function bedWords(science) {
  const bed = science.map;
  const f = bed.figures;
  const levels = bed.contours.map((c) => c.depth_m).sort((a, b) => a - b);
  const every = levels.length > 1 ? ` contours every ${metres(levels[1] - levels[0], 1)};` : "";
  const trust = typeof f.cv_rmse_m === "number"
    ? `within about ${metres(f.cv_rmse_m)} (an estimate: cross-validated RMSE, ${plural(f.cv_predicted, "held-out block")})`
    : "a sketch: too few lines to estimate its accuracy";
  return `Lake floor from ${plural(f.soundings.kept, "sounding")} (${madeWords(science)}):`
    + ` deepest ${metres(f.max_depth_m, 1)};${every} ${trust}.`;
}

// Why a number is missing, as the stations table's `missing` column says it.
const MISSING = {
  mixed: "mixed: no thermocline", at_edge: "at the cast's edge", not_reached: "not reached",
  no_hypsography: "needs a lake map that can be trusted", too_few: "too few readings",
};

function cell(row, at, name, digits = 2) {
  const value = row[at[name]];
  if (typeof value === "number") return num(value, digits).replace(/^-(0\.?0*)$/, "$1");  // no "-0.0"
  const reasons = String(row[at.missing] || "").split(";").map((r) => r.split(":"));
  const why = reasons.find(([key]) => key === name.split(" [")[0]);
  return why ? MISSING[why[1]] || words(why[1]) : "–";
}

function range(row, at, top, bottom) {
  const a = row[at[top]], b = row[at[bottom]];
  return typeof a === "number" && typeof b === "number" ? `${num(a)}–${num(b)}` : cell(row, at, top);
}

// The mixed layer: from the surface to the metalimnion's top (none when that is the surface).
function mixedLayer(top) {
  if (typeof top !== "number") return null;
  return top > 0 ? `0–${num(top)}` : "none: stratified from the surface";
}

// Each column: its heading (with its unit) and how a row shows it.
const COLUMNS = [
  ["Thermocline (m)", (r, at) => cell(r, at, "thermocline [m]")],
  ["Mixed layer (m)", (r, at) => mixedLayer(r[at["metalimnion_top [m]"]]) || cell(r, at, "metalimnion_top [m]")],
  ["Metalimnion (m)", (r, at) => range(r, at, "metalimnion_top [m]", "metalimnion_bottom [m]")],
  ["Chlorophyll maximum (m)", (r, at) => cell(r, at, "dcm [m]")],
  ["Oxycline (m)", (r, at) => cell(r, at, "oxycline [m]")],
  ["O₂ under 2 mg/L from (m)", (r, at) => cell(r, at, "hypoxia_top [m]")],
  ["Surface, bottom (°C)", (r, at) => `${cell(r, at, "surface_temperature [degC]")}, ${cell(r, at, "bottom_temperature [degC]")}`],
  ["Schmidt stability (J/m²)", (r, at) => cell(r, at, "schmidt_stability [J/m2]", 1)],
];

// The stations table: one row per cast with a profile, named as the operator knows it.
export function stationsTable(science, casts) {
  const p = science && science.profiles;
  if (!p) return el("p", {}, "Working out the day's profiles…");
  if (p.why) return el("p", {}, `No profiles: ${p.why}.`);
  const at = Object.fromEntries(p.stations.header.map((h, i) => [h, i]));
  const named = new Map(casts.map((c) => [c.id, c.station]));
  const head = el("tr", {}, el("th", { scope: "col" }, "Station"),
    ...COLUMNS.map(([title]) => el("th", { scope: "col" }, title)));
  const rows = p.stations.rows.map((r) => {
    const id = r[at.cast_id];
    return el("tr", { "data-cast": id },
      el("th", { scope: "row" }, `${named.get(id) || "?"} · cast ${id}`),
      ...COLUMNS.map(([title, show]) => el("td", { "data-label": title }, show(r, at))));
  });
  const lags = p.lag_correction === "none" ? "not lag-corrected" : `its sensors' lags corrected (${p.lag_correction})`;
  const note = `Read from each cast's way down, binned every ${metres(p.bin_m)}, ${lags}, with`
    + ` rLakeAnalyzer's definitions (the same numbers as stations.csv below; ${madeWords(science)}).`;
  const said = p.notes.map((n) => ` ${n.charAt(0).toUpperCase()}${n.slice(1)}.`);
  return el("div", {}, el("table", { class: "numbers" }, el("thead", {}, head), el("tbody", {}, ...rows)),
    el("p", { class: "note" }, note, ...said));
}

// One cast's binned profile of one parameter: a layer per way, drawn over the readings.
// Only when the bins were made from every reading the page has of the cast: bins made
// while it ran are not drawn over its later readings.
export function binnedLayers(science, castId, name, readings) {
  const p = science && science.profiles;
  const found = p && p.binned && p.binned[String(castId)] && p.binned[String(castId)][name];
  if (!found || (p.readings || {})[String(castId)] !== readings) return [];
  const how = `binned every ${metres(p.bin_m)}${corrected(p, name) ? ", lag-corrected" : ""}`;
  return [["down", "way down"], ["up", "way up"]].filter(([way]) => found[way].length)
    .map(([way, label]) => ({ cls: `${way} binned`, label: `${label}, ${how}`, dots: false,
      points: found[way].map(([v, d]) => [v, d]) }));
}

// Whether a parameter's binned values were corrected for its sensor's lag.
function corrected(p, name) {
  return p.lag_correction !== "none" && (p.lags_s || {})[name] > 0;
}

// The thermocline and the metalimnion of a cast, to mark on its temperature profile.
export function stratification(science, castId) {
  const p = science && science.profiles;
  if (!p || p.why) return null;
  const at = Object.fromEntries(p.stations.header.map((h, i) => [h, i]));
  const row = p.stations.rows.find((r) => r[at.cast_id] === castId);
  if (!row) return null;
  const value = (name) => (typeof row[at[name]] === "number" ? row[at[name]] : null);
  return { thermocline: value("thermocline [m]"), top: value("metalimnion_top [m]"),
    bottom: value("metalimnion_bottom [m]") };
}

// The science's files, each with the command that writes the same file.
const PRODUCTS = [
  ["bathymetry.nc", "map", "The lake floor's grid (NetCDF-CF, ACDD)", "depth, its distance to a sounding"],
  ["depth.tif", "map", "The lake floor (GeoTIFF)", "for QGIS"],
  ["contours.geojson", "map", "Depth contours (GeoJSON)", "for QGIS"],
  ["hypsography.csv", "map", "Area and volume at each depth (CSV)", "the hypsographic curve"],
  ["profiles.csv", "profiles", "Binned profiles (CSV)", "lag-corrected, each cast's way down and way up"],
  ["profiles.nc", "profiles", "Binned profiles (NetCDF-CF)", "the same, as CF profiles"],
  ["stations.csv", "profiles", "Stations' numbers (CSV)", "the table above"],
  ["stations.geojson", "profiles", "Stations' numbers (GeoJSON)", "the table above, for QGIS"],
];

export function scienceFiles(science, id) {
  if (!science) return el("p", {}, "Working out the day's science…");
  const list = el("ul", { class: "files" });
  for (const [name, part, title, what] of PRODUCTS) {
    const made = science[part] || {};
    const command = el("span", { class: "command" }, chunk("The same file:"), " ", chunk("cc-daemon"), " ",
      chunk(part), " ", chunk("--db JOURNAL"), " ", chunk(`--survey ${id}`), " ", chunk("-o DIR"), " ",
      chunk(`(DIR/${name})`));
    if ((made.files || []).includes(name)) {
      list.append(el("li", {}, el("a", { href: `/download/survey/${id}/${name}`, download: `survey-${id}-${name}`,
        "data-format": name }, title), `: ${what}. `, command));
    } else {
      const why = made.why || (made.notes || []).find((n) => n.startsWith(name)) || "not made";
      list.append(el("li", {}, el("strong", {}, title), `: not made: ${why}.`));
    }
  }
  return list;
}
