// Small canvas charts: the diameter trend with its tolerance band, and bars.
function fit(canvas) {
  const dpr = window.devicePixelRatio || 1;
  const w = canvas.clientWidth, h = canvas.clientHeight || canvas.height;
  if (canvas.width !== Math.round(w * dpr)) { canvas.width = Math.round(w * dpr); canvas.height = Math.round(h * dpr); }
  const ctx = canvas.getContext("2d");
  ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
  ctx.clearRect(0, 0, w, h);
  return { ctx, w, h };
}

// Round tick values between lo and hi, about n of them (1, 2 or 5 times a power of ten apart).
export function ticks(lo, hi, n = 5) {
  if (!(hi > lo)) return [lo];
  const mag = 10 ** Math.floor(Math.log10((hi - lo) / n));
  const step = [1, 2, 5, 10].map((k) => k * mag).find((s) => (hi - lo) / s <= n + 1 + 1e-9);
  const out = [];
  for (let v = Math.ceil(lo / step) * step; v <= hi + step * 1e-9; v += step) {
    out.push(Math.abs(v) < step * 1e-9 ? 0 : v);
  }
  return out;
}

// Decimals that tell ticks `step` apart.
const decimals = (vs) => vs.length < 2 ? 4 :
  Math.max(0, Math.min(6, -Math.floor(Math.log10(Math.abs(vs[1] - vs[0])) + 1e-9)));

// Axes: tick values on the left (y, in `yUnit`) and below (x), gridlines, the units named.
function axes(ctx, pad, w, h, x, y, xs, ys) {
  ctx.save();
  ctx.font = "11px system-ui"; ctx.fillStyle = "#9aa5b1"; ctx.strokeStyle = "rgba(154,165,177,.18)";
  const yt = ticks(ys.lo, ys.hi, Math.max(2, Math.floor((h - pad.t - pad.b) / 28)))
    .filter((v) => !ys.integer || Number.isInteger(v));
  const yd = ys.integer ? 0 : decimals(yt);
  for (const v of yt) {
    ctx.beginPath(); ctx.moveTo(pad.l, y(v)); ctx.lineTo(w - pad.r, y(v)); ctx.stroke();
    ctx.textAlign = "right"; ctx.fillText(v.toFixed(yd), pad.l - 4, y(v) + 4);
  }
  ctx.textAlign = "left"; ctx.fillText(ys.unit, 4, pad.t + 8);
  const xt = ticks(xs.lo, xs.hi, Math.max(2, Math.floor((w - pad.l - pad.r) / 90)))
    .filter((v) => !xs.integer || Number.isInteger(v));
  const xd = xs.integer ? 0 : decimals(xt);
  ctx.textAlign = "center";
  for (const v of xt) ctx.fillText(v.toFixed(xd), x(v), h - pad.b + 13);
  ctx.textAlign = "right"; ctx.fillText(xs.unit, w - pad.r, h - 3);
  ctx.restore();
}

// points: [{seq, d}] (mm); band: {lo, hi, nominal} (mm) or null; marks: [seq];
// process: [{seq, d}] (mm), the uncompensated process, dashed (none when no offset applied)
export function drawTrend(canvas, points, band, marks, process = []) {
  const { ctx, w, h } = fit(canvas);
  const pad = { l: 64, r: 8, t: 8, b: 30 };
  ctx.font = "12px system-ui"; ctx.fillStyle = "#9aa5b1";
  if (!points.length) { ctx.fillText("no measurements yet", pad.l, h / 2); return; }
  const ds = [...points, ...process].map((p) => p.d);
  let lo = Math.min(...ds), hi = Math.max(...ds);
  if (band) { lo = Math.min(lo, band.lo); hi = Math.max(hi, band.hi); }
  const span = Math.max(hi - lo, 0.002); lo -= span * 0.1; hi += span * 0.1;
  const s0 = points[0].seq, s1 = Math.max(points[points.length - 1].seq, s0 + 1);
  const x = (s) => pad.l + (s - s0) / (s1 - s0) * (w - pad.l - pad.r);
  const y = (d) => pad.t + (hi - d) / (hi - lo) * (h - pad.t - pad.b);
  if (band) {
    ctx.fillStyle = "rgba(31, 122, 77, .30)";
    ctx.fillRect(pad.l, y(band.hi), w - pad.l - pad.r, y(band.lo) - y(band.hi));
    ctx.strokeStyle = "rgba(139, 224, 176, .6)"; ctx.setLineDash([4, 4]);
    ctx.beginPath(); ctx.moveTo(pad.l, y(band.nominal)); ctx.lineTo(w - pad.r, y(band.nominal)); ctx.stroke();
    ctx.setLineDash([]);
  }
  axes(ctx, pad, w, h, x, y, { lo: s0, hi: s1, unit: "measurement", integer: true },
       { lo, hi, unit: "mm" });
  ctx.strokeStyle = "#e0a030";
  for (const s of marks) {
    if (s < s0) continue;
    ctx.beginPath(); ctx.moveTo(x(s), pad.t); ctx.lineTo(x(s), h - pad.b); ctx.stroke();
  }
  if (process.length) {
    ctx.strokeStyle = "#c58af9"; ctx.setLineDash([5, 3]); ctx.beginPath();
    process.forEach((p, i) => (i ? ctx.lineTo(x(p.seq), y(p.d)) : ctx.moveTo(x(p.seq), y(p.d))));
    ctx.stroke(); ctx.setLineDash([]);
  }
  ctx.strokeStyle = "#6fb3ff"; ctx.lineWidth = 1.5; ctx.beginPath();
  points.forEach((p, i) => (i ? ctx.lineTo(x(p.seq), y(p.d)) : ctx.moveTo(x(p.seq), y(p.d))));
  ctx.stroke(); ctx.lineWidth = 1;
}

// bars: [{label, value}] ; limit: a reference line (e.g. the "good" limit)
export function drawBars(canvas, bars, unit, limit) {
  const { ctx, w, h } = fit(canvas);
  const pad = { l: 44, r: 8, t: 16, b: 18 };
  const top = Math.max(...bars.map((b) => b.value), limit || 0) * 1.15 || 1;
  const bw = (w - pad.l - pad.r) / Math.max(bars.length, 1);
  const y = (v) => pad.t + (1 - v / top) * (h - pad.t - pad.b);
  ctx.font = "11px system-ui"; ctx.fillStyle = "#9aa5b1";
  ctx.fillText(unit, 4, 12);
  ctx.fillText(top.toFixed(2), 4, y(top) + 10);
  bars.forEach((b, i) => {
    ctx.fillStyle = limit && b.value > limit ? "#a32b2b" : "#2d6cdf";
    ctx.fillRect(pad.l + i * bw + 1, y(b.value), Math.max(bw - 2, 1), h - pad.b - y(b.value));
    if (bars.length <= 40) { ctx.fillStyle = "#9aa5b1"; ctx.fillText(b.label, pad.l + i * bw + 2, h - 4); }
  });
  if (limit) {
    ctx.strokeStyle = "#f3c76b"; ctx.setLineDash([4, 3]); ctx.beginPath();
    ctx.moveTo(pad.l, y(limit)); ctx.lineTo(w - pad.r, y(limit)); ctx.stroke(); ctx.setLineDash([]);
  }
}

// A line chart of values with horizontal reference lines; flagged points drawn red.
// values: [number]; lines: [{v, label, color, dash}]; flagged: Set of indices
// opts: {unit (y), xUnit, note: said on the chart (e.g. why it has no limits yet)}
export function drawLines(canvas, values, lines, flagged = new Set(), opts = {}) {
  const { ctx, w, h } = fit(canvas);
  const pad = { l: 70, r: 8, t: 8, b: 30 };
  ctx.font = "11px system-ui"; ctx.fillStyle = "#9aa5b1";
  if (!values.length) { ctx.fillText(opts.note || "no values yet", pad.l, h / 2); return; }
  const all = [...values, ...lines.map((l) => l.v)];
  let lo = Math.min(...all), hi = Math.max(...all);
  const span = Math.max(hi - lo, 1e-6); lo -= span * 0.08; hi += span * 0.08;
  const x = (i) => pad.l + (values.length > 1 ? i / (values.length - 1) : 0.5) * (w - pad.l - pad.r);
  const y = (v) => pad.t + (hi - v) / (hi - lo) * (h - pad.t - pad.b);
  const n = values.length;
  axes(ctx, pad, w, h, (v) => x(v - 1), y,
       { lo: 1, hi: Math.max(n, 2), unit: opts.xUnit || "", integer: true },
       { lo, hi, unit: opts.unit || "" });
  for (const l of lines) {
    ctx.strokeStyle = l.color; ctx.setLineDash(l.dash ? [5, 4] : []);
    ctx.beginPath(); ctx.moveTo(pad.l, y(l.v)); ctx.lineTo(w - pad.r, y(l.v)); ctx.stroke();
    ctx.fillStyle = l.color; ctx.textAlign = "right";
    ctx.fillText(l.label, w - pad.r - 2, y(l.v) - 3); ctx.textAlign = "left";
  }
  if (opts.note) { ctx.fillStyle = "#f3c76b"; ctx.fillText(opts.note, pad.l + 6, pad.t + 12); }
  ctx.setLineDash([]); ctx.strokeStyle = "#6fb3ff"; ctx.beginPath();
  values.forEach((v, i) => (i ? ctx.lineTo(x(i), y(v)) : ctx.moveTo(x(i), y(v))));
  ctx.stroke();
  values.forEach((v, i) => {
    ctx.fillStyle = flagged.has(i) ? "#ff5a45" : "#6fb3ff";
    ctx.beginPath(); ctx.arc(x(i), y(v), flagged.has(i) ? 4 : 2.5, 0, 2 * Math.PI); ctx.fill();
  });
}

// A histogram of values with the specification limits (lsl, usl may be null).
export function drawHistogram(canvas, values, lsl, usl, nominal) {
  const { ctx, w, h } = fit(canvas);
  const pad = { l: 36, r: 8, t: 8, b: 30 };
  ctx.font = "11px system-ui"; ctx.fillStyle = "#9aa5b1";
  if (!values.length) { ctx.fillText("no values yet", 10, h / 2); return; }
  const edges = [...values, ...[lsl, usl].filter((v) => v != null)];
  let lo = Math.min(...edges), hi = Math.max(...edges);
  const span = Math.max(hi - lo, 1e-6); lo -= span * 0.05; hi += span * 0.05;
  const bins = 30, counts = new Array(bins).fill(0);
  for (const v of values) counts[Math.min(bins - 1, Math.floor((v - lo) / (hi - lo) * bins))]++;
  const top = Math.max(...counts);
  const x = (v) => pad.l + (v - lo) / (hi - lo) * (w - pad.l - pad.r);
  const bw = (w - pad.l - pad.r) / bins;
  axes(ctx, pad, w, h, x, (c) => h - pad.b - c / top * (h - pad.t - pad.b),
       { lo, hi, unit: "mm" }, { lo: 0, hi: top, unit: "count", integer: true });
  ctx.fillStyle = "#2d6cdf";
  counts.forEach((c, i) => {
    const bh = c / top * (h - pad.t - pad.b);
    ctx.fillRect(pad.l + i * bw + 1, h - pad.b - bh, Math.max(bw - 2, 1), bh);
  });
  for (const [v, label, color] of [[lsl, "LSL", "#ff5a45"], [usl, "USL", "#ff5a45"],
                                   [nominal, "nominal", "#8be0b0"]]) {
    if (v == null) continue;
    ctx.strokeStyle = color; ctx.beginPath(); ctx.moveTo(x(v), pad.t); ctx.lineTo(x(v), h - pad.b);
    ctx.stroke(); ctx.fillStyle = color; ctx.fillText(label, x(v) + 3, pad.t + 10);
  }
}

// The revolution in polar form: the reference circle, the measured profile about it (its
// deviation magnified so that the largest reaches a quarter of the radius; rings in um), and
// the spindle axis where it lies from the surface's centre (the eccentricity, same scale).
// profile: {deg: [...], mm: [...]} or null; ecc: {mm, deg} or null.
export function drawPolar(canvas, profile, ecc) {
  const { ctx, w, h } = fit(canvas);
  const cx = w / 2, cy = h / 2, r0 = Math.min(w, h) * 0.3;
  const devs = profile ? profile.mm.map(Math.abs) : [];
  const reach = Math.max(...devs, ecc ? ecc.mm : 0, 0.001);  // mm shown at a quarter radius
  const stepUm = ticks(0, reach * 1000, 2).find((v) => v > 0) || reach * 1000;
  const k = (r0 * 0.25) / reach;                              // px per mm of deviation
  ctx.font = "11px system-ui"; ctx.fillStyle = "#9aa5b1";
  ctx.strokeStyle = "rgba(154,165,177,.25)";
  for (const ring of [-stepUm, stepUm]) {
    const r = r0 + ring / 1000 * k;
    if (r <= 0) continue;
    ctx.setLineDash([3, 3]); ctx.beginPath(); ctx.arc(cx, cy, r, 0, 2 * Math.PI); ctx.stroke();
  }
  ctx.setLineDash([]);
  ctx.fillText(`rings ±${stepUm.toFixed(stepUm < 1 ? 1 : 0)} µm`, 4, 14);
  ctx.strokeStyle = "rgba(139, 224, 176, .8)";                // the reference circle
  ctx.beginPath(); ctx.arc(cx, cy, r0, 0, 2 * Math.PI); ctx.stroke();
  if (profile && profile.deg.length) {
    ctx.strokeStyle = "#6fb3ff"; ctx.lineWidth = 1.5; ctx.beginPath();
    profile.deg.forEach((d, i) => {
      const a = d * Math.PI / 180, r = r0 + profile.mm[i] * k;
      const px = cx + r * Math.cos(a), py = cy - r * Math.sin(a);
      i ? ctx.lineTo(px, py) : ctx.moveTo(px, py);
    });
    ctx.closePath(); ctx.stroke(); ctx.lineWidth = 1;
  } else {
    ctx.fillText("form: not known yet", cx - 48, cy + 4);
  }
  if (ecc) {                                                  // the spindle axis
    const a = ecc.deg * Math.PI / 180;
    const px = cx - ecc.mm * k * Math.cos(a), py = cy + ecc.mm * k * Math.sin(a);
    ctx.strokeStyle = "#e0a030"; ctx.beginPath();
    ctx.moveTo(px - 6, py); ctx.lineTo(px + 6, py); ctx.moveTo(px, py - 6); ctx.lineTo(px, py + 6);
    ctx.stroke();
  }
  ctx.fillStyle = "#9aa5b1"; ctx.fillText("0°", cx + r0 + 6, cy + 4);
}
