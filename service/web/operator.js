// Operator view: the diameter against its tolerance, the trend, the gauge's state, the frame.
import { $, api, clock, mm, um } from "./api.js";
import { drawPolar, drawTrend } from "./chart.js";

const MAX_POINTS = 600;
const points = [];      // {seq, d, feature}
const marks = [];       // seq of measurements after which an offset was applied
const applied = [];     // {seq, offset_mm} of those offsets, oldest first
let deadTime = 0;       // measurements from an offset applied to the first that shows it
let feature = null;     // {nominal_mm, tol_upper_mm, tol_lower_mm, name?}: judged against
let features = {};      // the job in force's, by number: a job of several features
let current = null;     // the number of the feature under the laser (null: the only one)

function band() {
  if (!feature || feature.nominal_mm == null) return null;
  return { nominal: feature.nominal_mm, lo: feature.nominal_mm + feature.tol_lower_mm,
           hi: feature.nominal_mm + feature.tol_upper_mm };
}

// The feature the card and the trend stand for: the one under the laser in a job of
// several features (each has its own nominal and tolerance), else the one feature.
function showFeature() {
  $("feature-name").textContent = current == null || !features[current] ? ""
    : `feature ${current} ${features[current].name ?? ""}`.trim();
  $("nominal").textContent = mm(feature?.nominal_mm ?? null);
  $("tolerance").textContent = feature?.nominal_mm == null ? "–"
    : `+${um(feature.tol_upper_mm, 0)} / ${um(feature.tol_lower_mm, 0)}`;
}

async function loadJob() {
  const st = await api("/status");
  const id = st.job?.job?.id;
  features = {};
  if (id == null || (st.job.job.features ?? 0) < 2) return;
  const job = await api(`/jobs/${id}`);
  for (const f of job.document.features ?? []) features[f.number] = f;
}

export async function loadOperator() {
  feature = await api("/feature");
  await loadJob();
  if (current != null && features[current]) feature = features[current];
  showFeature();
  const hist = await api("/measurements?limit=" + MAX_POINTS + "&ok_only=true");
  points.length = 0;
  for (const m of hist.items.reverse()) {
    points.push({ seq: m.seq, d: m.diameter_mm, feature: m.feature });
  }
  const log = await api("/compensation/log?limit=200&kinds=applied");
  deadTime = (await api("/compensation")).settings.dead_time_measurements ?? 0;
  marks.length = 0; applied.length = 0;
  for (const d of log.items.reverse()) {
    if (d.measurement_seq == null) continue;
    marks.push(d.measurement_seq);
    applied.push({ seq: d.measurement_seq, offset_mm: d.offset_mm ?? 0 });
  }
  redraw();
}

// The measured diameter less the offsets in force when its surface was cut (an offset
// applied after measurement s shows from s + the dead time on): what the process would have
// done uncompensated, the tool's wear and the machine's growth as the gauge sees them.
export function uncompensated(pts, offsets, dead) {
  if (!offsets.length) return [];
  let k = 0, inForce = 0;
  return pts.map((p) => {
    while (k < offsets.length && offsets[k].seq + dead < p.seq) inForce += offsets[k++].offset_mm;
    return { seq: p.seq, d: p.d - inForce };
  });
}

export function redraw() {
  if (Object.keys(features).length > 1) {  // the feature under the laser's own, alone
    const own = points.filter((p) => p.feature === current);
    drawTrend($("trend"), own, band(), [], []);
    return;
  }
  drawTrend($("trend"), points, band(), marks, uncompensated(points, applied, deadTime));
}

let lastSeq = 0;

export function onMeasurement(m) {
  lastSeq = m.seq;
  if (m.feature != null && m.feature !== current && features[m.feature]) {
    current = m.feature;  // another feature under the laser: its nominal and tolerance
    feature = features[current];
    showFeature();
  }
  const card = $("state-card");
  $("diameter").textContent = m.diameter_mm == null ? "no diameter" : mm(m.diameter_mm);
  $("deviation").textContent = um(m.deviation_mm);
  $("uncertainty").textContent = m.uncertainty_mm == null ? "–" : "± " + um(m.uncertainty_mm);
  $("fused").textContent = m.fused_diameter_mm == null ? "–"
    : `${mm(m.fused_diameter_mm)} ± ${um(m.fused_uncertainty_mm)}`;
  $("status").textContent = m.status === "ok" ? `ok (${m.method}, ${clock(m.time)})`
    : `${m.status}: ${m.reason}`;
  let state = "warn", verdict = "no verdict";
  if (m.status !== "ok") { state = "bad"; verdict = "not measuring"; }
  else if (m.in_tolerance === true) { state = "ok"; verdict = "in tolerance"; }
  else if (m.in_tolerance === false) { state = "bad"; verdict = "OUT OF TOLERANCE"; }
  else verdict = "no nominal set";
  card.className = "card big " + state;
  $("verdict").textContent = verdict; $("verdict").className = "pill " + state;
  if (m.status === "ok" && m.diameter_mm != null) {
    points.push({ seq: m.seq, d: m.diameter_mm, feature: m.feature });
    if (points.length > MAX_POINTS) points.shift();
    if (!document.hidden && !$("view-operator").hidden) redraw();
  }
}

export function onDecision(d) {
  if (d.kind !== "applied") return;
  const seq = d.measurement_seq ?? lastSeq;
  marks.push(seq);
  applied.push({ seq, offset_mm: d.offset_mm ?? 0 });
  redraw();
}

function pill(el, text, state) { el.textContent = text; el.className = "pill " + state; }

export function onStatus(st) {
  $("rate").textContent = st.pipeline.rate_hz.toFixed(1) + " /s";
  const cam = st.camera;
  pill($("camera"), cam.state + (cam.message ? `: ${cam.message}` : ""),
       cam.state === "streaming" ? "ok" : "bad");
  if (st.plc == null) pill($("plc"), "not configured", "warn");
  else if (st.plc.connected) pill($("plc"), `connected ${st.plc.host}:${st.plc.port}`, "ok");
  else if (st.plc.outage_s == null) pill($("plc"), "idle: connects to write an offset", "warn");
  else pill($("plc"), `unreachable for ${st.plc.outage_s.toFixed(0)} s: ${st.plc.last_error}`,
            "bad");
  showForm(st.pipeline.runout);
  const ul = $("problems");
  ul.replaceChildren(...st.problems.map((p) => Object.assign(document.createElement("li"),
                                                             { textContent: p.text,
                                                               title: p.code })));
}

export function refreshFrame() {
  const img = $("frame");
  const next = new Image();
  next.onload = () => { img.src = next.src; };
  next.src = "/api/v1/frame/latest.jpg?width=688&t=" + Date.now();
}

// Form and position, when the spindle's angle is known (status pipeline.runout).
function showForm(ro) {
  $("form-card").hidden = !ro;
  if (!ro) return;
  const shape = ro.roundness && ro.roundness.ok ? ro.roundness : null;
  $("tir").textContent = ro.known ? `${um(ro.tir_mm)} ± ${um(ro.tir_uncertainty_mm)}` +
    (ro.tir_mm > ro.max_tir_mm ? ` (beyond ${um(ro.max_tir_mm)}: offsets held)` : "") : "–";
  $("ecc-phase").textContent = ro.known ? `${ro.eccentricity_deg.toFixed(0)}°` : "–";
  $("ront").textContent = shape ? `${um(shape.ront_mm)} ± ${um(shape.ront_uncertainty_mm)}`
    : "–";
  $("lobes").textContent = shape ? (shape.lobes ? shape.lobes + (shape.odd_lobing
    ? " (odd: a two-point gauge cannot see it)" : "") : "none above the noise") : "–";
  $("runout-why").textContent = ro.known ? "" : ro.reason || "";
  drawPolar($("polar"), shape ? { deg: shape.profile_deg, mm: shape.profile_mm } : null,
            ro.known ? { mm: ro.eccentricity_mm, deg: ro.eccentricity_deg } : null);
}
