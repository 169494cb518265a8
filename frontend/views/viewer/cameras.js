// The viewer's camera against camera: this topography against another camera's of the same experiment (peak
// over time, the first section line's profile at this instant, or the difference map of this frame), each with
// the difference this − other and its RMS and largest value. Only what both cameras measured is compared: a frame
// either camera did not measure the peak of has no difference (a gap, never a drop), and is listed with why.
import { COLORS, Figure, axis, lineLayout, lineTraces, missingMarkTraces, verticalMarker } from "../../plots.js";
import { fieldRange, mapLayout, mapTraces, resampleField } from "../../plot_fields.js";
import { attempt, fill, h, num } from "../../ui.js";
import { gridOf, timeAxis } from "./shared.js";

export class CamerasPanel {
  constructor(viewer) {
    this.viewer = viewer;
    this.compareSelect = h("select", { id: "compare-with" }, h("option", { value: "" }, "no other camera"));
    this.compareSelect.addEventListener("change", () => this.loadComparison());
    this.compareWhat = h("select", { id: "compare-what" },
      h("option", { value: "peak" }, "peak deflection over time"),
      h("option", { value: "profile" }, "profile along the first section line, this frame"),
      h("option", { value: "map" }, "difference map, this frame"));
    this.compareWhat.addEventListener("change", () => this.draw());
    this.figure = new Figure({ name: "Camera against camera", filename: `topography-${viewer.job.id.slice(0, 8)}-cameras`, height: 420, csv: () => this.csv() });
    this.element = h("section", { "aria-label": "Camera against camera", hidden: true },
      h("h2", {}, "Camera against camera"),
      h("div", { class: "compare-controls" },
        h("div", { class: "field inline" }, h("label", { for: "compare-with" }, "Compare with the topography of"), this.compareSelect),
        h("div", { class: "field inline" }, h("label", { for: "compare-what" }, "Compare"), this.compareWhat)),
      (this.compareStats = h("p", { class: "facts", "aria-label": "Difference between the cameras" })),
      (this.leftOut = h("ul", { class: "warnings", "aria-label": "Frames left out of the difference" })),
      this.figure.element);
  }

  async findOtherCameras() {
    const viewer = this.viewer;
    this.label = await attempt("name the camera of this result", () => viewer.source.label());
    const others = await attempt("find the other cameras' topography", () => viewer.source.otherTopographies());
    if (!others || !viewer.context.current()) return;
    fill(this.compareSelect, h("option", { value: "" }, others.length ? "choose…" : "no other camera"),
      others.map((o) => h("option", { value: o.job.id }, o.label)));
    this.others = others;
    this.element.hidden = false;
    if (others.length) {
      this.compareSelect.value = others[0].job.id;
      await this.loadComparison();
    } else {
      fill(this.element, h("h2", {}, "Camera against camera"),
        h("p", { class: "empty" }, "No other camera of this experiment has a topography result yet."));
    }
  }

  async loadComparison() {
    const chosen = (this.others || []).find((o) => o.job.id === this.compareSelect.value);
    this.comparison = chosen
      ? { label: chosen.label, source: chosen.source, meta: await attempt("read the other camera's result", () => chosen.source.meta()) }
      : null;
    return this.draw();
  }

  /** The other camera's frame nearest in time to this one's current frame (the same index without times). */
  otherFrame(other) {
    const viewer = this.viewer;
    const t = viewer.meta.frames.time_s[viewer.position];
    const times = other.frames.time_s;
    if (!Number.isFinite(t) || !times.every(Number.isFinite)) return other.frames.index.includes(viewer.frame) ? viewer.frame : null;
    let best = 0;
    times.forEach((v, i) => {
      if (Math.abs(v - t) < Math.abs(times[best] - t)) best = i;
    });
    return other.frames.index[best];
  }

  /**
   * Both cameras: peak deflection against time (or frame), or the first line's profile at this instant, each with
   * the difference (this − other) on a second axis; or the difference map of this frame. Line styles differ
   * (solid, dashed with other markers, dotted difference) so that curves that coincide are still both seen.
   */
  async draw() {
    const viewer = this.viewer;
    const other = this.comparison && this.comparison.meta ? this.comparison : null;
    const mine = this.label || "this camera";
    const styles = {
      mine: { color: COLORS[0], dash: "solid" },
      theirs: { color: COLORS[1], dash: "dash" },
      difference: { color: "#111111", dash: "dot", yaxis: "y2" },
    };
    const differenceAxis = axis("difference w (this − other)", "mm");
    const show = (series, differences, xAxis, yAxis, extra = {}, marks = []) => {
      const traces = lineTraces(series);
      traces.forEach((trace, i) => {
        if (i === 1) trace.marker = { size: 7, symbol: "x" };
      });
      traces.push(...marks);
      const finite = differences.filter(Number.isFinite);
      const rms = finite.length ? Math.sqrt(finite.reduce((a, d) => a + d * d, 0) / finite.length) : NaN;
      this.compareStats.textContent = other
        ? `Difference this − other: RMS ${num(rms, 3)} mm, largest ${num(finite.length ? Math.max(...finite.map(Math.abs)) : NaN, 3)} mm over ${finite.length} points where both measured.`
        : "Choose another camera to see the difference.";
      return this.figure.react(traces, { ...lineLayout({ xAxis, yAxis, y2Axis: other ? differenceAxis : null, ...extra }), uirevision: this.compareWhat.value });
    };
    fill(this.leftOut);
    if (this.compareWhat.value === "map") return this.drawDifferenceMap(other);
    if (this.compareWhat.value === "profile" && !viewer.lines.length) {
      this.comparedSeries = null;
      this.compareStats.textContent = "";
      return this.figure.react([], { ...lineLayout({ xAxis: axis("distance along the line", "mm"), yAxis: axis("deflection w", "mm"), note: "Draw a section line on the map first" }), uirevision: "profile" });
    }
    if (this.compareWhat.value === "profile" && viewer.lines.length) {
      const line = viewer.lines[0];
      const [ours] = await viewer.source.profiles([viewer.frame], line);
      const series = [{ name: `${mine}, frame ${viewer.frame}`, x: ours.s, y: ours.w, ...styles.mine }];
      let differences = [];
      const frame = other ? this.otherFrame(other.meta) : null;
      if (frame !== null) {
        const [theirs] = await other.source.profiles([frame], line);
        // Both profiles are sampled at the same points of the same line: subtract point by point.
        differences = ours.w.map((w, i) => w - theirs.w[i]);
        series.push({ name: `${other.label}, frame ${frame}`, x: theirs.s, y: theirs.w, mode: "lines+markers", ...styles.theirs });
        series.push({ name: "difference (this − other)", x: ours.s, y: differences, ...styles.difference });
      }
      this.comparedSeries = { columns: ["series", "s_mm", "w_mm", "grid", "grid_step_mm"], series, grid: "result" };
      return show(series, differences, axis(`distance along line ${line.label}`, "mm"), axis("deflection w", "mm"));
    }
    const time = timeAxis(viewer.meta);
    const ours = viewer.meta.frames;
    const series = [{ name: mine, x: time.values, y: ours.peak_w_mm, mode: "lines+markers", ...styles.mine }];
    const marks = [];
    const notMeasured = (frames, k) => `peak not measured${frames.peak_reason[k] ? ` (${frames.peak_reason[k]})` : ""}`;
    marks.push(...missingMarkTraces(time.values, ours.peak_w_mm, ours.peak_w_mm.map((w) => !Number.isFinite(w)),
      { name: `${mine}: peak not measured`, color: styles.mine.color, hover: (k) => `${mine}, frame ${ours.index[k]}: ${notMeasured(ours, k)}` }));
    let differences = [];
    const leftOut = [];
    if (other) {
      const theirs = other.meta.frames;
      const t = theirs.time_s;
      const byTime = time.key === "time" && t.every(Number.isFinite);
      const x = byTime ? t.map((v) => v * time.scale) : theirs.index;
      const y = theirs.peak_w_mm;
      series.push({ name: other.label, x, y, mode: "lines+markers", ...styles.theirs });
      marks.push(...missingMarkTraces(x, y, y.map((w) => !Number.isFinite(w)),
        { name: `${other.label}: peak not measured`, color: styles.theirs.color, hover: (k) => `${other.label}, frame ${theirs.index[k]}: ${notMeasured(theirs, k)}` }));
      // The difference is the server's (one rule: compared only where both cameras measured the peak, the other's
      // interpolated in time); every frame it leaves out is listed with its reason.
      const against = await attempt("compare the peaks with the other camera", () => viewer.source.against(other.source.job.id));
      if (!against || !this.viewer.context.current()) return null;
      differences = against.difference_w_mm;
      leftOut.push(...against.left_out_frames.map((f) => `Frame ${f.frame}: ${f.reason}`));
      // Markers too: a compared frame between two left out is a point, not an invisible line.
      series.push({ name: "difference (this − other)", x: time.values, y: differences, mode: "lines+markers", ...styles.difference });
    }
    this.comparedSeries = { columns: ["series", time.key === "time" ? `time_${time.unit}` : "frame", "peak_w_mm", "grid", "grid_step_mm"], series, grid: "result" };
    await show(series, differences, time.title, axis("peak deflection w", "mm"), { shapes: [verticalMarker(time.values[viewer.position])] }, marks);
    // Each peak is the largest w over that camera's own measured area: say so, since areas differ.
    if (other) {
      this.compareStats.append(` Compared: ${time.values.length - leftOut.length} of ${time.values.length} frames; left out: ${leftOut.length}${leftOut.length ? " (listed below, with why)" : ""}.`,
        " Each peak is taken over that camera's own measured area; the difference map compares the same points.");
      fill(this.leftOut, leftOut.map((text) => h("li", {}, text)));
    }
    return null;
  }

  /** This frame's field minus the other camera's (its frame nearest in time), on this field's nodes. */
  async drawDifferenceMap(other) {
    const viewer = this.viewer;
    const frame = other ? this.otherFrame(other.meta) : null;
    if (!other || frame === null || !viewer.current) {
      this.compareStats.textContent = other ? `${other.label} has no frame at this instant.` : "Choose another camera to see the difference.";
      this.comparedSeries = null;
      return this.figure.react([], { ...lineLayout({ xAxis: axis("x", "mm"), yAxis: axis("y", "mm"), note: this.compareStats.textContent }), uirevision: "map" });
    }
    const region = viewer.fullResolution ? viewer.zoomRegion() : null;
    const theirs = resampleField(await other.source.field(frame, region), viewer.current);
    const difference = { x: viewer.current.x, y: viewer.current.y, z: viewer.current.z.map((row, j) => row.map((w, i) => w - theirs.z[j][i])) };
    const range = fieldRange(difference);
    const reach = range ? Math.max(Math.abs(range[0]), Math.abs(range[1])) : 1;
    const values = difference.z.flatMap((row) => Array.from(row).filter(Number.isFinite));
    const rms = values.length ? Math.sqrt(values.reduce((a, d) => a + d * d, 0) / values.length) : NaN;
    this.compareStats.textContent = `Difference map this − ${other.label} (frame ${viewer.frame} − frame ${frame}): RMS ${num(rms, 3)} mm, largest ${num(reach, 3)} mm over ${values.length} nodes where both measured; the other field is interpolated (bilinear) at this field's nodes.`;
    this.comparedSeries = { map: { difference, theirs, frame, grid: gridOf(viewer.meta, viewer.current) } };
    const traces = mapTraces(difference, { range: [-reach, reach], valueName: "Δw", rangeNote: " this − other" });
    return this.figure.react(traces, { ...mapLayout({ uirevision: "map" }), dragmode: "zoom" });
  }

  csv() {
    const viewer = this.viewer;
    const compared = this.comparedSeries;
    if (compared && compared.map) {
      const { difference, theirs, frame, grid } = compared.map;
      const rows = [];
      difference.z.forEach((row, j) => row.forEach((d, i) => rows.push([viewer.frame, frame, difference.x[i], difference.y[j], viewer.current.z[j][i], theirs.z[j][i], d, grid.grid, grid.step_mm])));
      return {
        filename: `topography-${viewer.job.id.slice(0, 8)}-difference-frame${viewer.frame}-${grid.name}`,
        columns: ["frame", "other_frame", "x_mm", "y_mm", "w_mm", "other_w_mm", "difference_w_mm", "grid", "grid_step_mm"],
        rows,
      };
    }
    const { columns, series } = compared || { columns: ["series", "x", "y", "grid", "grid_step_mm"], series: [] };
    const rows = [];
    for (const one of series) one.x.forEach((x, i) => rows.push([one.name, x, one.y[i], "result", viewer.meta.grid.step_mm]));
    return { columns, rows };
  }
}
