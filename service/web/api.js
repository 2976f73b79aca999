// Talking to the service: JSON requests with the technician key, errors as readable text.
export const $ = (id) => document.getElementById(id);

export function key() { return sessionStorage.getItem("shaftgauge-key") || ""; }
export function setKey(k) { sessionStorage.setItem("shaftgauge-key", k); }

export class ApiError extends Error {}

function detail(body, status) {
  if (body && typeof body.detail === "string") return body.detail;
  if (body && Array.isArray(body.detail)) {
    return body.detail.map((e) => `${(e.loc || []).slice(1).join(".")}: ${e.msg}`).join("; ");
  }
  return `HTTP ${status}`;
}

export async function api(path, { method = "GET", json, body, headers = {} } = {}) {
  const h = { ...headers };
  if (method !== "GET" && key()) h["X-API-Key"] = key();
  if (json !== undefined) { h["Content-Type"] = "application/json"; body = JSON.stringify(json); }
  let r;
  try {
    // A hung service must show as lost, not leave the page waiting forever.
    const signal = AbortSignal.timeout(method === "GET" ? 4000 : 120000);
    r = await fetch("/api/v1" + path, { method, headers: h, body, signal });
  } catch (err) {
    throw new ApiError("the service cannot be reached");
  }
  const text = await r.text();
  let data = null;
  try { data = text ? JSON.parse(text) : null; } catch { data = null; }
  if (!r.ok) {
    const why = r.status === 401 || r.status === 403
      ? "enter a technician key (Technician page): " + detail(data, r.status) : detail(data, r.status);
    throw new ApiError(why);
  }
  return data;
}

export const um = (mm, digits = 1) => mm == null ? "–" : (mm * 1000).toFixed(digits) + " µm";
export const mm = (v, digits = 4) => v == null ? "–" : v.toFixed(digits) + " mm";
export const clock = (unix) => new Date(unix * 1000).toLocaleTimeString();

export function say(el, text, kind = "") { el.textContent = text; el.className = "msg " + kind; }
