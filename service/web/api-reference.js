// The REST API reference, rendered from the gauge's own /openapi.json (Swagger UI comes from
// a CDN, which the gauge's security policy blocks and a machine shop's network may not reach).
const el = (tag, props = {}, ...children) => {
  const e = Object.assign(document.createElement(tag), props);
  e.append(...children);
  return e;
};

function resolve(spec, schema) {
  if (!schema) return {};
  if (schema.$ref) return resolve(spec, spec.components.schemas[schema.$ref.split("/").pop()]);
  const only = (schema.anyOf || []).filter((s) => s.type !== "null");
  return only.length === 1 ? { ...resolve(spec, only[0]), nullable: true } : schema;
}

function typeOf(spec, schema) {
  const s = resolve(spec, schema);
  if (s.enum) return s.enum.map((v) => JSON.stringify(v)).join(" | ");
  if (s.type === "array") return `array of ${typeOf(spec, s.items)}`;
  const base = s.type || (s.anyOf ? s.anyOf.map((x) => typeOf(spec, x)).join(" | ") : "any");
  return base + (s.nullable ? " or null" : "");
}

function table(head, rows) {
  if (!rows.length) return "";
  return el("table", { className: "list" },
    el("thead", {}, el("tr", {}, ...head.map((h) => el("th", { textContent: h })))),
    el("tbody", {}, ...rows.map((r) => el("tr", {}, ...r.map((c) => el("td", { textContent: c }))))));
}

function operation(spec, path, method, op) {
  const params = (op.parameters || []).map((p) => [p.name, p.in, typeOf(spec, p.schema),
    p.required ? "required" : "", p.description || ""]);
  const body = resolve(spec, op.requestBody?.content?.["application/json"]?.schema);
  const fields = Object.entries(body.properties || {}).map(([name, s]) => [name,
    typeOf(spec, s), (body.required || []).includes(name) ? "required" : "",
    resolve(spec, s).description || s.description || ""]);
  const codes = Object.entries(op.responses || {}).map(([c, r]) => `${c} ${r.description}`);
  return el("div", { className: "card op" },
    el("h3", {}, el("code", { textContent: `${method.toUpperCase()} ${path}` })),
    el("p", { textContent: op.summary || "" }),
    table(["parameter", "in", "type", "", "meaning"], params),
    fields.length ? el("div", { className: "label", textContent: "JSON body" }) : "",
    table(["field", "type", "", "meaning"], fields),
    el("p", { className: "hint", textContent: "answers: " + codes.join(" · ") }));
}

async function main() {
  const spec = await (await fetch("/openapi.json")).json();
  const byTag = new Map();
  for (const [path, ops] of Object.entries(spec.paths)) {
    for (const [method, op] of Object.entries(ops)) {
      const tag = (op.tags || ["other"])[0];
      if (!byTag.has(tag)) byTag.set(tag, []);
      byTag.get(tag).push(operation(spec, path, method, op));
    }
  }
  document.title = `${spec.info.title} ${spec.info.version} REST API`;
  $endpoints().replaceChildren(...[...byTag].flatMap(([tag, ops]) =>
    [el("h2", { textContent: tag }), ...ops]));
}

const $endpoints = () => document.getElementById("endpoints");
main().catch((err) => { $endpoints().textContent = `The API description failed to load: ${err}`; });
