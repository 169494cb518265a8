// The comparison view of a comparison job: a measured topography against a finite-element simulation. The map of a
// frame (w_meas − w_sim, or either side, or the measurement's σ_w) with a frame slider; the profile through the
// punch axis, measured with its ±σ band against simulated, the points where |w_meas − w_sim| > 2σ marked; peak
// deflection and force against punch displacement, measured and simulated; the RMS and largest difference of every
// frame, where a frame without a simulation partner is a gap marked with its reason, never a drop to zero; the
// mapping used; exports. Every plot downloads its data (CSV) and its image (PNG).
import { getJSON, query } from "../api.js";
import { COLORS, Figure, axis, bandTrace, lineLayout, lineTraces, missingMarkTraces, verticalMarker } from "../plots.js";
import { fieldRows, mapLayout, mapTraces } from "../plot_fields.js";
import { attempt, field, fill, h, latestOnly, num, page, showError } from "../ui.js";
import { comparisonExportPanel } from "./exports.js";
import { jobName, shortId } from "./job-helpers.js";
import { profileTraces, stateText } from "./simulations.js";

const FIELDS = {
  diff_mm: { label: "difference w_meas − w_sim", value: "Δw" },
  w_meas_mm: { label: "measured w", value: "w meas." },
  w_sim_mm: { label: "simulated w", value: "w sim." },
  sigma_w_mm: { label: "σ of the measured w", value: "σ_w" },
};
const MAP_BUDGET = 120; // nodes per side of the map (block averages): enough to see, light to send

/** Diagnostics for the browser tests: the comparison view shown. */
window.fringelab = window.fringelab || {};

export async function renderComparison(container, { id }, context) {
  const job = await attempt("open the job", () => getJSON(`jobs/${id}`));
  if (!job || !context.current()) return;
  if (job.kind !== "comparison" || job.state !== "succeeded") {
    page(container, "Comparison", h("p", {}, h("a", { href: `#/jobs/${job.id}` }, jobName(job)),
      job.kind !== "comparison" ? " is not a comparison job." : ` is ${job.state}; its comparison shows when it has succeeded.`));
    return;
  }
  const overview = await attempt("read the comparison", () => getJSON(`jobs/${id}/comparison`));
  if (!overview || !context.current()) return;
  const view = new ComparisonView(job, overview, context);
  window.fringelab.comparison = view;
  page(container, `Comparison: ${jobName(job)}`, view.element);
  context.onLeave(() => {
    view.dispose();
    window.fringelab.comparison = null;
  });
  await view.start();
}

const finite = (values) => values.filter((v) => v !== null && Number.isFinite(v));

class ComparisonView {
  constructor(job, overview, context) {
    this.job = job;
    this.overview = overview;
    this.context = context;
    this.frames = overview.frames.frame;
    this.position = 0;
    this.showLatest = latestOnly((position) => this.showFrame(position));
    this.build();
  }

  get frame() {
    return this.frames[this.position];
  }

  build() {
    const f = this.overview.frames;
    const short = shortId(this.job.id);
    const last = this.frames.length - 1;
    this.slider = h("input", { type: "range", min: 0, max: last, step: 1, value: 0, "aria-label": "Frame", class: "scrubber" });
    this.slider.addEventListener("input", () => this.goTo(Number(this.slider.value)));
    this.frameFacts = h("output", { class: "frame-facts", "aria-label": "Current frame" });
    this.fieldChoice = field("Field", h("select", {}, Object.entries(FIELDS).map(([value, { label }]) => h("option", { value }, label))));
    this.fieldChoice.input.addEventListener("change", () => this.drawMap());
    this.axisChoice = field("Profile along", h("select", {}, h("option", { value: "x" }, "X through the punch axis"), h("option", { value: "y" }, "Y through the punch axis")));
    this.axisChoice.input.addEventListener("change", () => this.drawProfile());
    this.mapFigure = new Figure({ name: "Comparison map", filename: `comparison-${short}-map`, height: 440, csv: () => this.mapCSV() });
    this.profileFigure = new Figure({ name: "Profile, measured against simulated", filename: `comparison-${short}-profile`, height: 400, csv: () => this.profileCSV() });
    this.curvesFigure = new Figure({ name: "Peak deflection and force", filename: `comparison-${short}-peak-force`, height: 360, csv: () => this.curvesCSV() });
    this.differenceFigure = new Figure({ name: "Difference per frame", filename: `comparison-${short}-differences`, height: 340, csv: () => this.differenceCSV() });
    this.profileStats = h("p", { class: "facts", "aria-label": "Profile against the measurement's uncertainty" });
    const notCompared = this.frames.map((frame, i) => (f.reason[i] ? h("li", {}, `Frame ${frame}: ${f.reason[i]}`) : null)).filter(Boolean);
    const m = this.overview.mapping;
    const detected = new Set(m.detected || []);
    const choice = (key, text) => `${text}${detected.has(key) ? " (detected)" : ""}`;
    const spec = this.job.spec || {};
    this.element = h(
      "div",
      { class: "viewer" },
      h("p", { class: "facts" },
        h("a", { href: `#/jobs/${this.job.id}` }, jobName(this.job)), " · topography ",
        h("a", { href: `#/jobs/${spec.job_id}/viewer` }, shortId(spec.job_id || "")), ` · simulation ${spec.simulation_id}`,
        ` · frames paired by ${this.overview.alignment} · ${f.state_lo.filter((s) => s >= 0).length} of ${this.frames.length} frames compared`),
      h("dl", { class: "facts", "aria-label": "Mapping used" },
        h("dt", {}, "Mapping"),
        h("dd", {}, [
          choice("length_unit", `units ${m.length_unit}`), choice("symmetry", `symmetry ${m.symmetry}`),
          choice("normal_axis", `normal ${m.normal_axis}`), choice("w_sign", `sign of w ${m.w_sign > 0 ? "+1" : "−1"}`),
          choice("origin_xy_mm", `origin (${num(m.origin_xy_mm[0], 2)}, ${num(m.origin_xy_mm[1], 2)}) mm`),
          `rotation ${num(m.rotation_deg, 1)}°`, `surface ${m.surface}`,
          m.shell_thickness_mm ? `shell thickness ${num(m.shell_thickness_mm, 3)} mm` : null,
        ].filter(Boolean).join(" · ")),
        (m.notes || []).length ? [h("dt", {}, "Notes"), h("dd", {}, m.notes.join("; "))] : null),
      h("div", { class: "player", role: "group", "aria-label": "Frames" },
        h("button", { type: "button", class: "small", "aria-label": "Previous frame", onclick: () => this.goTo(this.position - 1) }, "◀"),
        this.slider,
        h("button", { type: "button", class: "small", "aria-label": "Next frame", onclick: () => this.goTo(this.position + 1) }, "▶")),
      this.frameFacts,
      h("div", { class: "plot-grid" },
        h("div", {}, h("div", { class: "compare-controls" }, this.fieldChoice.wrap), this.mapFigure.element),
        h("div", {}, h("div", { class: "compare-controls" }, this.axisChoice.wrap), this.profileFigure.element, this.profileStats)),
      h("div", { class: "plot-grid" },
        h("div", {}, this.curvesFigure.element),
        h("div", {}, this.differenceFigure.element,
          notCompared.length
            ? h("div", {}, h("p", { class: "hint" }, "Frames not compared (gaps in the curves):"), h("ul", { class: "warnings", "aria-label": "Frames not compared" }, notCompared))
            : h("p", { class: "hint" }, "Every frame was compared."))),
      comparisonExportPanel(this.job, { line: () => this.profileLine(), context: this.context }),
    );
  }

  async start() {
    // Open on the compared frame of the largest measured deflection.
    const f = this.overview.frames;
    let start = -1;
    f.peak_w_mm.forEach((w, i) => {
      if (f.state_lo[i] >= 0 && w !== null && (start < 0 || w > f.peak_w_mm[start])) start = i;
    });
    start = Math.max(start, 0);
    this.slider.value = start;
    await this.showFrame(start);
  }

  dispose() {
    for (const figure of [this.mapFigure, this.profileFigure, this.curvesFigure, this.differenceFigure]) figure.purge();
  }

  goTo(position) {
    const clamped = Math.max(0, Math.min(this.frames.length - 1, position));
    this.slider.value = clamped;
    return this.showLatest(clamped);
  }

  async showFrame(position) {
    this.position = position;
    const f = this.overview.frames;
    const i = position;
    const facts = [`frame ${this.frame}`];
    if (f.time_s[i] !== null) facts.push(`t = ${num(f.time_s[i], 4)} s`);
    if (f.punch_displacement_mm[i] !== null) facts.push(`punch ${num(f.punch_displacement_mm[i], 2)} mm`);
    if (f.state_lo[i] >= 0) {
      facts.push(`simulation ${stateText(f.state_lo[i], f.state_fraction[i])}`);
      facts.push(`RMS difference ${num(f.rms_diff_mm[i], 3)} mm, largest ${num(f.max_diff_mm[i], 3)} mm over ${f.n_nodes[i]} nodes`);
      if (f.fraction_beyond_2sigma[i] !== null) facts.push(`${num(100 * f.fraction_beyond_2sigma[i], 1)} % beyond 2σ`);
    } else {
      facts.push(`not compared: ${f.reason[i]}`);
    }
    this.frameFacts.textContent = facts.join(" · ");
    try {
      await Promise.all([this.drawMap(), this.drawProfile(), this.drawCurves(), this.drawDifferences()]);
    } catch (error) {
      showError(error, `show frame ${this.frame}`);
    }
  }

  // ---- the map -------------------------------------------------------------------------------------------------

  async drawMap() {
    const name = this.fieldChoice.input.value;
    const frame = this.frame;
    const cut = await getJSON(`jobs/${this.job.id}/comparison/grid${query({ frame, field: name, budget: MAP_BUDGET })}`);
    if (!this.context.current() || frame !== this.frame || name !== this.fieldChoice.input.value) return null;
    this.shownMap = { name, frame, field: { x: cut.x_mm, y: cut.y_mm, z: cut.values_mm }, step: cut.step };
    const f = this.overview.frames;
    let range = null;
    let rangeNote = "";
    if (name === "diff_mm") {
      // One symmetric range for every frame (white is agreement), wide enough for the typical differences:
      // four times the largest RMS, so that a few outliers at the data's edge do not wash the map out.
      const largest = Math.max(...finite(f.max_diff_mm), 1e-3);
      const reach = Math.min(largest, Math.max(4 * Math.max(...finite(f.rms_diff_mm), 0), 0.05));
      range = [-reach, reach];
      rangeNote = reach < largest ? `, clipped at ±${num(reach, 2)}` : "";
    } else if (name !== "sigma_w_mm") {
      const top = Math.max(...finite(f.peak_w_mm), ...finite(this.overview.simulation.peak_w_mm), 1e-3);
      range = [-top, top];
    }
    const traces = mapTraces(this.shownMap.field, { range, valueName: FIELDS[name].value, rangeNote });
    if (name === "sigma_w_mm") Object.assign(traces[0], { colorscale: "Viridis", zmid: undefined, zmin: 0 });
    const plotLayout = { ...mapLayout({ uirevision: "comparison-map" }), dragmode: "zoom" };
    // The result grid's extent for every frame and field (a frame with nothing to draw too); a zoom is kept.
    const g = this.overview.grid;
    plotLayout.xaxis = { ...plotLayout.xaxis, range: [g.x_min_mm, g.x_max_mm] };
    plotLayout.yaxis = { ...plotLayout.yaxis, range: [g.y_min_mm, g.y_max_mm] };
    const i = this.position;
    if (!this.shownMap.field.z.some((row) => row.some((v) => v !== null))) {
      const why = f.state_lo[i] < 0 ? `not compared:<br>${f.reason[i]}` : "has no value here";
      plotLayout.annotations = [{ text: `Frame ${frame} ${why}`, xref: "paper", yref: "paper", x: 0.5, y: 0.5, showarrow: false, font: { size: 13, color: "#5b6472" } }];
    }
    return this.mapFigure.react(traces, plotLayout);
  }

  mapCSV() {
    const shown = this.shownMap;
    if (!shown) return { columns: ["frame", "x_mm", "y_mm", "value_mm"], rows: [] };
    const step = this.overview.grid.step_mm;
    return {
      filename: `comparison-${shortId(this.job.id)}-${shown.name}-frame${shown.frame}`,
      columns: ["frame", "x_mm", "y_mm", shown.name, "grid", "grid_step_mm"],
      rows: fieldRows(shown.field).map((row) => [shown.frame, ...row, shown.step === 1 ? "result" : `display (${shown.step} × ${shown.step} block averages)`, step * shown.step]),
    };
  }

  // ---- the profile -----------------------------------------------------------------------------------------------

  profileLine() {
    const p = this.shownProfile && this.shownProfile.profile;
    if (!p || !p.x_mm.length) return null;
    const n = p.x_mm.length - 1;
    return [p.x_mm[0], p.y_mm[0], p.x_mm[n], p.y_mm[n]];
  }

  async drawProfile() {
    const along = this.axisChoice.input.value;
    const frame = this.frame;
    const profile = await getJSON(`jobs/${this.job.id}/comparison/profile${query({ frame, axis: along })}`);
    if (!this.context.current() || frame !== this.frame || along !== this.axisChoice.input.value) return null;
    // Where the measurement and the simulation differ by more than twice the measurement's own σ: marked.
    const beyond = profile.s_mm.map((s, k) => {
      const [m, sim, sigma] = [profile.measured_mm[k], profile.simulated_mm[k], profile.sigma_mm[k]];
      return m !== null && sim !== null && sigma !== null && Math.abs(m - sim) > 2 * sigma;
    });
    this.shownProfile = { along, frame, profile, beyond };
    const traces = profileTraces(profile);
    const marked = beyond.filter(Boolean).length;
    // On a second axis: the difference itself within ±2σ of the measurement (the band it must stay in).
    const difference = profile.s_mm.map((_, k) => (profile.measured_mm[k] !== null && profile.simulated_mm[k] !== null ? profile.measured_mm[k] - profile.simulated_mm[k] : null));
    const twoSigma = profile.sigma_mm.map((sigma, k) => (sigma !== null && difference[k] !== null ? 2 * sigma : null));
    traces.push(bandTrace(profile.s_mm, twoSigma.map((v) => (v === null ? null : -v)), twoSigma, { name: "±2σ", color: "rgba(120,120,120,0.3)", yaxis: "y2" }));
    traces.push({ type: "scatter", mode: "lines", name: "difference meas. − sim.", x: profile.s_mm, y: difference, yaxis: "y2", line: { color: "#111", width: 1, dash: "dot" }, connectgaps: false });
    traces.push({
      type: "scatter", mode: "markers", name: "|w_meas − w_sim| > 2σ",
      x: profile.s_mm.filter((_, k) => beyond[k]), y: profile.measured_mm.filter((_, k) => beyond[k]),
      marker: { symbol: "x", size: 8, color: "#c2185b" }, hovertemplate: "s %{x:.1f} mm: beyond 2σ<extra></extra>",
    });
    const known = beyond.map((_, k) => profile.measured_mm[k] !== null && profile.simulated_mm[k] !== null && profile.sigma_mm[k] !== null).filter(Boolean).length;
    this.profileStats.textContent = profile.simulated_mm.some((v) => v !== null)
      ? `${marked} of ${known} points along the profile differ by more than 2σ of the measurement (marked ×); the blue band is measured ± σ, the grey one ±2σ around the difference (right axis).`
      : `Frame ${frame} was not compared: no simulated profile.`;
    return this.profileFigure.react(traces, lineLayout({
      xAxis: axis(`distance along ${along.toUpperCase()} through the punch axis`, "mm"),
      yAxis: axis("deflection w", "mm"),
      y2Axis: axis("difference w_meas − w_sim", "mm"),
    }));
  }

  profileCSV() {
    const shown = this.shownProfile;
    if (!shown) return { columns: ["frame", "s_mm"], rows: [] };
    const p = shown.profile;
    return {
      filename: `comparison-${shortId(this.job.id)}-profile-${shown.along}-frame${shown.frame}`,
      columns: ["frame", "along", "s_mm", "x_mm", "y_mm", "w_meas_mm", "w_sim_mm", "sigma_w_mm", "beyond_2sigma", "grid", "grid_step_mm"],
      rows: p.s_mm.map((s, k) => [shown.frame, shown.along, s, p.x_mm[k], p.y_mm[k], p.measured_mm[k], p.simulated_mm[k], p.sigma_mm[k], shown.beyond[k] ? 1 : 0, "result", this.overview.grid.step_mm]),
    };
  }

  // ---- curves over the test ------------------------------------------------------------------------------------------

  /** The x of the curves: punch displacement where the test logged it, else time, else the frame. */
  curveAxis() {
    const f = this.overview.frames;
    if (finite(f.punch_displacement_mm).length) {
      return { key: "punch_displacement_mm", title: axis("punch displacement", "mm"), frames: f.punch_displacement_mm, states: this.overview.simulation.punch_displacement_mm };
    }
    if (finite(f.time_s).length) {
      // The states' times on the test's clock: the model's time plus the offset the mapping added to align them.
      const offset = this.overview.mapping.time_offset_s || 0;
      const states = this.overview.simulation.time_s.map((t) => (t === null ? null : t + offset));
      return { key: "time_s", title: axis("time", "s"), frames: f.time_s, states };
    }
    return { key: "frame", title: axis("frame", "index"), frames: this.frames, states: null };
  }

  drawCurves() {
    const f = this.overview.frames;
    const s = this.overview.simulation;
    const x = this.curveAxis();
    const series = [{ name: "peak w, measured", x: x.frames, y: f.peak_w_mm, color: COLORS[0], mode: "lines+markers" }];
    // The simulation's own states where they have the same x (its punch travel, its time); else its blend at each
    // compared frame, at the frame's x.
    const ownX = Boolean(x.states && finite(x.states).length);
    series.push(ownX
      ? { name: "peak w, simulated", x: x.states, y: s.peak_w_mm, color: COLORS[1], dash: "dash", mode: "lines+markers" }
      : { name: "peak w, simulated", x: x.frames, y: f.sim_peak_w_mm, color: COLORS[1], dash: "dash", mode: "lines+markers" });
    const haveForce = finite(f.force_kN).length || finite(s.force_kN).length;
    if (finite(f.force_kN).length) series.push({ name: "force, measured", x: x.frames, y: f.force_kN, color: COLORS[2], yaxis: "y2" });
    if (finite(s.force_kN).length) {
      series.push(ownX
        ? { name: "force, simulated", x: x.states, y: s.force_kN, color: COLORS[3], dash: "dash", yaxis: "y2" }
        : { name: "force, simulated", x: x.frames, y: f.sim_force_kN, color: COLORS[3], dash: "dash", yaxis: "y2" });
    }
    const traces = lineTraces(series);
    // A frame whose peak was not measured (only a lower bound; its peak_w_mm is null) is a gap, marked on the
    // measured curve's line of missing values, never at w = 0.
    const unmeasured = (f.peak_measured || []).map((v) => v === 0 || v === false);
    traces.push(...missingMarkTraces(x.frames, f.peak_w_mm, unmeasured, { name: "peak not measured", lineColor: COLORS[0], hover: (k) => `frame ${this.frames[k]}: peak not measured (a lower bound only)` }));
    const i = this.position;
    traces.push({ type: "scatter", mode: "markers", name: "this frame", x: [x.frames[i]], y: [f.peak_w_mm[i]], marker: { size: 12, color: "#111", symbol: "circle-open", line: { width: 2 } } });
    return this.curvesFigure.react(traces, lineLayout({ xAxis: x.title, yAxis: axis("peak deflection w", "mm"), y2Axis: haveForce ? axis("force", "kN") : null }));
  }

  curvesCSV() {
    const f = this.overview.frames;
    const s = this.overview.simulation;
    const measured = f.peak_measured || [];
    const rows = this.frames.map((frame, i) => ["measured frame", frame, f.time_s[i], f.punch_displacement_mm[i], f.force_kN[i], f.peak_w_mm[i], measured[i] ?? ""]);
    s.time_s.forEach((t, k) => rows.push(["simulation state", k, t, s.punch_displacement_mm[k], s.force_kN[k], s.peak_w_mm[k], ""]));
    return { columns: ["source", "frame_or_state", "time_s", "punch_displacement_mm", "force_kN", "peak_w_mm", "peak_measured"], rows };
  }

  /** RMS and largest |w_meas − w_sim| per frame: a frame not compared is a gap (null), marked on the axis with its
   * reason, never a drop to zero. */
  drawDifferences() {
    const f = this.overview.frames;
    const x = finite(f.time_s).length === this.frames.length ? { title: axis("time", "s"), values: f.time_s } : { title: axis("frame", "index"), values: this.frames };
    const traces = lineTraces([
      { name: "RMS difference", x: x.values, y: f.rms_diff_mm, color: COLORS[0], mode: "lines+markers" },
      { name: "largest difference", x: x.values, y: f.max_diff_mm, color: COLORS[1], mode: "lines+markers", dash: "dot" },
    ]);
    const missing = this.frames.map((_, i) => f.state_lo[i] < 0 || f.rms_diff_mm[i] === null);
    if (missing.some(Boolean)) {
      traces.push({
        type: "scatter", mode: "markers", name: "not compared",
        x: x.values.filter((_, i) => missing[i]), y: x.values.filter((_, i) => missing[i]).map(() => 0),
        text: f.reason.filter((_, i) => missing[i]).map((r) => r || "no node with both"),
        marker: { size: 11, symbol: "x-thin-open", color: "#c2185b", line: { width: 2 } },
        cliponaxis: false, // on the axis line, whole
        hovertemplate: "not compared: %{text}<extra></extra>",
      });
    }
    return this.differenceFigure.react(traces, lineLayout({
      xAxis: x.title,
      yAxis: axis("|w_meas − w_sim|", "mm", { rangemode: "tozero" }),
      shapes: [verticalMarker(x.values[this.position])],
    }));
  }

  differenceCSV() {
    const f = this.overview.frames;
    return {
      columns: ["frame", "time_s", "state_lo", "state_fraction", "rms_diff_mm", "max_diff_mm", "mean_diff_mm", "fraction_beyond_2sigma", "n_nodes", "reason"],
      rows: this.frames.map((frame, i) => [frame, f.time_s[i], f.state_lo[i], f.state_fraction[i], f.rms_diff_mm[i], f.max_diff_mm[i], f.mean_diff_mm[i], f.fraction_beyond_2sigma[i], f.n_nodes[i], f.reason[i]]),
    };
  }
}
