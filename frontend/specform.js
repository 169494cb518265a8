// A form for a job spec, built from the API's own schema of that spec (GET /api/v1/jobs/specs: the models POST
// /api/v1/jobs takes), so the form offers exactly the parameters the API takes, with its defaults, ranges, choices
// and descriptions. Inputs that name other things (a recording, a calibration, a job) are selects the caller
// provides ("pickers"). The schemas are read once per page load and shared by every form; building a form from
// them takes about a millisecond. (The whole OpenAPI document is ten times larger and, on a loaded machine, took
// the server seconds to build the first time each of its processes was asked for it.)
import { getJSON } from "./api.js";
import { field, h, newId } from "./ui.js";

const UNITS = [
  ["_px_per_mm", "px/mm"],
  ["_mm", "mm"],
  ["_px", "px"],
  ["_s", "s"],
  ["_kn", "kN"],
  ["_deg", "°"],
  ["_um", "µm"],
];

let specs = null;

/** The server's job spec schemas ({ schemas: { name: JSON Schema } }), fetched once: every caller shares the one
 * request (a failed one is asked again next time). */
export function apiSchema() {
  specs = specs || getJSON("jobs/specs").catch((error) => {
    specs = null;
    throw error;
  });
  return specs;
}

/** A schema with its `$ref` (`#/schemas/NAME`) followed. */
export function resolve(schema, root) {
  if (schema && schema.$ref) return resolve(root.schemas[schema.$ref.split("/").pop()], root);
  return schema || {};
}

/** The schema of the spec whose `kind` is `kind`, among the server's job spec schemas. */
export function specSchema(root, kind) {
  for (const schema of Object.values(root.schemas)) {
    const k = schema.properties && resolve(schema.properties.kind, root);
    if (k && (k.const === kind || (Array.isArray(k.enum) && k.enum.length === 1 && k.enum[0] === kind))) return schema;
  }
  throw new Error(`the server's API has no job spec of kind ${kind}`);
}

/** "frame_size_px" → "Frame size (px)". */
export function labelOf(name) {
  let base = name;
  let unit = "";
  for (const [suffix, text] of UNITS) {
    if (base.toLowerCase().endsWith(suffix)) {
      base = base.slice(0, -suffix.length);
      unit = text;
      break;
    }
  }
  const words = base.replace(/_/g, " ");
  const text = words.charAt(0).toUpperCase() + words.slice(1);
  return unit ? `${text} (${unit})` : text;
}

/** A property's own schema and whether it may be null (`anyOf: [X, {type: null}]`). */
function unpack(schema, root) {
  const resolved = resolve(schema, root);
  if (Array.isArray(resolved.anyOf)) {
    const others = resolved.anyOf.filter((s) => s.type !== "null");
    if (others.length === 1) return { schema: { ...resolve(others[0], root), description: schema.description || resolved.description }, nullable: true };
  }
  return { schema: resolved, nullable: false };
}

/** One input (or group of inputs) for a property; returns { element, value(), set(v) } where value() is the JSON
 * and set(v) puts a value in (null empties it; an optional group is switched on or off). */
function control(name, property, required, root, prefix, pickers) {
  const { schema, nullable } = unpack(property, root);
  const description = property.description || schema.description || "";
  const label = labelOf(name);
  const path = prefix ? `${prefix}.${name}` : name;
  const fallback = property.default !== undefined ? property.default : schema.default;

  if (pickers[path] && pickers[path].control) return pickers[path].control; // the caller's own { element, value }
  if (pickers[path]) {
    const select = pickers[path].select;
    return { element: field(pickers[path].label || label, select, description).wrap, value: () => (select.value === "" ? null : Number(select.value) || select.value) };
  }
  const choices = schema.enum || (schema.const !== undefined ? [schema.const] : null);
  if (choices) {
    const select = h("select", {}, choices.map((c) => h("option", { value: c, selected: c === fallback }, String(c))));
    return { element: field(label, select, description).wrap, value: () => select.value, set: (v) => { select.value = v ?? fallback; } };
  }
  if (schema.type === "boolean") {
    const id = newId("check");
    const box = h("input", { type: "checkbox", id, checked: Boolean(fallback) });
    return {
      element: h("div", { class: "field check-field" }, h("label", { for: id }, box, " ", label), description ? h("small", { class: "hint" }, description) : null),
      value: () => box.checked,
      set: (v) => { box.checked = Boolean(v); },
    };
  }
  if (schema.type === "integer" || schema.type === "number") {
    const input = h("input", {
      type: "number",
      step: schema.type === "integer" ? 1 : "any",
      min: schema.minimum ?? schema.exclusiveMinimum,
      max: schema.maximum ?? schema.exclusiveMaximum,
      value: fallback ?? null,
      required: required && !nullable && fallback === undefined,
      placeholder: nullable ? "empty" : null,
    });
    return { element: field(label, input, description).wrap, value: () => (input.value === "" ? null : Number(input.value)), set: (v) => { input.value = v ?? ""; } };
  }
  if (schema.type === "array" && Array.isArray(schema.prefixItems)) {
    const inputs = schema.prefixItems.map((_, i) => h("input", { type: "number", step: "any", "aria-label": `${label}, value ${i + 1}` }));
    const id = newId("tuple");
    return {
      element: h("div", { class: "field" }, h("span", { class: "label", id }, label), h("div", { class: "tuple", role: "group", "aria-labelledby": id }, inputs), description ? h("small", { class: "hint" }, description) : null),
      value: () => (inputs.every((i) => i.value === "") ? null : inputs.map((i) => Number(i.value))),
      set: (v) => inputs.forEach((input, i) => { input.value = v ? v[i] ?? "" : ""; }),
    };
  }
  if (schema.type === "object" && schema.properties) {
    const inner = specControls(schema, root, path, pickers);
    const legend = h("legend", {}, label);
    const set = h("fieldset", { class: "sub-spec" }, legend, description ? h("small", { class: "hint" }, description) : null, inner.elements);
    if (!nullable) return { element: set, value: inner.value, set: inner.set };
    // An optional group (e.g. the board): off means null, the server's default.
    const id = newId("give");
    const give = h("input", { type: "checkbox", id });
    const toggle = () => {
      // Disabled, its inputs are neither validated nor sent (the checkbox in the legend stays usable).
      set.disabled = !give.checked;
      for (const el of inner.elements) el.hidden = !give.checked;
    };
    give.addEventListener("change", toggle);
    legend.replaceChildren(h("label", { for: id }, give, " ", label));
    toggle();
    return {
      element: set,
      value: () => (give.checked ? inner.value() : null),
      set: (v) => {
        give.checked = v !== null && v !== undefined;
        if (give.checked) inner.set(v);
        toggle();
      },
    };
  }
  const input = h("input", { type: "text", value: fallback ?? null, maxlength: schema.maxLength });
  return { element: field(label, input, description).wrap, value: () => (input.value === "" ? null : input.value), set: (v) => { input.value = v ?? ""; } };
}

function specControls(schema, root, prefix, pickers) {
  const required = new Set(schema.required || []);
  const controls = Object.entries(schema.properties)
    .filter(([name]) => name !== "kind")
    .map(([name, property]) => [name, control(name, property, required.has(name), root, prefix, pickers)]);
  return {
    elements: controls.map(([, c]) => c.element),
    value: () => {
      const out = {};
      for (const [name, c] of controls) {
        const v = c.value();
        if (v !== null) out[name] = v; // left empty: the server's default
      }
      return out;
    },
    set: (values) => {
      for (const [name, c] of controls) if (values && name in values && c.set) c.set(values[name]);
    },
  };
}

/**
 * Inputs for the spec of `kind`, from the server's schema: { elements, spec() → the JSON to POST }. `pickers`
 * maps a property path ("recording_id") to { select, label } made by the caller, or to { control: { element,
 * value() } } for a control the caller makes whole (the consent to use a bad calibration).
 */
export async function specInputs(kind, pickers = {}) {
  const root = await apiSchema();
  const schema = specSchema(root, kind);
  const controls = specControls(schema, root, "", pickers);
  return { elements: controls.elements, spec: () => ({ kind, ...controls.value() }), set: controls.set, description: schema.description || "" };
}
