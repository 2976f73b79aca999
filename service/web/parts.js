// Parts view: the last part records as rows and the job's features as columns (each cell the
// feature's deviation, marked when out of tolerance), the feature under the laser now, and a
// trend a feature over the last 50 parts.
import { $, api, clock } from "./api.js";
import { drawLines } from "./chart.js";

let features = [];

function cell(f) {
  const td = document.createElement("td");
  td.className = "num";
  if (!f || f.diameter_mm == null) { td.textContent = "–"; return td; }
  const dev = (f.diameter_mm - f.nominal_mm) * 1000;
  td.textContent = `${dev >= 0 ? "+" : ""}${dev.toFixed(1)} µm`;
  if (f.verdict !== "ok") td.classList.add("out");
  td.title = `${f.name}: ${f.diameter_mm.toFixed(4)} mm, ${f.n} measurements, ${f.verdict}`;
  return td;
}

export async function loadParts() {
  const [st, parts] = await Promise.all([api("/status"), api("/parts?limit=50")]);
  onStatus(st);
  // The newest part's job: its parts as rows, its features as columns.
  const items = parts.items.filter((p) => p.job_id === parts.items[0]?.job_id);
  features = items.length ? items[0].features.map((f) => ({ number: f.feature, name: f.name }))
    : features;  // the features of the job in force when the newest part was made
  const head = document.createElement("tr");
  for (const t of ["part", "time", "verdict", ...features.map((f) => `${f.number} ${f.name}`)]) {
    head.append(Object.assign(document.createElement("th"), { textContent: t }));
  }
  $("parts-head").replaceChildren(head);
  $("parts-body").replaceChildren(...items.slice(0, 20).map((p) => {
    const tr = document.createElement("tr");
    const when = p.time ?? p.time_s;
    for (const t of [p.serial, clock(when), p.verdict]) {
      tr.append(Object.assign(document.createElement("td"), { textContent: t }));
    }
    if (p.verdict !== "ok") tr.children[2].classList.add("out");
    const by = Object.fromEntries(p.features.map((f) => [f.feature, f]));
    for (const f of features) tr.append(cell(by[f.number]));
    return tr;
  }));
  trends(items);
}

// Each feature's deviation part by part, oldest first, against its tolerance.
function trends(items) {
  const box = $("feature-trends");
  const parts = [...items].reverse();
  const wanted = features.map((f) => `trend-${f.number}`);
  if ([...box.children].map((c) => c.dataset.id).join() !== wanted.join()) {
    box.replaceChildren(...features.map((f) => {
      const div = document.createElement("div");
      div.dataset.id = `trend-${f.number}`;
      div.append(Object.assign(document.createElement("div"),
                               { className: "hint", textContent: `${f.number} ${f.name}` }),
                 Object.assign(document.createElement("canvas"), { id: `trend-${f.number}` }));
      return div;
    }));
  }
  for (const f of features) {
    const cells = parts.map((p) => p.features.find((x) => x.feature === f.number))
      .filter((c) => c && c.diameter_mm != null);
    const values = cells.map((c) => (c.diameter_mm - c.nominal_mm) * 1000);
    const flagged = new Set(cells.map((c, i) => (c.verdict !== "ok" ? i : -1)).filter((i) => i >= 0));
    const tol = cells[cells.length - 1];
    const lines = tol ? [{ v: tol.tol_upper_mm * 1000, label: "upper", color: "#f3c76b", dash: true },
                         { v: 0, label: "nominal", color: "#8be0b0" },
                         { v: tol.tol_lower_mm * 1000, label: "lower", color: "#f3c76b", dash: true }]
      : [];
    drawLines($(`trend-${f.number}`), values, lines, flagged, { unit: "µm", xUnit: "part" });
  }
}

export function onStatus(st) {
  const job = st.job || {};
  $("job-name").textContent = job.job
    ? `${job.job.part_number}${job.job.version ? " v" + job.job.version : ""}: ` +
      `${job.job.features} features, ${job.job.tools} tools` : "none (no nominal set)";
  $("job-held").textContent = job.offsets_held || "";
  $("job-refused").textContent = job.last_refused ? "last refused: " + job.last_refused : "";
}

export function onMeasurement(m) {
  $("feature-now").textContent = m.feature == null
    ? (m.reason ? "no feature fits" : "–") : `feature ${m.feature}`;
}
