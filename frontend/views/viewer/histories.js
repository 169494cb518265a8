// The viewer's point histories: w over the test at each clicked or typed point (time, or frame numbers without
// times), the current frame marked; frames where a point was not measured are marked on its curve's line of
// missing values, never at w = 0; each with its ±2σ_w band (shaded in the point's colour).
import { Figure, axis, lineLayout, lineTraces, missingMarkTraces, sigmaBandTrace, translucent, verticalMarker } from "../../plots.js";
import { field, h, num } from "../../ui.js";
import { timeAxis } from "./shared.js";

export class HistoriesPanel {
  constructor(viewer) {
    this.viewer = viewer;
    this.figure = new Figure({ name: "Point histories", filename: `topography-${viewer.job.id.slice(0, 8)}-histories`, height: 340, csv: () => this.csv() });
    this.pointList = h("ul", { class: "chips", "aria-label": "Points" });
    const pointInputs = ["x", "y"].map((name) => field(`Point ${name} (mm)`, h("input", { type: "number", step: "any", required: true })));
    this.pointForm = h(
      "form",
      {
        class: "inline-form",
        "aria-label": "Add a point",
        onsubmit: (event) => {
          event.preventDefault();
          const [x, y] = pointInputs.map((f) => Number(f.input.value));
          viewer.addPoint({ x, y });
        },
      },
      pointInputs.map((f) => f.wrap),
      h("button", { type: "submit", class: "small" }, "Add point"),
    );
  }

  draw() {
    const viewer = this.viewer;
    const time = timeAxis(viewer.meta);
    const series = viewer.points.filter((p) => p.history).map((p) => ({
      name: `${p.label} (${num(p.x, 1)}, ${num(p.y, 1)}) mm`,
      label: p.label,
      x: p.history.frame.map((f) => time.values[viewer.frames.indexOf(f)]),
      y: p.history.w,
      frames: p.history.frame,
      sigma: p.history.sigma || p.history.w.map(() => NaN),
      color: p.color,
      mode: "lines+markers",
    }));
    const bands = series.map((one) => sigmaBandTrace(one.x, one.y, one.sigma, { name: `${one.label} ±2σ_w`, color: translucent(one.color, 0.18) }));
    const traces = [...bands, ...lineTraces(series)];
    for (const one of series) {
      traces.push(...missingMarkTraces(one.x, one.y, one.y.map((w) => !Number.isFinite(w)), {
        name: `${one.label} not measured`, color: one.color, hover: (k) => `${one.label}, frame ${one.frames[k]}: not measured at this point`,
      }));
    }
    return this.figure.react(traces, lineLayout({
      note: series.length ? null : "Click a point on the map to see its deflection over time",
      xAxis: time.title,
      yAxis: axis("deflection w", "mm"),
      shapes: [verticalMarker(time.values[viewer.position])],
    }));
  }

  csv() {
    const rows = [];
    for (const p of this.viewer.points.filter((q) => q.history)) {
      p.history.frame.forEach((frame, i) => rows.push([p.label, p.x, p.y, frame, p.history.time_s[i], p.history.w[i], p.history.sigma ? p.history.sigma[i] : NaN]));
    }
    const step = this.viewer.meta.grid.step_mm;
    return { columns: ["point", "x_mm", "y_mm", "frame", "time_s", "w_mm", "sigma_w_mm", "grid", "grid_step_mm"], rows: rows.map((r) => [...r, "result", step]) };
  }
}
