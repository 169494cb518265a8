// The viewer's peak deflection against punch displacement (or time), force on a second axis; a frame whose peak
// region was not measured is a gap with a mark on the axis, never a drop.
import { COLORS, Figure, axis, lineLayout, lineTraces } from "../../plots.js";
import { timeAxis } from "./shared.js";

export class PeakPanel {
  constructor(viewer) {
    this.viewer = viewer;
    this.figure = new Figure({ name: "Peak deflection and force", filename: `topography-${viewer.job.id.slice(0, 8)}-peak`, height: 340, csv: () => this.csv() });
  }

  draw() {
    const meta = this.viewer.meta;
    const m = meta.frames;
    const i = this.viewer.position;
    const haveForce = m.force_kN.some(Number.isFinite);
    const havePunch = m.punch_displacement_mm.some(Number.isFinite);
    const xs = havePunch ? m.punch_displacement_mm : timeAxis(meta).values;
    const xAxis = havePunch ? axis("punch displacement", "mm") : timeAxis(meta).title;
    // A frame whose peak region was not measured has no peak: a gap in the line and a mark on the axis, not a drop.
    const unmeasured = meta.coverage.peak_measured.map((v) => v === false);
    const peaks = m.peak_w_mm.map((w, k) => (unmeasured[k] ? NaN : w));
    const series = [{ name: "peak deflection", x: xs, y: peaks, color: COLORS[0], mode: "lines+markers" }];
    if (haveForce) series.push({ name: "force", x: xs, y: m.force_kN, color: COLORS[1], yaxis: "y2", dash: "dot" });
    const traces = lineTraces(series);
    if (unmeasured.some(Boolean)) {
      const gaps = xs.map((x, k) => (unmeasured[k] ? x : NaN));
      traces.push({ type: "scatter", mode: "markers", name: "peak region not measured", x: gaps, y: gaps.map(() => 0),
        marker: { size: 10, symbol: "x-thin-open", color: "#c2185b", line: { width: 2 } }, hovertemplate: "peak region not measured<extra></extra>" });
    }
    traces.push({ type: "scatter", mode: "markers", name: "this frame", x: [xs[i]], y: [peaks[i]], marker: { size: 12, color: "#111", symbol: "circle-open", line: { width: 2 } } });
    return this.figure.react(traces, lineLayout({
      xAxis,
      yAxis: axis("peak deflection w", "mm"),
      y2Axis: haveForce ? axis("force", "kN") : null,
    }));
  }

  csv() {
    const meta = this.viewer.meta;
    const m = meta.frames;
    const measured = meta.coverage.peak_measured;
    return {
      columns: ["frame", "time_s", "punch_displacement_mm", "force_kN", "peak_w_mm", "peak_region_measured", "grid", "grid_step_mm"],
      rows: this.viewer.frames.map((frame, i) => [frame, m.time_s[i], m.punch_displacement_mm[i], m.force_kN[i], m.peak_w_mm[i], measured[i] ?? "", "result", meta.grid.step_mm]),
    };
  }
}
