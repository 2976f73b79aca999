// The page: which view is shown, the live connection (SSE) and the status poll.
import { $, api } from "./api.js";
import * as comp from "./compensation.js";
import * as op from "./operator.js";
import * as parts from "./parts.js";
import * as spc from "./spc.js";
import * as study from "./study.js";
import * as tech from "./technician.js";

const VIEWS = { operator: op.loadOperator, compensation: comp.loadCompensation,
                parts: parts.loadParts, spc: spc.loadSpc,
                technician: async () => { await tech.loadTechnician(); await study.refreshStudy(); } };
let source = null, live = false, retry = null, ticks = 0;

function setLive(on, why = "") {
  live = on;
  $("lost").hidden = on;
  const link = $("link");
  link.textContent = on ? "live" : "offline" + (why ? ": " + why : "");
  link.className = "pill " + (on ? "ok" : "bad");
}

async function show(name) {
  if (!VIEWS[name]) name = "operator";
  for (const v of Object.keys(VIEWS)) $("view-" + v).hidden = v !== name;
  for (const a of document.querySelectorAll("nav a")) a.classList.toggle("active", a.dataset.view === name);
  try { await VIEWS[name](); } catch (err) { console.warn(name, err.message); }
}

async function backOnline() {
  const wasLost = !live;
  setLive(true);
  if (wasLost) await show(location.hash.slice(1));  // reload what was missed
}

function connect() {
  clearTimeout(retry);
  if (source) source.close();
  source = new EventSource("/api/v1/stream");
  source.onopen = backOnline;
  source.addEventListener("measurement", (e) => {
    const m = JSON.parse(e.data);
    op.onMeasurement(m); parts.onMeasurement(m);
  });
  source.addEventListener("decision", (e) => {
    const d = JSON.parse(e.data);
    op.onDecision(d); comp.onDecision(d);
  });
  source.addEventListener("spc", () => spc.onSpcEvent());
  source.onerror = () => {
    setLive(false, "connection to the service lost");
    source.close();
    retry = setTimeout(connect, 2000);
  };
}

async function poll() {
  try {
    const st = await api("/status");
    op.onStatus(st); comp.onStatus(st);
    if (!live) {  // the service answers again: the stream either still stands or is renewed
      if (source && source.readyState === EventSource.OPEN) await backOnline();
      else if (!source || source.readyState === EventSource.CLOSED) connect();
    }
  } catch (err) {
    setLive(false, err.message);
  }
  if (!$("view-operator").hidden && live) op.refreshFrame();
  if (!$("view-spc").hidden && live && ++ticks % 3 === 0) spc.loadSpc().catch(() => {});
  if (!$("view-parts").hidden && live) parts.loadParts().catch(() => {});
  if (!$("view-technician").hidden && live) study.refreshStudy().catch(() => {});
}

window.addEventListener("hashchange", () => show(location.hash.slice(1)));
window.addEventListener("resize", () => { op.redraw(); spc.redrawSpc(); });
comp.wireCompensation();
spc.wireSpc();
tech.wireTechnician();
study.wireStudy();
show(location.hash.slice(1));
connect();
poll();
setInterval(poll, 1000);
