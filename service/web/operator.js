// Operator view: the diameter against its tolerance, the trend, the gauge's state, the frame.
import { $, api, clock, mm, um } from "./api.js";
import { drawTrend } from "./chart.js";

const MAX_POINTS = 600;
const points = [];      // {seq, d}
const marks = [];       // seq of measurements after which an offset was applied
let feature = null;     // {nominal_mm, tol_upper_mm, tol_lower_mm}
let lastSeq = 0;

function band() {
  if (!feature || feature.nominal_mm == null) return null;
  return { nominal: feature.nominal_mm, lo: feature.nominal_mm + feature.tol_lower_mm,
           hi: feature.nominal_mm + feature.tol_upper_mm };
}

export async function loadOperator() {
  feature = await api("/feature");
  $("nominal").textContent = mm(feature.nominal_mm);
  $("tolerance").textContent = feature.nominal_mm == null ? "–"
    : `+${um(feature.tol_upper_mm, 0)} / ${um(feature.tol_lower_mm, 0)}`;
  const hist = await api("/measurements?limit=" + MAX_POINTS + "&ok_only=true");
  points.length = 0;
  for (const m of hist.items.reverse()) points.push({ seq: m.seq, d: m.diameter_mm });
  const applied = await api("/compensation/log?limit=200&kinds=applied");
  marks.length = 0;
  for (const d of applied.items) if (d.measurement_seq != null) marks.push(d.measurement_seq);
  redraw();
}

export function redraw() { drawTrend($("trend"), points, band(), marks); }

export function onMeasurement(m) {
  lastSeq = m.seq;
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
    points.push({ seq: m.seq, d: m.diameter_mm });
    if (points.length > MAX_POINTS) points.shift();
    if (!document.hidden && !$("view-operator").hidden) redraw();
  }
}

export function onDecision(d) {
  if (d.kind === "applied") { marks.push(d.measurement_seq ?? lastSeq); redraw(); }
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
