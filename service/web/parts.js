// Parts view: the last part records as rows and the job's features as columns (each cell the
// feature's deviation, marked when out of tolerance), and the feature under the laser now.
import { $, api, clock } from "./api.js";

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
  const [st, parts] = await Promise.all([api("/status"), api("/parts?limit=20")]);
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
  $("parts-body").replaceChildren(...items.map((p) => {
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
