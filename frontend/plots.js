// Plotly helpers of the dashboard: every plot is a Figure (a titled box with "Download CSV" and "Download PNG"
// buttons for the data and the image behind it), updated with Plotly.react; every axis title carries its unit
// (use `axis(name, unit)`). Fields (maps and surfaces) are drawn by plot_fields.js.
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
