// Technician view: the calibration wizard over the session endpoints, history and rollback,
// the master check.
import { $, api, clock, key, mm, say, setKey, um } from "./api.js";
import { drawBars } from "./chart.js";

const STEPS = ["intrinsics", "plane", "axis", "build"];
let session = null;

function showSession(s) {
  session = s;
  $("session-id").textContent = s ? `session ${s.id}` : "";
  for (const box of document.querySelectorAll(".kinds > div")) {
    box.querySelector(".count").textContent = s ? s.images[box.dataset.kind] : 0;
  }
  $("activate").disabled = !(s && s.built && s.activated_id == null);
  $("end-session").disabled = !s;
}

function sessionState(s) {
  if (s.activated_id != null) return `activated as calibration ${s.activated_id}`;
  return s.progress.state === "idle" ? "collecting images"
    : `${s.progress.step}: ${s.progress.state}`;
}

// The kept sessions, each to resume or end: a technician who closed the page can still end
// the sessions that fill the open places.
async function loadSessions() {
  const items = (await api("/calibration-sessions")).items;
  $("sessions").replaceChildren(...items.map((s) => {
    const tr = document.createElement("tr");
    const images = Object.values(s.images).reduce((a, b) => a + b, 0);
    for (const t of [s.id, clock(s.created), s.by, images, sessionState(s)]) {
      tr.append(Object.assign(document.createElement("td"), { textContent: t }));
    }
    const td = document.createElement("td");
    const resume = Object.assign(document.createElement("button"), { textContent: "Resume" });
    resume.addEventListener("click", guarded($("progress"), async () => {
      showSession(await api(`/calibration-sessions/${s.id}`));
      showReport(session.report);
      say($("progress"), `session ${s.id} resumed`, "ok");
    }));
    const end = Object.assign(document.createElement("button"), { textContent: "End" });
    end.addEventListener("click", guarded($("progress"), () => endSession(s.id)));
    td.append(resume, " ", end);
    tr.append(td);
    return tr;
  }));
}

async function endSession(id) {
  await api(`/calibration-sessions/${id}`, { method: "DELETE" });
  if (session && session.id === id) { showSession(null); showReport(null); }
  say($("progress"), `session ${id} ended: its images are deleted`, "ok");
  await loadSessions();
}

function showReport(report) {
  const el = $("report");
  if (!report) { el.innerHTML = '<p class="hint">The quality report appears here.</p>'; return; }
  const f = report.figures || {};
  const lines = [];
  if (f.intrinsics) {
    lines.push(`reprojection RMS ${f.intrinsics.rms_px.toFixed(3)} px, worst ` +
               `${f.intrinsics.worst_px.toFixed(2)} px, ${f.intrinsics.images_used} images, ` +
               `corners over ${(100 * f.intrinsics.coverage).toFixed(0)} % of the image`);
  }
  if (f.light_plane) {
    lines.push(`light plane residual ${um(f.light_plane.rms_mm)} RMS over ` +
               `${f.light_plane.points} points of ` +
               `${f.light_plane.poses_used ?? (f.light_plane.per_pose_points || []).length} poses` +
               (Object.keys(f.light_plane.rejected || {}).length
                 ? `, ${Object.keys(f.light_plane.rejected).length} left out` : ""));
  }
  if (f.axis) lines.push(`axis: board turned through ${f.axis.rotation_span_deg.toFixed(0)}°,` +
                         ` residual ${um(f.axis.plane_residual_mm)}`);
  if (f.plane_axis_angle_deg != null) {
    lines.push(`light plane meets the axis at ${f.plane_axis_angle_deg.toFixed(0)}°`);
  }
  el.replaceChildren();
  const v = document.createElement("p");
  v.innerHTML = `Verdict: <b class="verdict-${report.verdict}" id="verdict-word">` +
                `${report.verdict}</b>`;
  el.append(v);
  for (const text of [...lines, ...report.reasons]) {
    el.append(Object.assign(document.createElement("div"), { textContent: text }));
  }
  plot($("reproj"), (f.intrinsics?.per_image_rms_px || []).map((e, i) => ({
    label: String(i + 1), value: e })), "px", 0.3);
  plot($("residuals"), (f.light_plane?.per_pose_rms_mm || []).map((e, i) => ({
    label: "pose " + (i + 1), value: e * 1000 })), "µm", 30);
}

function plot(canvas, bars, unit, good) {
  canvas.hidden = !bars.length;
  if (bars.length) drawBars(canvas, bars, unit, good);
}

async function refresh() {
  if (!session) return null;
  const s = await api(`/calibration-sessions/${session.id}`);
  showSession(s);
  return s;
}

async function upload(kind, files) {
  for (const f of files) {
    const type = f.type || "application/octet-stream";  // PNG or JPEG, grey or colour
    const s = await api(`/calibration-sessions/${session.id}/images/${kind}`,
                        { method: "POST", body: f, headers: { "Content-Type": type } });
    showSession(s);
  }
}

async function runAll() {
  for (const step of STEPS) {
    say($("progress"), `${step}: working…`);
    await api(`/calibration-sessions/${session.id}/run/${step}`, { method: "POST" });
    let s;
    for (;;) {
      await new Promise((r) => setTimeout(r, 400));
      s = await refresh();
      if (s.progress.step === step && s.progress.state !== "running") break;
    }
    if (s.progress.state === "failed" || (step === "build" && !s.built)) {
      say($("progress"), `${step} refused: ${s.progress.message}`, "bad");
      showReport(s.report || s.results[step]?.report);
      return;
    }
    if (step === "intrinsics") showReport(s.results.intrinsics?.report);
  }
  say($("progress"), "all steps done: review the report, then activate", "ok");
  showReport(session.report);
}

async function loadHistory() {
  const items = (await api("/calibrations")).items;
  $("history").replaceChildren(...items.map((c) => {
    const tr = document.createElement("tr");
    for (const t of [c.id, clock(c.created), c.quality?.verdict ?? "–", c.note]) {
      tr.append(Object.assign(document.createElement("td"), { textContent: t }));
    }
    const td = document.createElement("td");
    if (c.active) td.textContent = "in use";
    else {
      const b = Object.assign(document.createElement("button"), { textContent: "Use this" });
      b.addEventListener("click", async () => {
        try { await api(`/calibrations/${c.id}/activate`, { method: "POST" }); await loadHistory(); }
        catch (err) { alert(err.message); }
      });
      td.append(b);
    }
    tr.append(td);
    return tr;
  }));
}

async function loadMaster() {
  const m = await api("/master");
  const last = m.last_check;
  say($("master-status"), last
    ? `last check ${clock(last.time)}: ${last.passed ? "passed" : "FAILED"} ` +
      `(error ${um(last.error_mm)})${m.blocking ? "; offsets blocked: " + m.blocking : ""}`
    : "no master check recorded yet", last && !last.passed ? "bad" : "");
}

export async function loadTechnician() {
  if (!$("key").value) $("key").value = key();  // never over what is being typed
  await Promise.all([loadHistory(), loadMaster(), loadSessions()]);
}

function guarded(el, fn) {
  return async (...args) => {
    try { await fn(...args); } catch (err) { say(el, err.message, "bad"); }
  };
}

export function wireTechnician() {
  $("key").addEventListener("change", (e) => setKey(e.target.value.trim()));
  // Enter in the key field takes the key; the page stays (no inline handler: the CSP
  // allows the gauge's own scripts only, and an inline one was refused on every load).
  $("key-form").addEventListener("submit", (e) => {
    e.preventDefault();
    setKey($("key").value.trim());
  });
  $("new-session").addEventListener("click", guarded($("progress"), async () => {
    showSession(await api("/calibration-sessions", { method: "POST",
                                                     json: { board: $("board").value } }));
    showReport(null);
    say($("progress"), "session started: add images", "ok");
    await loadSessions();
  }));
  $("end-session").addEventListener("click", guarded($("progress"), async () => {
    if (session) await endSession(session.id);
  }));
  for (const box of document.querySelectorAll(".kinds > div")) {
    const kind = box.dataset.kind;
    box.querySelector("input[type=file]").addEventListener("change", guarded($("progress"),
      async (e) => {
        if (!session) throw new Error("start a session first");
        await upload(kind, [...e.target.files]);
        e.target.value = "";
      }));
    box.querySelector(".capture").addEventListener("click", guarded($("progress"), async () => {
      if (!session) throw new Error("start a session first");
      showSession(await api(`/calibration-sessions/${session.id}/capture/${kind}`,
                            { method: "POST" }));
    }));
  }
  $("run-all").addEventListener("click", guarded($("progress"), async () => {
    if (!session) throw new Error("start a session first");
    await runAll();
  }));
  $("activate").addEventListener("click", guarded($("activate-msg"), async () => {
    const s = await api(`/calibration-sessions/${session.id}/activate`,
                        { method: "POST", json: { note: "from the calibration page" } });
    showSession(s);
    say($("activate-msg"), `calibration ${s.activated_id} is in use`, "ok");
    await Promise.all([loadHistory(), loadSessions()]);
  }));
  $("master-run").addEventListener("click", guarded($("master-msg"), async () => {
    say($("master-msg"), "measuring the master…");
    const r = await api("/master/measure", { method: "POST",
      json: { certified_mm: parseFloat($("master-mm").value) } });
    say($("master-msg"), `measured ${mm(r.corrected_mm)} ± ${um(r.uncertainty_mm)} over ` +
        `${r.frames} frames: ${r.check.passed ? "passed" : "FAILED"}`, r.check.passed ? "ok" : "bad");
    await loadMaster();
  }));
}
