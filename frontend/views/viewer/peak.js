// The viewer's peak deflection against punch displacement (or time), force on a second axis. A frame whose peak
// was not measured is a gap in the curve, marked on the curve's line of missing values (never at w = 0), with its
// lower bound (the largest w measured, when there is one) drawn as a lower bound, not as the peak.
import { COLORS, Figure, axis, lineLayout, lineTraces, lowerBoundTraces, missingMarkTraces } from "../../plots.js";
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
    // The title says what the recording's test log (frames.csv) holds: no "and force" without a force.
    this.figure.rename(haveForce ? "Peak deflection and force" : "Peak deflection");
    // What the server notes about the test log (a column missing from frames.csv, or no frames.csv), else ours.
    const logNotes = (meta.notes || []).filter((n) => /frames\.csv/.test(n));
    const note = logNotes.length ? logNotes.join(" ") : havePunch || haveForce ? null : "No punch displacement or force in this recording's test log (frames.csv)";
    const unmeasured = meta.coverage.peak_measured.map((v) => v === false);
    const peaks = m.peak_w_mm.map((w, k) => (unmeasured[k] ? NaN : w));
    const series = [{ name: "peak deflection", x: xs, y: peaks, color: COLORS[0], mode: "lines+markers" }];
    if (haveForce) series.push({ name: "force", x: xs, y: m.force_kN, color: COLORS[1], yaxis: "y2", dash: "dot" });
    const why = (k) => `frame ${this.viewer.frames[k]}: peak not measured${m.peak_reason[k] ? ` (${m.peak_reason[k]})` : ""}`;
    const traces = [
      ...lineTraces(series),
      ...missingMarkTraces(xs, peaks, unmeasured, { name: "peak not measured", lineColor: COLORS[0], hover: why }),
      ...lowerBoundTraces(xs, m.peak_w_lower_bound_mm, { hover: why }),
    ];
    const here = Number.isFinite(peaks[i]) ? peaks[i] : m.peak_w_lower_bound_mm[i];
    traces.push({ type: "scatter", mode: "markers", name: "this frame", x: [xs[i]], y: [here], marker: { size: 12, color: "#111", symbol: "circle-open", line: { width: 2 } } });
    return this.figure.react(traces, PeakPanel.annotate(lineLayout({
      xAxis,
      yAxis: axis("peak deflection w", "mm"),
      y2Axis: haveForce ? axis("force", "kN") : null,
    }), note));
  }

  /** A note over the plot's top when the test log lacks what it usually holds (it is not the empty-plot note). */
  static annotate(plotLayout, note) {
    if (!note) return plotLayout;
    const text = { text: note, xref: "paper", yref: "paper", x: 0, y: 1.14, xanchor: "left", yanchor: "bottom", showarrow: false, font: { size: 12, color: "#a35f00" } };
    return { ...plotLayout, annotations: [...(plotLayout.annotations || []), text], margin: { ...plotLayout.margin, t: 64 } };
  }

  csv() {
    const meta = this.viewer.meta;
    const m = meta.frames;
    const measured = meta.coverage.peak_measured;
    return {
      columns: ["frame", "time_s", "punch_displacement_mm", "force_kN", "peak_w_mm", "peak_measured", "peak_w_lower_bound_mm", "peak_reason", "grid", "grid_step_mm"],
      rows: this.viewer.frames.map((frame, i) => [frame, m.time_s[i], m.punch_displacement_mm[i], m.force_kN[i], m.peak_w_mm[i], measured[i] ?? "", m.peak_w_lower_bound_mm[i], m.peak_reason[i] ?? "", "result", meta.grid.step_mm]),
    };
  }
}
