// DOM helpers shared by the views, and the status region: every error a view meets is shown there
// (role="alert"), never only in the console. No network code here (that is api.js).

/**
 * h("button", { type: "button", onclick }, "text", child, ...): an element with attributes and children.
 * Attributes starting with "on" become listeners; `class`, `for`, `aria-*`, `data-*` are set as attributes;
 * booleans set or leave out the attribute; null/undefined/false children are skipped.
 */
export function h(tag, attrs = {}, ...children) {
  const element = document.createElement(tag);
  for (const [key, value] of Object.entries(attrs || {})) {
    if (value === null || value === undefined || value === false) continue;
    if (key.startsWith("on") && typeof value === "function") {
      element.addEventListener(key.slice(2), value);
    } else if (key === "value" && "value" in element) {
      element.value = value;
    } else if (key === "checked" || key === "selected") {
      element[key] = Boolean(value);
    } else if (value === true) {
      element.setAttribute(key, "");
    } else {
      element.setAttribute(key, String(value));
    }
  }
  append(element, children);
  return element;
}

function append(element, children) {
  for (const child of children.flat(Infinity)) {
    if (child === null || child === undefined || child === false) continue;
    element.append(child instanceof Node ? child : document.createTextNode(String(child)));
  }
}

/** Replace the children of `element`. */
export function fill(element, ...children) {
  element.replaceChildren();
  append(element, children);
  return element;
}

let uid = 0;
/** A fresh id for label/for and aria-labelledby pairs. */
export function newId(prefix = "id") {
  uid += 1;
  return `${prefix}-${uid}`;
}

/** A labelled form field: <label for>text</label><input id> in a wrapper; returns { wrap, input }. */
export function field(labelText, input, hint = null) {
  const id = input.id || newId("field");
  input.id = id;
  const hintNode = hint ? h("small", { class: "hint", id: `${id}-hint` }, hint) : null;
  if (hintNode) input.setAttribute("aria-describedby", hintNode.id);
  return { wrap: h("div", { class: "field" }, h("label", { for: id }, labelText), input, hintNode), input };
}

/** A table with a caption-like accessible name; `columns` = [{ title, value(row) -> node|text }]. */
export function table(label, columns, rows, { empty = "None yet." } = {}) {
  if (!rows.length) return h("p", { class: "empty" }, empty);
  return h(
    "table",
    { "aria-label": label },
    h("thead", {}, h("tr", {}, columns.map((c) => h("th", { scope: "col" }, c.title)))),
    h(
      "tbody",
      {},
      rows.map((row) => h("tr", {}, columns.map((c) => h("td", { class: c.class || null }, c.value(row))))),
    ),
  );
}

// ---- the status region ------------------------------------------------------------------------------------------

const statusNode = () => document.getElementById("status");
const alertNode = () => document.getElementById("alert");

// A passing message goes after this long: left up, it covered plot buttons and axes for good. Errors stay until
// dismissed (or the page changes): they ask for something to be done.
export const SAY_MS = 8000;
let sayTimer = null;

/** A passing message for people ("Experiment created."); replaces the previous one and goes after SAY_MS. */
export function say(message) {
  statusNode().textContent = message;
  clearTimeout(sayTimer);
  if (message) sayTimer = setTimeout(() => say(""), SAY_MS);
}

/** Show an error (an ApiError, an Error or a string) in the alert region, with what was being done. */
export function showError(error, doing = "") {
  const text = typeof error === "string" ? error : error && error.message ? error.message : String(error);
  const node = alertNode();
  document.getElementById("alert-text").textContent = doing ? `Could not ${doing}: ${text}` : text;
  node.hidden = false;
}

export function clearError() {
  alertNode().hidden = true;
  document.getElementById("alert-text").textContent = "";
}

/**
 * `show(value)` for the latest value asked for: values asked for while one is being shown collapse into the last
 * (quick moves of a slider draw once each settle, in order). Returns the function that asks; its promise settles
 * once what was asked is shown.
 */
export function latestOnly(show) {
  let drawing = Promise.resolve();
  let pending = null;
  return (value) => {
    pending = value;
    drawing = drawing.then(async () => {
      if (pending === null) return;
      const next = pending;
      pending = null;
      await show(next);
    });
    return drawing;
  };
}

/** Run `action` and show its error in the status region; returns its value, or undefined when it failed. */
export async function attempt(doing, action) {
  try {
    return await action();
  } catch (error) {
    showError(error, doing);
    return undefined;
  }
}

// ---- formatting ---------------------------------------------------------------------------------------------------

export function formatBytes(bytes) {
  if (bytes === null || bytes === undefined || Number.isNaN(bytes)) return "–";
  const units = ["B", "kB", "MB", "GB", "TB"];
  let value = bytes;
  let unit = 0;
  while (value >= 1000 && unit < units.length - 1) {
    value /= 1000;
    unit += 1;
  }
  return `${value.toFixed(unit === 0 ? 0 : value < 10 ? 2 : 1)} ${units[unit]}`;
}

export function formatDuration(seconds) {
  if (seconds === null || seconds === undefined || !Number.isFinite(seconds)) return "–";
  const s = Math.max(0, Math.round(seconds));
  if (s < 60) return `${s} s`;
  if (s < 3600) return `${Math.floor(s / 60)} min ${s % 60} s`;
  return `${Math.floor(s / 3600)} h ${Math.floor((s % 3600) / 60)} min`;
}

export function formatTime(iso) {
  if (!iso) return "–";
  const date = new Date(iso);
  return Number.isNaN(date.getTime()) ? iso : date.toLocaleString();
}

/** A number with a fixed count of significant decimals, or "–". */
export function num(value, digits = 3) {
  if (value === null || value === undefined || !Number.isFinite(Number(value))) return "–";
  const text = Number(value).toFixed(digits);
  return /^-0\.?0*$/.test(text) ? text.slice(1) : text; // no "-0.0"
}

/** A heading and a body for a view, with the document title following the heading. */
export function page(container, title, ...children) {
  document.title = `${title} · fringelab`;
  fill(container, h("h1", {}, title), ...children);
}
