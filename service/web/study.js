// The type-1 gauge study in the technician view: start one, follow its progress, the values'
// run chart with the reference and the ±0.1 T band, and the studies so far.
import { $, api, clock, say } from "./api.js";
import { drawLines } from "./chart.js";

let shownRunning = false;

function chart(values, ref, tol) {
  const lines = ref == null ? [] : [
    { v: ref + 0.1 * tol, label: "+0.1T", color: "#f3c76b", dash: true },
    { v: ref, label: "ref", color: "#8be0b0" },
    { v: ref - 0.1 * tol, label: "-0.1T", color: "#f3c76b", dash: true }];
  drawLines($("study-chart"), values, lines, new Set(), { unit: "mm", xUnit: "value" });
}

function verdict(s) {
  if (s.state === "running") return "running";
  if (s.state !== "done") return `failed: ${s.reason}`;
  return s.result.capable ? "capable" : "not capable: " + s.result.reasons.join("; ");
}

function table(items) {
  const body = $("studies");
  body.replaceChildren();
  for (const s of items) {
    const r = s.result || {};
    const tr = document.createElement("tr");
    tr.dataset.state = s.state;
    const cells = [s.id, s.finished ? clock(s.finished) : "–", s.n,
                   r.cg == null ? "–" : r.cg.toFixed(2), r.cgk == null ? "–" : r.cgk.toFixed(2),
                   r.bias == null ? "–" : (r.bias * 1000).toFixed(2), verdict(s)];
    for (const c of cells) tr.append(Object.assign(document.createElement("td"), { textContent: String(c) }));
    tr.lastChild.className = r.capable ? "verdict-good" : s.state === "running" ? "" : "verdict-refused";
    body.append(tr);
  }
}

export async function refreshStudy() {
  const st = await api("/gauge-studies");
  const run = st.running;
  $("study-run").disabled = !!run;
  if (run) {
    say($("study-msg"), `study ${run.id}: ${run.done} of ${run.n} values (offsets held)`);
    chart(run.values_mm, run.certified_mm, run.tolerance_mm);
  } else if (shownRunning || !$("study-msg").textContent) {
    const last = st.items[0];
    if (last) {
      const r = last.result;
      say($("study-msg"), r ? `study ${last.id}: Cg ${r.cg?.toFixed(2)}, Cgk ` +
          `${r.cgk?.toFixed(2)}: ${verdict(last)}` : `study ${last.id}: ${verdict(last)}`,
          r && r.capable ? "ok" : "bad");
      chart(last.values, last.certified_mm, last.tolerance_mm);
    }
    if (st.blocking) say($("study-msg"), `${$("study-msg").textContent}. Offsets blocked: ` +
                         st.blocking, "bad");
  }
  shownRunning = !!run;
  table(st.items);
}

export function wireStudy() {
  $("study-run").addEventListener("click", async () => {
    try {
      const body = { certified_mm: Number($("study-mm").value), n: Number($("study-n").value) };
      if ($("study-feature").value) body.feature = Number($("study-feature").value);
      const r = await api("/gauge-studies", { method: "POST", json: body });
      say($("study-msg"), `study ${r.id} started: ${r.n} values, T = ${r.tolerance_mm} mm`, "ok");
      shownRunning = true;
      await refreshStudy();
    } catch (err) { say($("study-msg"), err.message, "bad"); }
  });
}
