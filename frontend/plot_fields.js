// Plotly helpers for fields, 2-D arrays of deflection on a regular x, y grid: their CSV rows, colour range and
// resampling, the 3-D surface and the 2-D map (click-and-drag draws section lines, plain clicks pick points).
// The general helpers (Figure, axis, layout, line plots) are in plots.js.
import { DEFLECTION_SCALE, axis, layout } from "./plots.js";

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
