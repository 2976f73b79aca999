// SPC view: the X-bar control chart with its limits and the rule violations, the capability
// figures with their confidence intervals, and a histogram against the tolerance.
import { $, api, clock, mm } from "./api.js";
import { drawHistogram, drawLines } from "./chart.js";

let figures = null;
const fmt = (v, d = 2) => v == null ? "–" : v.toFixed(d);
const ci = (c) => c == null ? "" : ` (95 %: ${c[0].toFixed(2)}–${c[1].toFixed(2)})`;

export async function loadSpc() {
  const chosen = $("spc-feature").value;
  figures = await api("/spc" + (chosen ? `?feature=${chosen}` : ""));
  features(figures.features || [], chosen);
  render();
}

// The features that have a chart: a choice kept while it has one.
function features(numbers, chosen) {
  const select = $("spc-feature");
  const have = [...select.options].slice(1).map((o) => o.value);
  if (have.join() !== numbers.join()) {
    select.replaceChildren(new Option("measured last", ""),
                           ...numbers.map((n) => new Option(`feature ${n}`, String(n))));
    select.value = numbers.map(String).includes(chosen) ? chosen : "";
  }
}

export function wireSpc() {
  $("spc-feature").addEventListener("change", () => loadSpc().catch(() => {}));
}

export function onSpcEvent() { if (!$("view-spc").hidden) loadSpc().catch(() => {}); }

export function redrawSpc() { if (figures && !$("view-spc").hidden) render(); }

function render() {
  const f = figures;
  const base = f.baseline;
  $("spc-n").textContent = `${f.n} values in ${f.subgroups} subgroups of ${f.subgroup_size}`;
  $("spc-baseline").textContent = base.complete ? "limits set" :
    `baseline: ${base.subgroups} of ${base.needed} subgroups`;
  $("spc-mean").textContent = mm(f.mean_mm);
  $("spc-std").textContent = f.std_mm == null ? "–" : (f.std_mm * 1000).toFixed(2) + " µm";
  $("spc-cp").textContent = fmt(f.cp) + ci(f.cp_ci);
  $("spc-cpk").textContent = fmt(f.cpk) + ci(f.cpk_ci);
  $("spc-pp").textContent = fmt(f.pp);
  $("spc-ppk").textContent = fmt(f.ppk);
  const cpk = $("spc-cpk-pill");
  cpk.textContent = f.cpk == null ? "Cpk –" : `Cpk ${f.cpk.toFixed(2)}`;
  cpk.className = "pill " + (f.cpk == null ? "" : f.cpk >= 1.33 ? "ok" : f.cpk >= 1 ? "warn" : "bad");
  const rule = $("spc-rule");
  rule.hidden = !f.rule_violation;
  const means = f.points.map((p) => p.mean_mm);
  const flagged = new Set(f.points.map((p, i) => (p.rules.length ? i : -1)).filter((i) => i >= 0));
  const lines = [];
  if (f.limits) {
    lines.push({ v: f.limits.ucl_mm, label: "UCL", color: "#f3c76b", dash: true },
               { v: f.limits.center_mm, label: "CL", color: "#8be0b0" },
               { v: f.limits.lcl_mm, label: "LCL", color: "#f3c76b", dash: true });
  }
  drawLines($("spc-chart"), means, lines, flagged, {
    unit: "mm", xUnit: "subgroup",
    note: f.limits ? "" : `no control limits until the baseline is complete (${base.subgroups} of ` +
      `${base.needed} subgroups)`,
  });
  drawHistogram($("spc-hist"), f.points.flatMap((p) => p.values_mm), f.lsl_mm, f.usl_mm,
                f.nominal_mm);
  const list = $("spc-violations");
  list.replaceChildren();
  for (const v of [...f.violations].reverse()) {
    const tr = document.createElement("tr");
    for (const text of [clock(v.time), mm(v.mean_mm),
                        v.rules.map((r) => `${r.rule}: ${r.text}`).join("; ")]) {
      tr.append(Object.assign(document.createElement("td"), { textContent: text }));
    }
    list.append(tr);
  }
}
