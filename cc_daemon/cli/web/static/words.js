// Plain words for the field page: numbers with their units, times, positions, the
// daemon's state and faults as sentences, and the journal's events as sentences.
// Pure: values in, text out; it touches neither the page nor the network.

export function num(v, digits = 2) {
  return typeof v === "number" && Number.isFinite(v) ? v.toFixed(digits) : "–";
}
export function metres(v, digits = 2) {
  return typeof v === "number" && Number.isFinite(v) ? `${v.toFixed(digits)} m` : "–";
}
// The sonde's units as the register map writes them (`degC`, `1`), as a person reads them.
export function unitText(unit) {
  return { degC: "°C", "1": "", "": "" }[unit] ?? unit;
}
export function withUnit(value, unit, digits = 2) {
  if (typeof value !== "number" || !Number.isFinite(value)) return "–";
  const u = unitText(unit || "");
  return u ? `${value.toFixed(digits)} ${u}` : value.toFixed(digits);
}
export function utc(s) {
  return s ? new Date(s * 1000).toISOString().replace("T", " ").slice(0, 19) : "–";
}
export function clock(s) { return utc(s).slice(11); }
export function ago(seconds) {
  if (typeof seconds !== "number" || !Number.isFinite(seconds)) return "–";
  const s = Math.max(0, seconds);
  if (s < 60) return `${s < 10 ? s.toFixed(1) : Math.round(s)} s`;
  if (s < 3600) return `${Math.floor(s / 60)} min ${Math.round(s % 60)} s`;
  return `${Math.floor(s / 3600)} h ${Math.round((s % 3600) / 60)} min`;
}
// Degrees to 1e-7 (about 1 cm): the autopilot's own resolution, never rounded to 100 m.
export function latlon(lat, lon) {
  if (typeof lat !== "number" || typeof lon !== "number") return "–";
  return `${Math.abs(lat).toFixed(7)}° ${lat >= 0 ? "N" : "S"}, `
    + `${Math.abs(lon).toFixed(7)}° ${lon >= 0 ? "E" : "W"}`;
}
export function words(key) { return String(key).replace(/_/g, " "); }
export function plural(n, one, many) { return `${n} ${n === 1 ? one : many || one + "s"}`; }

// What the autopilot is told while the probe cannot come home, and what to do.
const R_L = "R-L (a fault report: error 76 on the ground station) every second instead of "
  + "R-F, so the boat holds the station";
function release(encoder) {
  const haul = "haul the probe in with the RC stick (probe up), or free the line and run "
    + "sudo cc-daemon winch home: once the winch verifies home, R-F goes and the boat moves on";
  return encoder
    ? "To release: the drum's count is no longer trusted, so no haul can verify home. "
      + "Bring the probe in by hand; with the probe seen on board, cc-daemon release ends the "
      + "station; then mend the pulse wire and restart the daemon."
    : `To release: ${haul}.`;
}

// Where the probe is: measured, or an estimate said as one, with its range.
export function probeWhere(depth, low, high) {
  if (typeof low === "number" && typeof high === "number") {
    return `somewhere between ${num(low)} and ${num(high)} m (an estimate: the drum's count is `
      + `no longer trusted; best estimate ${metres(depth)})`;
  }
  return `at ${metres(depth)}`;
}

// The faults the status document reports, each as sentences a person can act on.
// Keys no version of this page knows still raise an alarm (`unknownAlarms`).
export function faultSentences(doc) {
  const out = [];
  const cast = doc.cast || {}, winch = doc.winch || {}, journal = doc.journal || {};
  const link = doc.link || {};
  const stranded = cast.fault_reported;
  if (stranded && typeof stranded === "object") {
    const low = stranded.depth_low_m ?? winch.depth_low_m, high = stranded.depth_high_m ?? winch.depth_high_m;
    const encoder = typeof low === "number" || /encoder|witnesses/.test(String(stranded.fault));
    out.push({
      title: "The probe is stranded: it cannot come home.",
      lines: [
        `What happened: ${stranded.fault || "the winch could not bring the probe home"}.`,
        `Where the probe is: ${probeWhere(stranded.depth_m, low, high)}. The motor is stopped.`,
        `What the autopilot is told: ${R_L} (${plural(stranded.r_l_sent || 0, "R-L")} so far).`,
        release(encoder),
      ],
    });
  } else if (winch.fault) {
    out.push({
      title: "The winch reports a fault.",
      lines: [`What happened: ${winch.fault}.`,
        `Where the probe is: ${probeWhere(winch.depth_m, winch.depth_low_m, winch.depth_high_m)}.`,
        cast.phase && cast.phase !== "idle"
          ? "The cast is cut short: the probe is hauled home before R-F."
          : "No cast starts until the winch verifies home."],
    });
  }
  if (winch.sensor_fault) {
    out.push({ title: "A winch sensor is not trusted.",
      lines: [`${winch.sensor_fault}. The winch still moves, guarded by its pulses only.`] });
  }
  if (journal.writable === false || journal.last_error) {
    out.push({ title: "The journal cannot be written.",
      lines: [`${journal.last_error || "writes have not come back"}. `
        + `${plural(journal.pending_rows || 0, "row")} wait in memory or in spill files.`] });
  }
  if (link.up === false) {
    out.push({ title: "The autopilot's serial port is not open.",
      lines: [`${link.port || "the port"}: ${plural(link.open_attempts || 0, "attempt")} to open it `
        + "so far; the daemon keeps trying. Check the cable and serial.port."] });
  }
  return out;
}

const KNOWN_ALARMS = /^(cast\.fault_reported|cast\.fault_reported\..*|winch\.fault|winch\.sensor_fault|journal\.last_error)$/;
// Every true-ish key naming a fault, a stranded probe or an error, wherever it is:
// sections the daemon adds later raise the banner without this page changing.
export function unknownAlarms(doc, path = "", out = []) {
  for (const [k, v] of Object.entries(doc || {})) {
    const where = path ? `${path}.${k}` : k;
    if (v && typeof v === "object" && !Array.isArray(v)) unknownAlarms(v, where, out);
    // A text or `true`: a fault said, or a probe stranded. A number is a count of
    // faults past (faults_total: 3), which must not cry wolf for ever.
    else if (/fault|stranded|^error$|last_error/.test(k) && (v === true || typeof v === "string")
      && v && !KNOWN_ALARMS.test(where)) {
      out.push(`The daemon reports ${words(where.replace(".", ": "))}: ${v === true ? "yes" : v}.`);
    }
  }
  return out;
}

const PHASE_WORDS = {
  soaking: "soaking at the surface", descending: "going down", dwelling: "waiting at depth",
  ascending: "coming up", aborting: "aborted: coming home", stranded: "stranded",
};
export function phaseWords(phase) { return PHASE_WORDS[phase] || words(phase || "?"); }

// The state in one or two plain sentences.
export function stateSentence(doc, station) {
  const cast = doc.cast || {}, winch = doc.winch || {};
  const at = station ? ` at ${station}` : "";
  if (cast.fault_reported) {
    return `Cast ${cast.cast_id}${at}: the probe is stranded `
      + `${probeWhere(cast.fault_reported.depth_m, winch.depth_low_m, winch.depth_high_m)}.`;
  }
  if (cast.phase && cast.phase !== "idle") {
    const planned = typeof cast.planned_depth_m === "number" && cast.planned_depth_m > 0
      ? ` of ${metres(cast.planned_depth_m)} planned` : "";
    return `Cast ${cast.cast_id}${at}: ${phaseWords(cast.phase)}, the probe `
      + `${probeWhere(cast.depth_m, winch.depth_low_m, winch.depth_high_m)}${planned}.`;
  }
  const home = winch.at_home ? "The probe is home." : `The probe is ${probeWhere(winch.depth_m ?? cast.depth_m,
    winch.depth_low_m, winch.depth_high_m)}.`;
  const stopping = (doc.daemon || {}).state === "stopping" ? " The daemon is stopping." : "";
  return `No cast running: waiting for the autopilot's next station. ${home}${stopping}`;
}

// The journal's events as sentences; their details are folded away by the page.
const EVENTS = {
  daemon_started: (d) => `The daemon started (autopilot port ${d.port || "?"}).`,
  daemon_stopped: (d) => `The daemon stopped (exit status ${d.exit_code}`
    + `${d.exit_code === 130 ? ": stopped at once, the probe may be down" : ""}).`,
  port_opened: (d) => `The autopilot's port ${d.port || ""} opened.`,
  port_regained: (d) => `The autopilot's port ${d.port || ""} is back.`,
  port_lost: (d) => `The autopilot's port was lost: ${d.reason || "no reason given"}.`,
  timestamp_order: (d) => `The autopilot's clock is read ${d.order}-endian (${plural(d.votes || 0, "vote")}).`,
  sonde_started: (d) => `The sonde started: ${plural((d.parameters || []).length, "parameter")} `
    + `(${d.backend || "?"}).`,
  sonde_port_opened: () => "The sonde's port opened.",
  sonar_port_opened: () => "The sonar's port opened.",
  sonar_port_lost: (d) => `The sonar's port was lost: ${d.reason || "?"}.`,
  jog_started: (d) => `The RC stick jogs the probe ${d.stick} from ${metres(d.depth_m)}.`,
  jog_stopped: (d) => `The jog stopped at ${metres(d.depth_m)}: ${d.reason || "?"}.`,
  cast_refused: (d) => `A station was refused: the winch cannot verify home (${d.fault || "?"}).`,
  cast_aborted: (d) => `Cast ${d.cast_id} aborted at ${metres(d.depth_m)}: ${d.reason || "?"}.`,
  cast_stranded: (d) => `Cast ${d.cast_id}: the probe is stranded at ${metres(d.depth_m)}.`,
  fault_reported: (d) => `Cast ${d.cast_id}: the fault is reported to the autopilot with R-L `
    + `(the probe at ${metres(d.depth_m)}).`,
  stranded_cleared: (d) => `Cast ${d.cast_id}: the probe is home again; R-F sent after `
    + `${plural(d.fault_reports || 0, "R-L")}.`,
  winch_fault: (d) => `The winch reports a fault: ${d.fault || "?"}`
    + (typeof d.depth_low_m === "number"
      ? ` (the probe between ${num(d.depth_low_m)} and ${num(d.depth_high_m)} m).` : "."),
  rf_repeated: () => "The autopilot was silent after R-F: R-F sent again.",
  corrupt_frames: (d) => `Corrupt frames from the autopilot: ${d.new ?? d.count ?? "?"}.`,
  config_reloaded: (d) => `The configuration was reloaded (${(d.applied || []).join(", ")}).`,
  config_reload_refused: () => "A new configuration was refused: the old one stays.",
  journal_unwritable: () => "The journal could not be written.",
  stations_planned: (d) => `The survey's plan: ${plural((d.stations || []).length, "station")} `
    + `(${(d.stations || []).map((s) => s.name).join(", ")}).`,
  operator_haul_in: () => "An operator hauled the probe in.",
  bottom_contact: (d) => `The sonde touched the bottom at ${metres(d.depth_m)}.`,
};
export function eventSentence(e) {
  const say = EVENTS[e.kind];
  let text;
  try { text = say ? say(e.detail || {}) : ""; } catch (err) { text = ""; }
  if (!text) text = words(e.kind).replace(/^./, (c) => c.toUpperCase()) + ".";
  return text;
}
