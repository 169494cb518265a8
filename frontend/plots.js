// Plotly helpers of the dashboard: every plot is a Figure (a titled box with "Download CSV" and "Download PNG"
// buttons for the data and the image behind it), updated with Plotly.react; every axis title carries its unit
// (use `axis(name, unit)`). The 2-D map turns click-and-drag into section lines and plain clicks into points.
// No network code here: views fetch the data (api.js) and hand arrays to these functions; plotly.js itself
// (4.8 MB) is loaded by the first figure drawn (loadPlotly), so pages without a plot never load it and pages with
// one show their content first.
import { h, newId } from "./ui.js";

let plotlyLoading = null;

/**
 * plotly.js, loaded once on first use: a script injected into the page from the versioned URL that index.html
 * names in `<meta name="plotly-js">`. Resolves to `window.Plotly`; a failed load rejects (and the next call tries
 * again).
 */
export function loadPlotly() {
  if (window.Plotly) return Promise.resolve(window.Plotly);
  if (!plotlyLoading) {
    plotlyLoading = new Promise((resolve, reject) => {
      const script = document.createElement("script");
      script.src = document.querySelector('meta[name="plotly-js"]').content;
      script.onload = () => resolve(window.Plotly);
      script.onerror = () => {
        plotlyLoading = null;
        script.remove();
        reject(new Error("Could not load the plotting library (plotly.js) from the server"));
      };
      document.head.append(script);
    });
  }
  return plotlyLoading;
}

export const COLORS = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#17becf", "#8c564b", "#e377c2"];
// Drawn over the red-white-blue map: dark or saturated colours that neither blend into it nor each other.
export const MARK_COLORS = ["#111111", "#e6a100", "#2ca02c", "#c2185b", "#6a3d9a", "#00838f", "#8c564b"];
export const DEFLECTION_SCALE = "RdBu"; // diverging, red up and blue down; white is zero when the range is symmetric
const CONFIG = {
  responsive: true,
  displaylogo: false,
  // Our own buttons download the image and the data; the mode bar keeps zoom, pan and reset.
  modeBarButtonsToRemove: ["toImage", "sendDataToCloud", "lasso2d", "select2d"],
};
const FONT = { family: "system-ui, sans-serif", size: 12, color: "#1d2430" };

/** An axis title that names its unit: axis("x", "mm") → { title: { text: "x (mm)" } }. */
export function axis(name, unit, extra = {}) {
  if (!unit) throw new Error(`axis "${name}" needs a unit`);
  return { title: { text: `${name} (${unit})` }, automargin: true, zeroline: false, ...extra };
}

/** Layout with the dashboard's defaults; uirevision keeps the user's zoom and camera across Plotly.react. */
export function layout(extra = {}) {
  return {
    font: FONT,
    margin: { l: 60, r: 20, t: 30, b: 50 },
    uirevision: "keep",
    paper_bgcolor: "#fff",
    plot_bgcolor: "#fff",
    legend: { orientation: "h", x: 0, y: 1.0, yanchor: "bottom" },
    ...extra,
  };
}

// ---- CSV ------------------------------------------------------------------------------------------------------

/** CSV text: a header of column names (with units, e.g. "x_mm") and one line per row; numbers in full. */
export function toCSV(columns, rows) {
  const cell = (value) => {
    if (value === null || value === undefined || (typeof value === "number" && Number.isNaN(value))) return "";
    const text = String(value);
    return /[",\n]/.test(text) ? `"${text.replace(/"/g, '""')}"` : text;
  };
  const lines = [columns.map(cell).join(",")];
  for (const row of rows) lines.push(row.map(cell).join(","));
  return `${lines.join("\n")}\n`;
}

/** Let the browser save `text` as a file named `filename`. */
export function saveText(filename, text, type = "text/csv") {
  const url = URL.createObjectURL(new Blob([text], { type }));
  const link = h("a", { href: url, download: filename, hidden: true });
  document.body.append(link);
  link.click();
  link.remove();
  setTimeout(() => URL.revokeObjectURL(url), 10_000);
}

// ---- a plot with its downloads -------------------------------------------------------------------------------------

/**
 * A titled plot. `name` is its accessible name and the base of its buttons' labels ("Download <name> CSV");
 * `filename` (no extension) names the downloads; `csv()` returns { columns, rows } of the data shown now.
 */
export class Figure {
  constructor({ name, filename, csv, height = 420, className = "", config = {} }) {
    this.name = name;
    this.config = { ...CONFIG, ...config };
    this.filename = filename;
    this.csv = csv;
    const titleId = newId("plot-title");
    this.plot = h("div", { class: "plot-area", role: "img", "aria-label": name, style: `height:${height}px` });
    this.csvButton = h(
      "button",
      { type: "button", class: "small", "aria-label": `Download ${name} CSV`, onclick: () => this.downloadCSV() },
      "CSV",
    );
    this.pngButton = h(
      "button",
      { type: "button", class: "small", "aria-label": `Download ${name} PNG`, onclick: () => this.downloadPNG() },
      "PNG",
    );
    this.title = h("span", { id: titleId }, name);
    this.element = h(
      "figure",
      { class: `plot ${className}`, "aria-labelledby": titleId },
      h(
        "figcaption",
        {},
        this.title,
        h("span", { class: "downloads" }, "Download ", this.csvButton, " ", this.pngButton),
      ),
      this.plot,
    );
    this.drawn = false;
  }

  /** A new title (and accessible name, and button labels): a plot's title says what it shows. */
  rename(name) {
    if (name === this.name) return;
    this.name = name;
    this.title.textContent = name;
    this.plot.setAttribute("aria-label", name);
    this.csvButton.setAttribute("aria-label", `Download ${name} CSV`);
    this.pngButton.setAttribute("aria-label", `Download ${name} PNG`);
  }

  async react(traces, plotLayout) {
    const Plotly = await loadPlotly();
    await Plotly.react(this.plot, traces, plotLayout, this.config);
    this.drawn = true;
  }

  /** `csv()` may name the file itself (`filename`, no extension), e.g. to say which grid it holds. */
  downloadCSV() {
    const { columns, rows, filename } = this.csv();
    saveText(`${filename || this.filename}.csv`, toCSV(columns, rows));
  }

  downloadPNG() {
    const { width, height } = this.plot.getBoundingClientRect();
    return window.Plotly.downloadImage(this.plot, {
      format: "png",
      filename: this.filename,
      width: Math.max(600, Math.round(width)),
      height: Math.max(400, Math.round(height)),
    });
  }

  purge() {
    if (this.drawn) window.Plotly.purge(this.plot);
    this.drawn = false;
  }
}

// ---- fields (a 2-D array of deflection on a regular x, y grid) --------------------------------------------------

// A field is { x: number[nx] (mm), y: number[ny] (mm), z: Float32Array[ny] rows (mm, NaN where unmeasured) }.
// Heatmap and surface take the rows as they are; NaN leaves a hole.

/** Long-format CSV rows (x, y, value) of a field, row by row; unmeasured points have an empty value. */
export function fieldRows(field) {
  const rows = [];
  field.z.forEach((row, j) => {
    for (let i = 0; i < row.length; i += 1) rows.push([field.x[i], field.y[j], row[i]]);
  });
  return rows;
}

/**
 * [min, max] of the finite values of a field inside an x, y window (mm; null: the whole field), or null when
 * there are none: the colour range of what is in view.
 */
export function fieldRange(field, window = null) {
  let lo = Infinity;
  let hi = -Infinity;
  const inX = field.x.map((x) => !window || (x >= window.x0 && x <= window.x1));
  field.z.forEach((row, j) => {
    const y = field.y[j];
    if (window && (y < window.y0 || y > window.y1)) return;
    for (let i = 0; i < row.length; i += 1) {
      const w = row[i];
      if (inX[i] && Number.isFinite(w)) {
        if (w < lo) lo = w;
        if (w > hi) hi = w;
      }
    }
  });
  if (lo > hi) return null;
  return lo === hi ? [lo - 1e-3, hi + 1e-3] : [lo, hi];
}

/**
 * `field` resampled at the nodes of `onto` (bilinear; NaN where a neighbour is unmeasured or the node is outside
 * `field`): two cameras' results in the plate frame, compared node by node.
 */
export function resampleField(field, onto) {
  const locate = (axisValues, v) => {
    const n = axisValues.length;
    if (n < 2) return null;
    const step = axisValues[1] - axisValues[0];
    const f = (v - axisValues[0]) / step;
    if (f < 0 || f > n - 1) return null;
    const i = Math.min(n - 2, Math.floor(f));
    return [i, f - i];
  };
  const xs = onto.x.map((x) => locate(field.x, x));
  return {
    x: onto.x,
    y: onto.y,
    z: onto.y.map((y) => {
      const row = new Float32Array(onto.x.length).fill(NaN);
      const at = locate(field.y, y);
      if (!at) return row;
      const [j, fy] = at;
      const a = field.z[j];
      const b = field.z[j + 1];
      xs.forEach((loc, k) => {
        if (!loc) return;
        const [i, fx] = loc;
        row[k] = (a[i] * (1 - fx) + a[i + 1] * fx) * (1 - fy) + (b[i] * (1 - fx) + b[i + 1] * fx) * fy;
      });
      return row;
    }),
  };
}

/** The 3-D surface of a field. `range` = [min, max] fixes the colours across frames. */
export function surfaceTraces(field, { range = null, valueName = "w", unit = "mm", rangeNote = "" } = {}) {
  return [
    {
      type: "surface",
      x: field.x,
      y: field.y,
      z: field.z,
      colorscale: DEFLECTION_SCALE,
      cmin: range ? range[0] : undefined,
      cmax: range ? range[1] : undefined,
      cmid: range ? undefined : 0,
      colorbar: { title: { text: `${valueName} (${unit})${rangeNote}` }, len: 0.8 },
      hovertemplate: `x %{x:.2f} mm<br>y %{y:.2f} mm<br>${valueName} %{z:.3f} ${unit}<extra></extra>`,
    },
  ];
}

export function surfaceLayout({ zName = "deflection w", unit = "mm", zRange = null } = {}) {
  return layout({
    margin: { l: 0, r: 0, t: 10, b: 0 },
    scene: {
      xaxis: axis("x", "mm"),
      yaxis: axis("y", "mm"),
      zaxis: axis(zName, unit, zRange ? { range: zRange } : {}),
      aspectmode: "manual",
      aspectratio: { x: 1, y: 1, z: 0.4 },
      camera: { eye: { x: -1.3, y: -1.5, z: 1.1 } },
    },
  });
}

/** The 2-D map of a field, with section lines (labelled A, B, ...) and points (P1, P2, ...) drawn over it. */
export function mapTraces(field, { range = null, points = [], valueName = "w", unit = "mm", rangeNote = "" } = {}) {
  const traces = [
    {
      type: "heatmap",
      x: field.x,
      y: field.y,
      z: field.z,
      colorscale: DEFLECTION_SCALE,
      zmin: range ? range[0] : undefined,
      zmax: range ? range[1] : undefined,
      zmid: range ? undefined : 0,
      zsmooth: false,
      colorbar: { title: { text: `${valueName} (${unit})${rangeNote}` } },
      hovertemplate: `x %{x:.2f} mm<br>y %{y:.2f} mm<br>${valueName} %{z:.3f} ${unit}<extra></extra>`,
    },
  ];
  if (points.length) {
    traces.push({
      type: "scatter",
      mode: "markers+text",
      x: points.map((p) => p.x),
      y: points.map((p) => p.y),
      text: points.map((p) => p.label),
      textposition: "top right",
      marker: { size: 12, symbol: "x", color: points.map((p) => p.color), line: { width: 1.5, color: "#fff" } },
      textfont: { color: points.map((p) => p.color), size: 13 },
      hoverinfo: "text",
      showlegend: false,
    });
  }
  return traces;
}

/**
 * Outlines of the regions of a field that are missing on the plate: where a reference field (the flat first frame)
 * had data, and where it had a gap inside its data (along both the row and the column: a highlight or a shadow
 * there from the start), but not outside the plate the reference saw. The reasons are in the coverage plot. One
 * contour line at the edge of the 0/1 mask; none when nothing is missing.
 */
export function missingOutlineTraces(field, reference) {
  if (!reference || reference.x.length !== field.x.length || reference.y.length !== field.y.length) return [];
  const span = (values) => {
    let lo = -1;
    let hi = -1;
    values.forEach((v, i) => {
      if (Number.isFinite(v)) {
        if (lo < 0) lo = i;
        hi = i;
      }
    });
    return [lo, hi];
  };
  const rows = reference.z.map((row) => span(Array.from(row)));
  const columns = reference.x.map((_, i) => span(reference.z.map((row) => row[i])));
  const inside = (j, i) => i >= rows[j][0] && i <= rows[j][1] && j >= columns[i][0] && j <= columns[i][1];
  let any = false;
  const mask = field.z.map((row, j) => Array.from(row, (v, i) => {
    const missing = (Number.isFinite(reference.z[j][i]) || inside(j, i)) && !Number.isFinite(v);
    any = any || missing;
    return missing ? 1 : 0;
  }));
  if (!any) return [];
  return [{
    type: "contour",
    name: "not measured",
    x: field.x,
    y: field.y,
    z: mask,
    showscale: false,
    contours: { start: 0.5, end: 0.5, size: 1, coloring: "none" },
    line: { color: "#111", width: 1.5, dash: "dot" },
    hoverinfo: "skip",
    showlegend: false,
  }];
}

export function mapLayout({ lines = [], uirevision = "keep" } = {}) {
  return layout({
    uirevision,
    margin: { l: 60, r: 10, t: 10, b: 50 },
    xaxis: axis("x", "mm", { constrain: "domain" }),
    yaxis: axis("y", "mm", { scaleanchor: "x", constrain: "domain" }),
    dragmode: "drawline",
    newshape: { line: { color: "#111", width: 2, dash: "dot" } },
    shapes: lines.map((line) => ({
      type: "line",
      xref: "x",
      yref: "y",
      x0: line.x0,
      y0: line.y0,
      x1: line.x1,
      y1: line.y1,
      editable: false,
      line: { color: line.color, width: 3, dash: "solid" }, // every property set: react would keep the drawn dash
      label: { text: line.label, textposition: "end", font: { color: line.color, size: 14 } },
    })),
  });
}

/**
 * Listen to a map Figure: a drag draws a section line (`onLine({x0, y0, x1, y1})`, in mm), a click without
 * moving picks a point (`onPoint({x, y})`, in mm). Plotly's drawline mode draws the line while dragging and
 * reports it through plotly_relayout; plain clicks are not reported in that mode, so they are read here from
 * the mouse position over the plot area and the axes' ranges. Returns a function that stops listening.
 */
export function listenToMap(figure, { onLine, onPoint }) {
  const gd = figure.plot;
  gd.on("plotly_relayout", (update) => {
    const shapes = update.shapes;
    if (!Array.isArray(shapes) || !shapes.length) return;
    const drawn = shapes[shapes.length - 1];
    if (drawn.editable === false) return; // ours, not a new one
    const line = { x0: drawn.x0, y0: drawn.y0, x1: drawn.x1, y1: drawn.y1 };
    if (Math.hypot(line.x1 - line.x0, line.y1 - line.y0) > 0) onLine(line);
  });
  // Plotly's drag handling stops the mousedown from bubbling and puts a cover over the page until mouseup:
  // listen in the capture phase, and for the mouseup on the window.
  let down = null;
  gd.addEventListener(
    "mousedown",
    (event) => {
      down = event.button === 0 ? { x: event.clientX, y: event.clientY } : null;
    },
    true,
  );
  const up = (event) => {
    if (!down) return;
    const moved = Math.hypot(event.clientX - down.x, event.clientY - down.y);
    down = null;
    if (moved > 3) return;
    const point = dataPoint(gd, event.clientX, event.clientY);
    if (point) onPoint(point);
  };
  window.addEventListener("mouseup", up, true);
  return () => window.removeEventListener("mouseup", up, true);
}

/** Data coordinates (mm) of a mouse position over the plot area of a 2-D plot, or null outside it. */
export function dataPoint(gd, clientX, clientY) {
  const area = gd.querySelector(".nsewdrag");
  const { xaxis, yaxis } = gd.layout;
  if (!area || !xaxis || !yaxis || !xaxis.range || !yaxis.range) return null;
  const box = area.getBoundingClientRect();
  const fx = (clientX - box.left) / box.width;
  const fy = (clientY - box.top) / box.height;
  if (fx < 0 || fx > 1 || fy < 0 || fy > 1) return null;
  const [x0, x1] = xaxis.range.map(Number);
  const [y0, y1] = yaxis.range.map(Number);
  return { x: x0 + fx * (x1 - x0), y: y0 + (1 - fy) * (y1 - y0) };
}

/** Screen position (client pixels) of a data point on a 2-D plot: the inverse of dataPoint, for tests. */
export function screenPoint(gd, x, y) {
  const box = gd.querySelector(".nsewdrag").getBoundingClientRect();
  const [x0, x1] = gd.layout.xaxis.range.map(Number);
  const [y0, y1] = gd.layout.yaxis.range.map(Number);
  return { x: box.left + ((x - x0) / (x1 - x0)) * box.width, y: box.top + (1 - (y - y0) / (y1 - y0)) * box.height };
}

// ---- line plots -----------------------------------------------------------------------------------------------

/**
 * Curves of y against x: `series` = [{ name, x: number[], y: number[], color?, dash?, yaxis? }].
 * `xAxis`, `yAxis` (and `y2Axis` for a second axis on the right) come from axis(name, unit).
 */
export function lineTraces(series, { mode = "lines" } = {}) {
  return series.map((s, i) => ({
    type: "scatter",
    mode: s.mode || mode,
    name: s.name,
    x: s.x,
    y: s.y,
    yaxis: s.yaxis || "y",
    line: { color: s.color || COLORS[i % COLORS.length], width: 2, dash: s.dash || "solid" },
    marker: { size: 5 },
    connectgaps: false,
  }));
}

export function lineLayout({ xAxis, yAxis, y2Axis = null, shapes = [], note = null }) {
  const out = layout({ xaxis: xAxis, yaxis: yAxis, shapes, hovermode: "x unified" });
  if (note) {
    // An empty plot says how to fill it.
    out.annotations = [{ text: note, xref: "paper", yref: "paper", x: 0.5, y: 0.5, showarrow: false, font: { size: 14, color: "#5b6472" } }];
  }
  if (y2Axis) {
    out.yaxis2 = { ...y2Axis, overlaying: "y", side: "right", showgrid: false, tickmode: "auto" };
    out.margin = { ...out.margin, r: 70 };
  }
  return out;
}

/**
 * A band between `lower` and `upper` (arrays with null where unknown) along `s`: one closed polygon per run of
 * known values (filled "toself", runs apart by a null), so that a gap in the data stays a gap in the band.
 */
export function bandTrace(s, lower, upper, { name, color, yaxis = "y" }) {
  const xs = [];
  const ys = [];
  let run = [];
  const flush = () => {
    if (run.length > 1) {
      const back = [...run].reverse();
      xs.push(...run.map((k) => s[k]), ...back.map((k) => s[k]), null);
      ys.push(...run.map((k) => upper[k]), ...back.map((k) => lower[k]), null);
    }
    run = [];
  };
  s.forEach((_, k) => (upper[k] === null || lower[k] === null ? flush() : run.push(k)));
  flush();
  return { type: "scatter", mode: "lines", name, x: xs, y: ys, yaxis, fill: "toself", fillcolor: color, line: { width: 0 }, hoverinfo: "skip" };
}

/**
 * The ±k·σ band of a curve (`w`, `sigma` arrays, NaN or null where unknown) along `s`, filled in `color`: a gap in
 * either stays a gap in the band. k = 2 by default: the band a 95 % interval of each value spans.
 */
export function sigmaBandTrace(s, w, sigma, { name, color, k = 2, yaxis = "y" }) {
  const known = (i) => Number.isFinite(w[i]) && Number.isFinite(sigma[i]);
  const upper = s.map((_, i) => (known(i) ? w[i] + k * sigma[i] : null));
  const lower = s.map((_, i) => (known(i) ? w[i] - k * sigma[i] : null));
  return bandTrace(s, lower, upper, { name, color, yaxis });
}

/** `#rrggbb` as an rgba() colour of opacity `alpha`: a band in the colour of its curve. */
export function translucent(hex, alpha = 0.2) {
  const [r, g, b] = [1, 3, 5].map((i) => parseInt(hex.slice(i, i + 2), 16));
  return `rgba(${r},${g},${b},${alpha})`;
}

/**
 * Marks of the samples a curve lacks (`missing[k]` true: not measured there), drawn on the curve's line of missing
 * values, never at 0: each at the value interpolated (in x) between the nearest known samples on either side (the
 * nearest one at an end), the run joined to them by a thin dotted line that reads as "not measured". Returns [] when
 * nothing is missing or no sample is known. `hover(k)` says why sample k is missing.
 */
export function missingMarkTraces(xs, ys, missing, { name, color = "#c2185b", lineColor = color, hover = () => name, yaxis = "y" }) {
  const known = (k) => Number.isFinite(ys[k]) && Number.isFinite(xs[k]) && !missing[k];
  const marks = { x: [], y: [], text: [] };
  const line = { x: [], y: [] };
  let k = 0;
  while (k < ys.length) {
    if (!missing[k] || !Number.isFinite(xs[k])) {
      k += 1;
      continue;
    }
    let end = k;
    while (end + 1 < ys.length && missing[end + 1]) end += 1;
    let before = k - 1;
    while (before >= 0 && !known(before)) before -= 1;
    let after = end + 1;
    while (after < ys.length && !known(after)) after += 1;
    const hasBefore = before >= 0;
    const hasAfter = after < ys.length;
    if (hasBefore || hasAfter) {
      const at = (x) => {
        if (!hasBefore) return ys[after];
        if (!hasAfter || xs[after] === xs[before]) return ys[before];
        return ys[before] + ((x - xs[before]) / (xs[after] - xs[before])) * (ys[after] - ys[before]);
      };
      const add = (into, x, y) => {
        into.x.push(x);
        into.y.push(y);
      };
      if (hasBefore) add(line, xs[before], ys[before]);
      for (let m = k; m <= end; m += 1) {
        if (!Number.isFinite(xs[m])) continue;
        const y = at(xs[m]);
        add(marks, xs[m], y);
        marks.text.push(hover(m));
        add(line, xs[m], y);
      }
      if (hasAfter) add(line, xs[after], ys[after]);
      add(line, null, null);
    }
    k = end + 1;
  }
  if (!marks.x.length) return [];
  return [
    { type: "scatter", mode: "lines", name: `${name} (line)`, x: line.x, y: line.y, yaxis, showlegend: false, hoverinfo: "skip",
      line: { color: lineColor, width: 1, dash: "dot" } },
    { type: "scatter", mode: "markers", name, x: marks.x, y: marks.y, yaxis, text: marks.text, hovertemplate: "%{text}<extra></extra>",
      marker: { size: 10, symbol: "x-thin-open", color, line: { width: 2, color } } },
  ];
}

/** Lower bounds (the value is at least y) as upward triangles, never on the curve: [] when there are none. */
export function lowerBoundTraces(xs, lower, { name = "lower bound (peak not measured)", color = "#c2185b", hover = () => "" } = {}) {
  const ks = lower.map((v, k) => (Number.isFinite(v) && Number.isFinite(xs[k]) ? k : -1)).filter((k) => k >= 0);
  if (!ks.length) return [];
  return [{
    type: "scatter", mode: "markers", name, x: ks.map((k) => xs[k]), y: ks.map((k) => lower[k]), text: ks.map((k) => hover(k)),
    hovertemplate: "at least %{y:.3f} mm<br>%{text}<extra></extra>",
    marker: { size: 10, symbol: "triangle-up-open", color, line: { width: 2, color } },
  }];
}

/** A vertical marker line at x on a line plot (the current frame's time on a history plot). */
export function verticalMarker(x) {
  return { type: "line", xref: "x", yref: "paper", x0: x, x1: x, y0: 0, y1: 1, line: { color: "#888", width: 1, dash: "dash" } };
}

// ---- bars and vectors -------------------------------------------------------------------------------------------

export function barTraces({ x, y, name, color = COLORS[0], text = null }) {
  return [{ type: "bar", x, y, name, marker: { color }, text, hovertemplate: "%{x}: %{y:.3f}<extra></extra>" }];
}

/**
 * Residual vectors drawn over the image area: arrows from each point (u, v) in pixels along its residual
 * (du, dv) × `scale`, as one line trace with gaps, plus the points. Image convention: v grows downwards.
 */
export function vectorTraces({ u, v, du, dv, scale, color = COLORS[1] }) {
  const xs = [];
  const ys = [];
  for (let i = 0; i < u.length; i += 1) {
    xs.push(u[i], u[i] + du[i] * scale, null);
    ys.push(v[i], v[i] + dv[i] * scale, null);
  }
  return [
    { type: "scatter", mode: "lines", x: xs, y: ys, line: { color, width: 1.5 }, name: `residual × ${scale}`, hoverinfo: "skip" },
    {
      type: "scatter",
      mode: "markers",
      x: u,
      y: v,
      marker: { size: 3, color: "#1d2430" },
      name: "corner",
      customdata: du.map((d, i) => [d, dv[i]]),
      hovertemplate: "u %{x:.1f} px, v %{y:.1f} px<br>residual (%{customdata[0]:.3f}, %{customdata[1]:.3f}) px<extra></extra>",
    },
  ];
}

export function imageLayout({ widthPx, heightPx }) {
  return layout({
    xaxis: axis("u", "px", { range: [0, widthPx], constrain: "domain" }),
    yaxis: axis("v", "px", { range: [heightPx, 0], scaleanchor: "x", constrain: "domain" }),
    shapes: [{ type: "rect", x0: 0, y0: 0, x1: widthPx, y1: heightPx, line: { color: "#999", width: 1 } }],
  });
}
