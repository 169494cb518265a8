// The viewer's coverage over time: the measured share of the plate per frame (left axis, %) and the area missing
// by reason (stacked bars, right), with the frames whose temporal cross-check found jumps marked.
import { COLORS, Figure, axis, lineLayout, lineTraces, verticalMarker } from "../../plots.js";
import { timeAxis } from "./shared.js";

export class CoveragePanel {
  constructor(viewer) {
    this.viewer = viewer;
    this.figure = new Figure({ name: "Coverage over time", filename: `topography-${viewer.job.id.slice(0, 8)}-coverage`, height: 340, csv: () => this.csv() });
  }

  /** Measured share of the plate per frame (left axis, %) and the area missing by reason (stacked bars, right). */
  draw() {
    const c = this.viewer.meta.coverage;
    const time = timeAxis(this.viewer.meta);
    const reasons = Object.keys(c.missing_mm2);
    const traces = lineTraces([{ name: "measured", x: time.values, y: c.measured_fraction.map((f) => f * 100), color: COLORS[0], mode: "lines+markers" }]);
    // Each reason under the API's label, and its description on hover ("hole" is anything as black as the
    // background: before a perforation, the punch in front or the clamp ring).
    const about = (reason) => c.missing_reasons[reason];
    reasons.forEach((reason, k) => traces.push({
      type: "bar", name: about(reason).label, x: time.values, y: c.missing_mm2[reason].map((a) => a / 100),
      yaxis: "y2", marker: { color: COLORS[(k + 1) % COLORS.length] }, opacity: 0.6,
      hovertemplate: `missing: ${about(reason).label} %{y:.2f} cm²<br>${about(reason).description}<extra></extra>`,
    }));
    // Frames where the cross-check against the frame before found points that jumped by a stripe step: marked on
    // the measured line (the order of those points is suspect; the points stay as measured).
    const jumps = (c.n_temporal_jumps || []).map((n) => Number.isFinite(n) && n > 0);
    if (jumps.some(Boolean)) traces.push({
      type: "scatter", mode: "markers", name: "temporal cross-check: jumps",
      x: time.values.filter((_, i) => jumps[i]), y: c.measured_fraction.map((f) => f * 100).filter((_, i) => jumps[i]),
      customdata: c.n_temporal_jumps.filter((_, i) => jumps[i]),
      marker: { symbol: "x", size: 11, color: "#c0392b" }, hovertemplate: "%{customdata} points jumped by a stripe step<extra></extra>",
    });
    const known = c.measured_fraction.some(Number.isFinite);
    const figureLayout = lineLayout({
      xAxis: time.title,
      yAxis: axis("measured share of the plate", "%", { range: [0, 101] }),
      y2Axis: axis("area missing", "cm²"),
      shapes: [verticalMarker(time.values[this.viewer.position])],
      note: known ? null : "This result was written before coverage was recorded",
    });
    figureLayout.barmode = "stack";
    return this.figure.react(traces, figureLayout);
  }

  csv() {
    const meta = this.viewer.meta;
    const c = meta.coverage;
    const reasons = Object.keys(c.missing_mm2);
    return {
      columns: ["frame", "time_s", "measured_fraction", ...reasons.map((r) => `missing_${r}_mm2`), "n_order_conflicts", "n_temporal_jumps"],
      rows: this.viewer.frames.map((frame, i) => [frame, meta.frames.time_s[i], c.measured_fraction[i], ...reasons.map((r) => c.missing_mm2[r][i]), c.n_order_conflicts[i], c.n_temporal_jumps[i]]),
    };
  }
}
