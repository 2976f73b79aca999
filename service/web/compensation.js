// Compensation view: decisions with reasons, the shadow switch, the cumulative offset.
import { $, api, clock, say, um } from "./api.js";

let switching = false;  // a shadow-mode change is on its way: leave the switch alone

const QUIET = ["held", "refused", "proposed"];  // a run of these is one row (with a count)

// An offset entry as the CNC names it: T2 (the tool's own), T2 offset 10012.
const entryName = (e) => e.entry == null ? `T${e.tool}` : `T${e.tool} offset ${e.entry}`;

function kindText(kind, count, d) {
  const what = d.tool == null ? kind : `${entryName(d)} ${kind}`;
  return count > 1 ? `${what} \u00d7${count}` : what;
}

function row(d) {
  const tr = document.createElement("tr");
  const count = d.count ?? 1;
  const cells = [clock(d.last_time ?? d.wall_time ?? d.time ?? d.time_s),
                 kindText(d.kind, count, d),
                 d.offset_mm == null ? "" : (d.offset_mm * 1000).toFixed(1),
                 d.deviation_mm == null ? "" : (d.deviation_mm * 1000).toFixed(1), d.reason];
  cells.forEach((c, i) => {
    const td = document.createElement("td");
    td.textContent = c;
    if (i === 2 || i === 3) td.className = "num";
    tr.append(td);
  });
  tr.dataset.kind = d.kind;
  tr.dataset.code = d.code ?? "";
  tr.dataset.count = count;
  tr.dataset.tool = d.tool ?? "";
  tr.dataset.entry = d.entry ?? "";
  return tr;
}

// Several entries in the job: each in its row, none at the top.
const several = (c) => (c.entries ?? []).length > 1;

// The tools an action may name: every tool of a job of several, else none but all.
function showTools(entries) {
  const tools = [...new Set(entries.length > 1 ? entries.map((e) => e.tool) : [])];
  const select = $("act-tool");
  const now = [...select.options].slice(1).map((o) => Number(o.value));
  if (now.join() === tools.join()) return;
  const keep = select.value;
  select.replaceChildren(select.options[0], ...tools.map((t) => {
    const o = document.createElement("option");
    o.value = t;
    o.textContent = `T${t}`;
    return o;
  }));
  select.value = tools.includes(Number(keep)) ? keep : "";
}

// A job of several offset entries: a row an entry (its state, offsets and exchange).
function showEntries(entries, shadow) {
  showTools(entries);
  const rows = entries.length > 1 ? entries : [];
  $("comp-tools-card").hidden = !rows.length;
  $("comp-tools").replaceChildren(...rows.map((t) => {
    const tr = document.createElement("tr");
    const cells = [entryName(t), t.features.join(", "), t.state, um(t.cumulative_offset_mm),
                   t.cnc_total_mm != null ? um(t.cnc_total_mm)
                     : t.writes_blocked ? "\u2013" : "not read yet", handshake(t),
                   t.writes_blocked ? "proposed only: " + t.writes_blocked
                     : shadow ? "proposed only (shadow mode)" : "written to the CNC",
                   deadTime(t.dead_time)];
    cells.forEach((c) => {
      const td = document.createElement("td");
      td.textContent = c;
      tr.append(td);
    });
    tr.dataset.tool = t.tool;
    tr.dataset.entry = t.entry ?? "";
    tr.dataset.state = t.state;
    return tr;
  }));
}

// The offset exchange with the CNC: an offset on its way, or the last one settled.
function handshake(c) {
  if (c.pending_seq != null) return `offset #${c.pending_seq} sent: waiting for the CNC's answer`;
  if (!c.offset_seq) return "no offset sent yet";
  return `settled: offset #${c.offset_seq} answered by the CNC`;
}

// The dead time the law waits (in use), typed, and as the gauge's own offsets show it.
function deadTime(d) {
  if (!d) return "\u2013";
  const inUse = `in use ${d.in_use.measurements} meas. / ${d.in_use.seconds} s`;
  const typed = `typed ${d.typed.measurements} meas. / ${d.typed.seconds} s`;
  if (!d.measured) return `${inUse}; ${typed}; not measured yet`;
  const measured = `measured ${d.measured.measurements} meas. (${Math.round(d.measured.seconds)} s)`;
  return `${inUse}; ${typed}; ${measured}${d.differs ? ": set the typed one to it" : ""}`;
}

function showCnc(c) {
  $("comp-dead-time").textContent = several(c) ? "each entry's, below" : deadTime(c.dead_time);
  $("comp-cnc-total").textContent = several(c) ? "each entry's, below"
    : c.cnc_total_mm == null ? "not read yet" : um(c.cnc_total_mm);
  $("comp-handshake").textContent = several(c) ? "each entry's, below" : handshake(c);
}

export async function loadCompensation() {
  const c = await api("/compensation");
  showCnc(c);
  $("comp-state").textContent = c.state;
  $("comp-cumulative").textContent = several(c) ? "each entry's, below"
    : um(c.cumulative_offset_mm);
  $("comp-cnc").textContent = several(c) ? "each entry's, below"
    : c.cnc_total_mm == null || c.baseline_mm == null ? "not read yet"
    : `${um(c.cnc_total_mm - c.baseline_mm)} of ±${um(c.settings.max_total_mm)}`;
  if (!switching) $("shadow").checked = c.settings.shadow;
  showEntries(c.entries ?? [], c.settings.shadow);
  const kinds = $("comp-filter").value;
  const log = await api("/compensation/log?limit=100" + (kinds ? "&kinds=" + kinds : ""));
  $("decisions").replaceChildren(...log.items.map(row));
}

export function onDecision(d) {
  if ($("view-compensation").hidden) return;
  const kinds = $("comp-filter").value;
  if (kinds && !kinds.split(",").includes(d.kind)) return;
  const body = $("decisions");
  const top = body.firstElementChild;
  if (top && QUIET.includes(d.kind) && top.dataset.kind === d.kind &&
      top.dataset.code === (d.code ?? "") && top.dataset.tool === String(d.tool ?? "") &&
      top.dataset.entry === String(d.entry ?? "")) {  // the run goes on: count it, show the latest
    top.replaceWith(row({ ...d, count: Number(top.dataset.count) + 1,
                          wall_time: Date.now() / 1000 }));
    return;
  }
  body.prepend(row({ ...d, wall_time: Date.now() / 1000 }));
  while (body.children.length > 100) body.lastChild.remove();
  // The one entry's figure; in a job of several entries each one's is in its row.
  if ($("comp-tools-card").hidden) $("comp-cumulative").textContent = um(d.after_mm);
}

export function onStatus(st) {
  const held = st.compensation.held;
  $("comp-held").textContent = held ? "held: " + held
    : several(st.compensation) ? "each entry's, below"
    : st.compensation.shadow ? "proposed only (shadow mode)" : "written to the CNC";
  $("comp-state").textContent = st.compensation.state;
  showCnc(st.compensation);
  showEntries(st.compensation.entries ?? [], st.compensation.shadow);
  if (several(st.compensation)) $("comp-cumulative").textContent = "each entry's, below";
  if (!switching) $("shadow").checked = st.compensation.shadow;  // the service's word counts
}

// Acknowledge, reset or record an insert change, of every tool or the one chosen (an insert
// change names its tool); refused without a technician's key.
async function act(command) {
  const tool = $("act-tool").value;
  const what = tool ? `T${tool}'s compensation` : "the compensation of every tool";
  const several = $("act-tool").options.length > 1;
  if (command === "insert_change" && !tool && several) {
    say($("act-msg"), "choose the tool whose insert was changed", "bad");
    return;
  }
  if (command === "reset" && !window.confirm(`Reset ${what}? Its cumulative offset starts `
      + "again from the CNC's total, and its process estimate from the next parts.")) {
    say($("act-msg"), "reset not taken");
    return;
  }
  const insert = tool ? `T${tool}` : "the tool";
  if (command === "insert_change" && !window.confirm(`Record an insert change of ${insert}? `
      + "Zero its wear offset at the CNC; the gauge starts its compensation again from the "
      + "new insert's parts.")) {
    say($("act-msg"), "insert change not recorded");
    return;
  }
  try {
    const got = await api("/compensation/command", {
      method: "POST", json: tool ? { command, tool: Number(tool) } : { command } });
    const d = got.decision;
    say($("act-msg"), d ? `${d.code}: ${d.reason}` : `${command}: done`, "ok");
    loadCompensation();
  } catch (err) {
    say($("act-msg"), err.message, "bad");
  }
}

export function wireCompensation() {
  $("comp-filter").addEventListener("change", loadCompensation);
  $("act-ack").addEventListener("click", () => act("acknowledge"));
  $("act-reset").addEventListener("click", () => act("reset"));
  $("act-insert").addEventListener("click", () => act("insert_change"));
  $("shadow").addEventListener("change", async (e) => {
    const want = e.target.checked;
    switching = true;
    try {
      await api("/compensation/shadow", { method: "PUT", json: { shadow: want } });
      say($("shadow-msg"), want ? "shadow mode on: nothing is written to the CNC"
                                : "shadow mode off: offsets are written to the CNC", "ok");
    } catch (err) {
      e.target.checked = !want;
      say($("shadow-msg"), err.message, "bad");
    } finally {
      switching = false;
    }
  });
}
