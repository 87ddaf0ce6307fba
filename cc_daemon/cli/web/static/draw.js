// The field page's drawings, in SVG drawn at the size they are shown (one SVG unit is
// one CSS pixel, so text is the same size on a phone and a laptop): axes with ticks,
// numbers and units; a depth against time; a parameter against depth; the survey map.
// It draws what it is given and never fetches anything.

const NS = "http://www.w3.org/2000/svg";

export function svgEl(tag, attrs, text) {
  const node = document.createElementNS(NS, tag);
  for (const [k, v] of Object.entries(attrs || {})) if (v !== undefined) node.setAttribute(k, v);
  if (text !== undefined) node.textContent = text;
  return node;
}

// Round numbers for ticks: steps of 1, 2 or 5 times a power of ten.
export function niceTicks(lo, hi, count) {
  if (!(hi > lo)) return [lo];
  const raw = (hi - lo) / Math.max(1, count);
  const power = 10 ** Math.floor(Math.log10(raw));
  const step = [1, 2, 5, 10].map((m) => m * power).find((s) => s >= raw) || raw;
  const ticks = [];
  for (let v = Math.ceil(lo / step - 1e-9) * step; v <= hi + step * 1e-9; v += step) {
    ticks.push(Math.abs(v) < step * 1e-9 ? 0 : v);
  }
  return ticks;
}
// The largest 1, 2 or 5 times a power of ten not above `x`.
export function roundDown(x) {
  const power = 10 ** Math.floor(Math.log10(x));
  return [5, 2, 1].map((m) => m * power).find((s) => s <= x) || power;
}
function tickText(v, ticks) {
  const step = ticks.length > 1 ? Math.abs(ticks[1] - ticks[0]) : 1;
  const digits = Math.max(0, Math.min(4, -Math.floor(Math.log10(step) + 1e-9)));
  return v.toFixed(digits);
}

// The width an SVG is shown at: its own, else its container's.
export function widthOf(svg, fallback = 360) {
  const w = svg.getBoundingClientRect().width || (svg.parentElement || {}).clientWidth;
  return Math.max(240, Math.round(w || fallback));
}

// Axes in a box: x to the right, y down or up; ticks, their numbers and the axis titles.
// Returns scales from data to the SVG's units.
export function axes(svg, W, H, x, y) {
  const L = 46, R = 10, T = 10, B = 38;
  const sx = (v) => L + ((v - x.lo) / ((x.hi - x.lo) || 1)) * (W - L - R);
  const sy = y.down
    ? (v) => T + ((v - y.lo) / ((y.hi - y.lo) || 1)) * (H - T - B)
    : (v) => H - B - ((v - y.lo) / ((y.hi - y.lo) || 1)) * (H - T - B);
  const g = svgEl("g", { class: "axes" });
  g.append(svgEl("rect", { x: L, y: T, width: W - L - R, height: H - T - B, class: "plot-area" }));
  const xt = x.ticks || niceTicks(x.lo, x.hi, Math.max(2, Math.floor((W - L - R) / 70)));
  for (const v of xt) {
    const px = sx(v).toFixed(1);
    g.append(svgEl("line", { x1: px, x2: px, y1: T, y2: H - B, class: "grid" }),
      svgEl("text", { x: px, y: H - B + 14, "text-anchor": "middle", class: "tick" }, tickText(v, xt)));
  }
  const yt = y.ticks || niceTicks(y.lo, y.hi, Math.max(2, Math.floor((H - T - B) / 36)));
  for (const v of yt) {
    const py = sy(v).toFixed(1);
    g.append(svgEl("line", { x1: L, x2: W - R, y1: py, y2: py, class: "grid" }),
      svgEl("text", { x: L - 4, y: (sy(v) + 4).toFixed(1), "text-anchor": "end", class: "tick" },
        tickText(v, yt)));
  }
  g.append(svgEl("text", { x: L + (W - L - R) / 2, y: H - 6, "text-anchor": "middle", class: "axis-title" }, x.label),
    svgEl("text", { x: 12, y: T + (H - T - B) / 2, "text-anchor": "middle", class: "axis-title",
      transform: `rotate(-90 12 ${T + (H - T - B) / 2})` }, y.label));
  svg.append(g);
  return { sx, sy, box: { L, R, T, B, W, H } };
}

function path(points, sx, sy) {
  return points.map((p) => `${sx(p[0]).toFixed(1)},${sy(p[1]).toFixed(1)}`).join(" ");
}

// Depth (down) against time: measured depths solid; estimates dashed over the range the
// probe may be in; the winch's depth at a fault (between samples) a diamond; the plan.
// `points`: [{t, depth, low, high, sampled}] with t in seconds from the first.
export function depthTime(svg, points, { planned = null, height = 220 } = {}) {
  const W = widthOf(svg), H = height;
  svg.replaceChildren();
  svg.setAttribute("viewBox", `0 0 ${W} ${H}`);
  const ts = points.map((p) => p.t);
  const deepest = Math.max(1, ...points.map((p) => Math.max(p.depth, p.high ?? 0)),
    planned && planned > 0 ? planned : 0);
  const { sx, sy } = axes(svg, W, H, { lo: 0, hi: Math.max(10, ...ts), label: "time (s)" },
    { lo: 0, hi: deepest * 1.1, down: true, label: "depth (m)" });
  if (planned && planned > 0) {
    svg.append(svgEl("line", { x1: sx(0), x2: sx(Math.max(10, ...ts)), y1: sy(planned), y2: sy(planned),
      class: "planned" }));
  }
  const known = points.filter((p) => p.low === null || p.low === undefined);
  const guessed = points.filter((p) => !(p.low === null || p.low === undefined));
  if (guessed.length) {
    const top = guessed.map((p) => [p.t, p.low]), bottom = guessed.map((p) => [p.t, p.high]).reverse();
    svg.append(svgEl("polygon", { points: path(top.concat(bottom), sx, sy), class: "estimate-band" }));
    const from = known.length && known[known.length - 1].t < guessed[0].t ? [known[known.length - 1]] : [];
    svg.append(svgEl("polyline", { points: path(from.concat(guessed).map((p) => [p.t, p.depth]), sx, sy),
      class: "estimate-line" }));
  }
  if (known.length) {
    svg.append(svgEl("polyline", { points: path(known.map((p) => [p.t, p.depth]), sx, sy),
      class: "measured-line", id: svg.id ? svg.id + "-line" : undefined }));
  }
  for (const p of points.filter((q) => q.sampled === false)) {
    const x = sx(p.t), y = sy(p.depth);
    svg.append(svgEl("polygon", { points: `${x},${y - 5} ${x + 5},${y} ${x},${y + 5} ${x - 5},${y}`,
      class: "fault-point" }));
  }
}

// One parameter (x) against depth (y, down): each layer its own series, told apart
// by line and marker (the way down and the way up, the readings under a binned
// profile as points only). `layers`: [{cls, points: [[value, depth]], line, dots}];
// `marks`: the thermocline (a dashed line) and the metalimnion (a band), in metres.
export function profile(svg, layers, { label, height = 240, marks = null } = {}) {
  const W = widthOf(svg, 300), H = height;
  svg.replaceChildren();
  svg.setAttribute("viewBox", `0 0 ${W} ${H}`);
  const all = layers.flatMap((l) => l.points);
  if (!all.length) {
    svg.append(svgEl("text", { x: W / 2, y: H / 2, "text-anchor": "middle", class: "tick" }, "no readings"));
    return;
  }
  let lo = Math.min(...all.map((p) => p[0])), hi = Math.max(...all.map((p) => p[0]));
  if (hi - lo < 1e-6) { lo -= 0.5; hi += 0.5; }
  const pad = (hi - lo) * 0.05;
  const deepest = Math.max(0.5, ...all.map((p) => p[1]));
  const { sx, sy } = axes(svg, W, H, { lo: lo - pad, hi: hi + pad, label },
    { lo: 0, hi: deepest * 1.08, down: true, label: "depth (m)" });
  const x0 = sx(lo - pad), x1 = sx(hi + pad);
  if (marks && marks.top !== null && marks.bottom !== null) {
    svg.append(svgEl("rect", { x: x0, y: sy(marks.top), width: x1 - x0,
      height: Math.max(1, sy(marks.bottom) - sy(marks.top)), class: "metalimnion" }));
  }
  if (marks && marks.thermocline !== null) {
    svg.append(svgEl("line", { x1: x0, x2: x1, y1: sy(marks.thermocline), y2: sy(marks.thermocline),
      class: "thermocline" }));
  }
  for (const layer of layers) {
    if (!layer.points.length) continue;
    if (layer.line !== false) {
      svg.append(svgEl("polyline", { points: path(layer.points, sx, sy), class: `series ${layer.cls}` }));
    }
    if (layer.dots === false) continue;
    for (const p of layer.points) {
      svg.append(svgEl("circle", { cx: sx(p[0]).toFixed(1), cy: sy(p[1]).toFixed(1), r: 2.5,
        class: `dot ${layer.cls}` }));
    }
  }
}

// The lake floor under the map: each cell shaded by its depth, each contour a line; the
// places for the contours' labels (the middle of each level's longest line).
function drawBed(svg, bed, sx, sy) {
  const g = svgEl("g", { class: "bed" });
  for (const c of bed.cells) {
    const fill = shadeOf(c.depth, bed.deepest);  // its edge too: no hairline between cells
    g.append(svgEl("polygon", { points: path(c.points, sx, sy), class: "bed-cell", fill, stroke: fill }));
  }
  const labels = [];
  for (const c of bed.contours) {
    let longest = [];
    for (const line of c.lines) {
      g.append(svgEl("polyline", { points: path(line, sx, sy), class: "contour" }));
      if (line.length > longest.length) longest = line;
    }
    if (longest.length) {
      const p = longest[Math.floor(longest.length / 2)];
      labels.push({ x: sx(p[0]), y: sy(p[1]), text: `${+c.depth.toFixed(2)} m` });
    }
  }
  svg.append(g);
  return labels;
}
// A depth's shade: pale shallows to deep blue (as the legend's bar).
export function shadeOf(depth, deepest) {
  const f = Math.max(0, Math.min(1, depth / deepest));
  return `hsl(205, 65%, ${Math.round(90 - 55 * f)}%)`;
}

// Does box a overlap box b (SVG units)?
function overlap(a, b) {
  const w = Math.min(a.x + a.width, b.x + b.width) - Math.max(a.x, b.x);
  const h = Math.min(a.y + a.height, b.y + b.height) - Math.max(a.y, b.y);
  return w > 0 && h > 0 ? w * h : 0;
}
const LABEL_PLACES = [[8, 4], [8, -8], [-8, 4], [-8, -8], [0, -12], [0, 16], [14, 16], [-14, -14],
  [16, 4], [-16, 4], [0, -22], [0, 26]];

// The survey in metres east and north of its south-west corner, one scale both ways,
// no tiles (the boat is offline): the track, each station by name and outcome, each
// label where it covers no other label and no station.
export function surveyMap(svg, data, { onStation, height } = {}) {
  const W = widthOf(svg), H = height || Math.round(Math.min(Math.max(W * 0.75, 260), 520));
  svg.replaceChildren();
  svg.setAttribute("viewBox", `0 0 ${W} ${H}`);
  const corners = data.bed ? data.bed.cells.flatMap((c) => c.points) : [];
  const xs = data.track.map((p) => p[0]).concat(data.stations.map((s) => s.east_m), corners.map((p) => p[0]));
  const ys = data.track.map((p) => p[1]).concat(data.stations.map((s) => s.north_m), corners.map((p) => p[1]));
  if (!xs.length) return;
  const L = 46, R = 10, T = 10, B = 38;
  const ex = Math.max(20, Math.max(...xs) - Math.min(0, ...xs)), ny = Math.max(20, Math.max(...ys) - Math.min(0, ...ys));
  const k = Math.min((W - L - R) / (ex * 1.16), (H - T - B) / (ny * 1.16));
  const cx = (Math.min(0, ...xs) + Math.max(...xs)) / 2, cy = (Math.min(0, ...ys) + Math.max(...ys)) / 2;
  const half = { x: (W - L - R) / 2 / k, y: (H - T - B) / 2 / k };
  const { sx, sy } = axes(svg, W, H, { lo: cx - half.x, hi: cx + half.x, label: `metres east of ${data.origin}` },
    { lo: cy - half.y, hi: cy + half.y, label: "metres north" });
  const taken = [];
  const contourLabels = data.bed ? drawBed(svg, data.bed, sx, sy) : [];
  if (data.track.length > 1) {
    svg.append(svgEl("polyline", { points: path(data.track, sx, sy), class: "track" }));
  }
  const marks = [];
  for (const s of data.stations) {
    const x = sx(s.east_m), y = sy(s.north_m);
    const cls = s.cast_ids.length ? (s.measured ? "station measured" : s.outcome === "skipped-shallow"
      ? "station skipped" : "station other") : "station unasked";
    const mark = s.cast_ids.length
      ? svgEl("circle", { cx: x.toFixed(1), cy: y.toFixed(1), r: 6, class: cls, "data-station": s.name })
      : svgEl("rect", { x: (x - 5).toFixed(1), y: (y - 5).toFixed(1), width: 10, height: 10, class: cls,
        "data-station": s.name });
    mark.append(svgEl("title", {}, `${s.name}: ${s.summary}`));
    if (onStation && s.cast_ids.length) mark.addEventListener("click", () => onStation(s));
    svg.append(mark);
    marks.push({ x, y, s });
    taken.push({ x: x - 7, y: y - 7, width: 14, height: 14 });
  }
  // A scale bar: a round number of metres, bottom right.
  const bar = roundDown((W - L - R) / k / 4);
  const x1 = W - R - 8, x0 = x1 - bar * k, yb = H - B - 8;
  svg.append(svgEl("line", { x1: x0, x2: x1, y1: yb, y2: yb, class: "scale" }),
    svgEl("text", { x: (x0 + x1) / 2, y: yb - 4, "text-anchor": "middle", class: "tick" }, `${bar} m`));
  taken.push({ x: x0 - 4, y: yb - 18, width: x1 - x0 + 8, height: 22 });
  const area = { x: L, y: T, width: W - L - R, height: H - T - B };
  // Each contour's depth once, where it covers nothing already there; else not at all.
  for (const { x, y, text } of contourLabels) {
    const t = svgEl("text", { x: x.toFixed(1), y: (y + 4).toFixed(1), "text-anchor": "middle",
      class: "contour-label" }, text);
    svg.append(t);
    const r = t.getBBox();
    const b = { x: r.x - 4, y: r.y - 2, width: r.width + 8, height: r.height + 4 };  // a gap around it
    const inside = r.x >= area.x && r.y >= area.y && r.x + r.width <= area.x + area.width
      && r.y + r.height <= area.y + area.height;
    if (!inside || taken.some((o) => overlap(b, o) > 0)) t.remove();
    else taken.push(b);
  }
  for (const { x, y, s } of marks) {
    let best = null;
    let label = null;
    for (const [dx, dy] of LABEL_PLACES) {
      if (label) label.remove();
      label = svgEl("text", { x: (x + dx).toFixed(1), y: (y + dy).toFixed(1), class: "station-label",
        "text-anchor": dx > 0 ? "start" : dx < 0 ? "end" : "middle" }, s.label);
      svg.append(label);
      const b = label.getBBox();
      const inside = b.x >= area.x && b.y >= area.y && b.x + b.width <= area.x + area.width
        && b.y + b.height <= area.y + area.height;
      const covered = taken.reduce((sum, t) => sum + overlap(b, t), 0) + (inside ? 0 : 1e6);
      if (covered === 0) { best = null; break; }
      if (!best || covered < best.covered) best = { covered, dx, dy };
    }
    if (best) {
      label.remove();
      label = svgEl("text", { x: (x + best.dx).toFixed(1), y: (y + best.dy).toFixed(1), class: "station-label",
        "text-anchor": best.dx > 0 ? "start" : best.dx < 0 ? "end" : "middle" }, s.label);
      svg.append(label);
    }
    taken.push(label.getBBox());
  }
}
