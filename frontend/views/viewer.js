// The topography viewer of a topography job: the deflection field of a frame as a 2-D map and a 3-D surface,
// a frame slider with play/pause, section lines drawn on the map with their profiles for the chosen frames,
// time histories of clicked points, peak deflection against punch displacement (force on a second axis), what of
// the plate each frame measured and why the rest is missing (outlined on the map too), and one camera against
// another. Every plot downloads its data (CSV) and its image (PNG).
import { getJSON } from "../api.js";
import {
  COLORS,
  Figure,
  fieldRange,
  resampleField,
  MARK_COLORS,
  axis,
  fieldRows,
  lineLayout,
  lineTraces,
  listenToMap,
  mapLayout,
  mapTraces,
  missingOutlineTraces,
  surfaceLayout,
  surfaceTraces,
  verticalMarker,
} from "../plots.js";
import { attempt, field, fill, h, latestOnly, num, page, say, showError } from "../ui.js";
import { TopographySource } from "./topography-source.js";
import { exportPanel } from "./exports.js";
import { explained } from "./calibration.js";
import { jobName } from "./jobs.js";

const LINE_LABELS = "ABCDEFGHIJKLMNOPQRSTUVWXYZ";
const DASHES = ["solid", "dash", "dot", "dashdot", "longdash", "longdashdot"];
const FRAME_CACHE = 64; // fields kept in memory for quick back-and-forth (each ≤ 250 × 250 float32 = 250 kB)
const SPEEDS = [2, 5, 10, 25];

/** Diagnostics for the browser tests and curious users (devtools): the viewer shown, and how long each frame
 * switch took (fetch, decode and Plotly.react of the field and the profiles), in ms. */
window.fringelab = { frameSwitchMs: [], viewer: null };

/** The unit the test's times read best in: ms for a high-speed test, s for a quasi-static one. */
function timeUnit(meta) {
  const finite = meta.frames.time_s.filter(Number.isFinite);
  const span = finite.length ? Math.max(...finite.map(Math.abs)) : 0;
  return span >= 1 ? { unit: "s", scale: 1 } : { unit: "ms", scale: 1000 };
}

function timeLabel(meta, frame) {
  const i = meta.frames.index.indexOf(frame);
  const t = i >= 0 ? meta.frames.time_s[i] : NaN;
  const { unit, scale } = timeUnit(meta);
  return Number.isFinite(t) ? `t = ${num(t * scale, 3)} ${unit}` : `frame ${frame}`;
}

export async function renderViewer(container, { id }, context) {
  const job = await attempt("open the job", () => getJSON(`jobs/${id}`));
  if (!job || !context.current()) return;
  if (job.kind !== "topography" || job.state !== "succeeded") {
    page(container, "Topography viewer", h("p", {}, h("a", { href: `#/jobs/${job.id}` }, jobName(job)),
      job.kind !== "topography" ? " is not a topography job." : ` is ${job.state}; its results come when it has succeeded.`));
    return;
  }
  const source = new TopographySource(job);
  const meta = await attempt("read the topography result", () => source.meta());
  if (!meta || !context.current()) return;
  const viewer = new Viewer(job, source, meta, context);
  window.fringelab = { frameSwitchMs: [], viewer };
  page(container, `Topography: ${jobName(job)}`, viewer.element);
  context.onLeave(() => {
    viewer.dispose();
    window.fringelab.viewer = null;
  });
  await viewer.start();
}

/** y at x by linear interpolation between the samples (xs increasing); NaN outside them or next to a gap. */
function interpolate(xs, ys, x) {
  if (!Number.isFinite(x)) return NaN;
  for (let i = 0; i + 1 < xs.length; i += 1) {
    if (x >= xs[i] && x <= xs[i + 1]) {
      const f = xs[i + 1] === xs[i] ? 0 : (x - xs[i]) / (xs[i + 1] - xs[i]);
      return ys[i] * (1 - f) + ys[i + 1] * f;
    }
  }
  return xs.length === 1 && xs[0] === x ? ys[0] : NaN;
}

class Viewer {
  constructor(job, source, meta, context) {
    this.job = job;
    this.source = source;
    this.meta = meta;
    this.context = context;
    this.frames = meta.frames.index; // recording frame numbers, in order
    this.position = 0; // index into this.frames
    this.cache = new Map();
    this.lines = [];
    this.points = [];
    this.pinned = new Set();
    this.fieldView = "map";
    this.playing = false;
    this.timer = null;
    this.fullResolution = false;
    // Symmetric about zero, so that white is a flat plate and red and blue read as up and down.
    const reach = Math.max(Math.abs(meta.w_range_mm[0]), Math.abs(meta.w_range_mm[1])) || 1;
    this.colorRange = [-reach, reach];
    this.showLatest = latestOnly((position) => this.showFrame(position));
    this.build();
  }

  get frame() {
    return this.frames[this.position];
  }

  // ---- layout ----------------------------------------------------------------------------------------------

  build() {
    const last = this.frames.length - 1;
    this.slider = h("input", { type: "range", min: 0, max: last, step: 1, value: 0, "aria-label": "Frame", class: "scrubber" });
    this.slider.addEventListener("input", () => this.goTo(Number(this.slider.value)));
    this.frameNumber = h("input", { type: "number", min: this.frames[0], max: this.frames[last], step: 1, value: this.frames[0], "aria-label": "Frame number" });
    this.frameNumber.addEventListener("change", () => {
      const wanted = Number(this.frameNumber.value);
      const nearest = this.frames.reduce((best, f, i) => (Math.abs(f - wanted) < Math.abs(this.frames[best] - wanted) ? i : best), 0);
      this.goTo(nearest);
    });
    this.playButton = h("button", { type: "button", class: "primary play", "aria-label": "Play", onclick: () => this.togglePlay() }, "▶ Play");
    this.speed = field("Playback speed (frames/s)", h("select", {}, SPEEDS.map((s) => h("option", { value: s, selected: s === 10 }, String(s)))));
    this.frameFacts = h("output", { class: "frame-facts", "aria-live": "off", "aria-label": "Current frame" });

    // Field: a tab for the map, a tab for the surface.
    this.mapFigure = new Figure({
      name: "Deflection map",
      filename: `topography-${this.job.id.slice(0, 8)}-map`,
      height: 470,
      csv: () => this.fieldCSV(),
      config: { modeBarButtonsToAdd: ["drawline"] },
    });
    this.surfaceFigure = new Figure({
      name: "Deflection surface",
      filename: `topography-${this.job.id.slice(0, 8)}-surface`,
      height: 470,
      csv: () => this.fieldCSV(),
    });
    this.surfaceFigure.element.hidden = true;
    const tab = (name, view) =>
      h("button", {
        type: "button",
        role: "tab",
        "aria-selected": view === "map" ? "true" : "false",
        "aria-controls": `field-${view}`,
        tabindex: view === "map" ? 0 : -1,
        onclick: () => this.showFieldView(view),
        onkeydown: (event) => {
          // Arrow keys move between the two tabs, as screen-reader users expect of a tab list.
          if (event.key !== "ArrowLeft" && event.key !== "ArrowRight") return;
          const next = view === "map" ? "surface" : "map";
          this.tabs[next].focus();
          this.showFieldView(next);
        },
      }, name);
    this.tabs = { map: tab("2-D map", "map"), surface: tab("3-D surface", "surface") };
    this.mapFigure.element.id = "field-map";
    this.surfaceFigure.element.id = "field-surface";
    this.mapFigure.element.setAttribute("role", "tabpanel");
    this.surfaceFigure.element.setAttribute("role", "tabpanel");
    // Off: one colour range for every frame (the whole test's); on: the range of what is in view, so that a
    // zoomed area is not one colour.
    this.viewRangeBox = h("input", { type: "checkbox", id: "view-colour-range" });
    this.viewRangeBox.addEventListener("change", () => this.drawField());
    this.fullRes = h("input", { type: "checkbox", id: "full-resolution" });
    this.fullRes.addEventListener("change", () => {
      this.fullResolution = this.fullRes.checked;
      this.cache.clear();
      this.redraw();
    });

    // Profiles.
    this.profileFigure = new Figure({ name: "Section profiles", filename: `topography-${this.job.id.slice(0, 8)}-profiles`, height: 360, csv: () => this.profileCSV() });
    this.lineList = h("ul", { class: "chips", "aria-label": "Section lines" });
    this.pinList = h("ul", { class: "chips", "aria-label": "Pinned frames" });
    const lineInputs = ["x₀", "y₀", "x₁", "y₁"].map((name) => field(`Line ${name} (mm)`, h("input", { type: "number", step: "any", required: true })));
    this.lineForm = h(
      "form",
      {
        class: "inline-form",
        "aria-label": "Add a section line",
        onsubmit: (event) => {
          event.preventDefault();
          const [x0, y0, x1, y1] = lineInputs.map((f) => Number(f.input.value));
          if (x0 === x1 && y0 === y1) return showError("the two ends of a line must differ", "add the section line");
          this.addLine({ x0, y0, x1, y1 });
        },
      },
      lineInputs.map((f) => f.wrap),
      h("button", { type: "submit", class: "small" }, "Add line"),
    );

    // Histories.
    this.historyFigure = new Figure({ name: "Point histories", filename: `topography-${this.job.id.slice(0, 8)}-histories`, height: 340, csv: () => this.historyCSV() });
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
          this.addPoint({ x, y });
        },
      },
      pointInputs.map((f) => f.wrap),
      h("button", { type: "submit", class: "small" }, "Add point"),
    );

    // Peak against punch displacement and force; camera against camera.
    this.peakFigure = new Figure({ name: "Peak deflection and force", filename: `topography-${this.job.id.slice(0, 8)}-peak`, height: 340, csv: () => this.peakCSV() });
    this.compareSelect = h("select", { id: "compare-with" }, h("option", { value: "" }, "no other camera"));
    this.compareSelect.addEventListener("change", () => this.loadComparison());
    this.compareWhat = h("select", { id: "compare-what" },
      h("option", { value: "peak" }, "peak deflection over time"),
      h("option", { value: "profile" }, "profile along the first section line, this frame"),
      h("option", { value: "map" }, "difference map, this frame"));
    this.compareWhat.addEventListener("change", () => this.drawComparison());
    this.coverageFigure = new Figure({ name: "Coverage over time", filename: `topography-${this.job.id.slice(0, 8)}-coverage`, height: 340, csv: () => this.coverageCSV() });
    this.compareFigure = new Figure({ name: "Camera against camera", filename: `topography-${this.job.id.slice(0, 8)}-cameras`, height: 420, csv: () => this.compareCSV() });

    this.exports = exportPanel(this.job, { frames: this.frames, lines: () => this.lines, context: this.context });
    const m = this.meta;
    this.element = h(
      "div",
      { class: "viewer" },
      h("p", { class: "facts" },
        h("a", { href: `#/jobs/${this.job.id}` }, jobName(this.job)), " · ",
        `${this.frames.length} frames · grid ${m.grid.nx} × ${m.grid.ny} nodes, ${num(m.grid.step_mm, 2)} mm apart · `,
        `peak deflection up to ${num(m.w_range_mm[1], 2)} mm · `,
        explained("how w is measured and what is left unmeasured", "6-topography-and-results")),
      h("div", { class: "player", role: "group", "aria-label": "Frames" },
        this.playButton,
        h("button", { type: "button", class: "small", "aria-label": "Previous frame", onclick: () => this.goTo(this.position - 1) }, "◀"),
        this.slider,
        h("button", { type: "button", class: "small", "aria-label": "Next frame", onclick: () => this.goTo(this.position + 1) }, "▶"),
        this.frameNumber,
        this.speed.wrap),
      this.frameFacts,
      h("div", { class: "plot-grid" },
        h("div", {},
          h("div", { class: "tabs" },
            h("div", { class: "tab-list", role: "tablist", "aria-label": "Field view" }, this.tabs.map, this.tabs.surface),
            h("label", { class: "check" }, this.viewRangeBox, " Colour range of this view"),
            h("label", { class: "check" }, this.fullRes, " Full resolution for the zoomed region")),
          this.mapFigure.element,
          this.surfaceFigure.element,
          h("p", { class: "hint" }, "Drag on the map to draw a section line; click a point to add its time history.")),
        h("div", {},
          this.profileFigure.element,
          h("div", { class: "chip-row" }, h("span", {}, "Lines: "), this.lineList),
          h("div", { class: "chip-row" }, h("span", {}, "Profiles of: the current frame, and "),
            this.pinList,
            h("button", { type: "button", class: "small", onclick: () => this.pinFrame() }, "Pin this frame")),
          h("details", {}, h("summary", {}, "Type a section line"), this.lineForm))),
      h("div", { class: "plot-grid" },
        h("div", {}, this.historyFigure.element, h("div", { class: "chip-row" }, h("span", {}, "Points: "), this.pointList),
          h("details", {}, h("summary", {}, "Type a point"), this.pointForm)),
        h("div", {}, this.peakFigure.element)),
      h("div", { class: "plot-grid" },
        h("div", {}, this.coverageFigure.element,
          h("p", { class: "hint" }, "Share of the plate (as the first frame sees it) measured in each frame, and the area missing by reason (bars; hover for what each covers); missing regions are outlined on the map."))),
      (this.compareSection = h("section", { "aria-label": "Camera against camera", hidden: true },
        h("h2", {}, "Camera against camera"),
        h("div", { class: "compare-controls" },
          h("div", { class: "field inline" }, h("label", { for: "compare-with" }, "Compare with the topography of"), this.compareSelect),
          h("div", { class: "field inline" }, h("label", { for: "compare-what" }, "Compare"), this.compareWhat)),
        (this.compareStats = h("p", { class: "facts", "aria-label": "Difference between the cameras" })),
        this.compareFigure.element)),
      this.exports.element,
    );
  }

  async start() {
    this.slider.addEventListener("keydown", (event) => {
      if (event.key === " ") {
        event.preventDefault();
        this.togglePlay();
      }
    });
    // Open on the frame of the largest deflection: the first thing worth seeing.
    const peaks = this.meta.frames.peak_w_mm;
    const start = peaks.reduce((best, w, i) => (Number.isFinite(w) && !(w <= peaks[best]) ? i : best), 0);
    this.slider.value = start;
    this.frameNumber.value = this.frames[start];
    this.drawChips();
    await this.showFrame(start);
    // Left already (the page changed while the first frame loaded): nothing to listen to.
    if (!this.context.current() || !this.mapFigure.drawn) return;
    // Plotly adds its event methods to the plot once it has drawn it.
    listenToMap(this.mapFigure, { onLine: (line) => this.addLine(line), onPoint: (point) => this.addPoint(point) });
    this.mapFigure.plot.on("plotly_relayout", (update) => {
      const zoomed = Object.keys(update).some((key) => key.startsWith("xaxis.") || key.startsWith("yaxis."));
      if (zoomed && this.fullResolution) this.redraw(); // fetch the new window at full resolution
      else if (zoomed && this.viewRangeBox.checked) this.drawField(); // the colours follow the zoom
    });
    await this.drawPeak();
    await this.drawCoverage();
    this.findOtherCameras();
  }

  dispose() {
    this.playing = false;
    clearTimeout(this.timer);
    for (const figure of [this.mapFigure, this.surfaceFigure, this.profileFigure, this.historyFigure, this.peakFigure, this.coverageFigure, this.compareFigure]) figure.purge();
  }

  // ---- frames ----------------------------------------------------------------------------------------------

  async field(frame) {
    const region = this.fullResolution ? this.zoomRegion() : null;
    const key = `${frame}:${region ? Object.values(region).join(",") : "all"}`;
    if (this.cache.has(key)) {
      const hit = this.cache.get(key);
      this.cache.delete(key); // most recent last
      this.cache.set(key, hit);
      return hit;
    }
    const loaded = await this.source.field(frame, region);
    this.cache.set(key, loaded);
    if (this.cache.size > FRAME_CACHE) this.cache.delete(this.cache.keys().next().value);
    return loaded;
  }

  zoomRegion() {
    const { xaxis, yaxis } = this.mapFigure.plot.layout || {};
    if (!xaxis || !yaxis || !xaxis.range || !yaxis.range) return null;
    const [x0, x1] = xaxis.range.map(Number).sort((a, b) => a - b);
    const [y0, y1] = yaxis.range.map(Number).sort((a, b) => a - b);
    return { x0, x1, y0, y1 };
  }

  /** Go to the frame at `position`; quick moves of the slider collapse into the latest one. */
  goTo(position) {
    const clamped = Math.max(0, Math.min(this.frames.length - 1, position));
    this.slider.value = clamped;
    this.frameNumber.value = this.frames[clamped];
    return this.showLatest(clamped);
  }

  async showFrame(position) {
    const started = performance.now();
    this.position = position;
    const frame = this.frame;
    try {
      // The field and the profiles come from two requests: ask for both at once.
      const [current, profiles] = await Promise.all([this.field(frame), this.profiles()]);
      if (!this.context.current()) return;
      this.current = current;
      await Promise.all([this.drawField(), this.drawProfiles(profiles)]);
      window.fringelab.frameSwitchMs.push(performance.now() - started);
      await Promise.all([
        this.drawHistories(),
        this.peakFigure.drawn ? this.drawPeak() : null,
        this.coverageFigure.drawn ? this.drawCoverage() : null,
        this.compareFigure.drawn ? this.drawComparison() : null,
      ]);
    } catch (error) {
      showError(error, `show frame ${frame}`);
      this.stop();
    }
    const i = this.position;
    const m = this.meta.frames;
    const facts = [`frame ${frame}`, timeLabel(this.meta, frame)];
    if (Number.isFinite(m.punch_displacement_mm[i])) facts.push(`punch ${num(m.punch_displacement_mm[i], 2)} mm`);
    if (Number.isFinite(m.force_kN[i])) facts.push(`force ${num(m.force_kN[i], 2)} kN`);
    if (Number.isFinite(m.peak_w_mm[i])) facts.push(`peak w ${num(m.peak_w_mm[i], 3)} mm`);
    this.frameFacts.textContent = facts.join(" · ");
  }

  redraw() {
    return this.goTo(this.position);
  }

  togglePlay() {
    if (this.playing) this.stop();
    else this.play();
  }

  play() {
    this.playing = true;
    this.playButton.textContent = "❚❚ Pause";
    this.playButton.setAttribute("aria-label", "Pause");
    const tick = async () => {
      if (!this.playing || !this.context.current()) return;
      const began = performance.now();
      await this.goTo((this.position + 1) % this.frames.length);
      const wait = Math.max(0, 1000 / Number(this.speed.input.value) - (performance.now() - began));
      this.timer = setTimeout(tick, wait);
    };
    tick();
  }

  stop() {
    this.playing = false;
    clearTimeout(this.timer);
    this.playButton.textContent = "▶ Play";
    this.playButton.setAttribute("aria-label", "Play");
  }

  // ---- the field -----------------------------------------------------------------------------------------

  showFieldView(view) {
    this.fieldView = view;
    for (const [name, button] of Object.entries(this.tabs)) {
      button.setAttribute("aria-selected", String(name === view));
      button.tabIndex = name === view ? 0 : -1;
    }
    this.mapFigure.element.hidden = view !== "map";
    this.surfaceFigure.element.hidden = view !== "surface";
    return this.drawField();
  }

  /** Only the visible view is drawn on a frame switch; the other catches up when its tab is chosen. */
  async drawField() {
    if (!this.current) return null;
    const own = this.viewRangeBox.checked;
    // The map's view is its zoom window; the surface shows the whole frame.
    const range = own ? fieldRange(this.current, this.fieldView === "map" ? this.zoomRegion() : null) || this.colorRange : this.colorRange;
    this.shownColorRange = range;
    const rangeNote = own ? ", this view" : "";
    if (this.fieldView === "surface") {
      return this.surfaceFigure.react(surfaceTraces(this.current, { range, rangeNote }), surfaceLayout({ zRange: this.meta.w_range_mm }));
    }
    const lines = this.lines.map((line) => ({ ...line }));
    const reference = await this.field(this.frames[0]);
    const traces = [...mapTraces(this.current, { range, points: this.points, rangeNote }), ...missingOutlineTraces(this.current, reference)];
    return this.mapFigure.react(traces, mapLayout({ lines }));
  }

  /** Which grid the numbers of a field come from: the result's own, or the display grid of block averages. */
  gridOf(field) {
    const resultStep = this.meta.grid.step_mm;
    if (!field || field.step === 1) return { grid: "result", step_mm: resultStep, name: `result-grid-${num(resultStep, 2)}mm` };
    return { grid: `display (${field.step} × ${field.step} block averages of the ${num(resultStep, 2)} mm result grid)`, step_mm: field.stepMm, name: `display-grid-${num(field.stepMm, 2)}mm` };
  }

  fieldCSV() {
    const grid = this.gridOf(this.current);
    return {
      filename: `topography-${this.job.id.slice(0, 8)}-frame${this.frame}-${grid.name}`,
      columns: ["frame", "x_mm", "y_mm", "w_mm", "grid", "grid_step_mm"],
      rows: fieldRows(this.current).map((row) => [this.frame, ...row, grid.grid, grid.step_mm]),
    };
  }

  // ---- section lines and their profiles --------------------------------------------------------------------

  addLine(line) {
    const index = this.lines.length;
    const label = LINE_LABELS[index % LINE_LABELS.length] + (index >= LINE_LABELS.length ? String(Math.floor(index / LINE_LABELS.length)) : "");
    this.lines.push({ ...line, label, color: MARK_COLORS[index % MARK_COLORS.length] });
    this.drawChips();
    say(`Section line ${label} from (${num(line.x0, 1)}, ${num(line.y0, 1)}) to (${num(line.x1, 1)}, ${num(line.y1, 1)}) mm.`);
    return Promise.all([this.drawField(), this.drawProfiles(), this.compareFigure.drawn ? this.drawComparison() : null]);
  }

  removeLine(label) {
    this.lines = this.lines.filter((line) => line.label !== label);
    this.drawChips();
    return Promise.all([this.drawField(), this.drawProfiles()]);
  }

  pinFrame() {
    this.pinned.add(this.frame);
    this.drawChips();
    return this.drawProfiles();
  }

  drawChips() {
    if (this.exports) this.exports.describe();
    const chip = (text, color, remove, name) =>
      h("li", {}, h("span", { class: "swatch", style: `background:${color}` }), text,
        h("button", { type: "button", class: "link", "aria-label": `Remove ${name}`, onclick: remove }, "×"));
    fill(this.lineList, this.lines.length ? this.lines.map((line) => chip(line.label, line.color, () => this.removeLine(line.label), `line ${line.label}`)) : h("li", { class: "empty" }, "none yet"));
    fill(this.pinList, [...this.pinned].sort((a, b) => a - b).map((frame) => chip(`frame ${frame}`, "#888", () => {
      this.pinned.delete(frame);
      this.drawChips();
      this.drawProfiles();
    }, `pinned frame ${frame}`)));
    fill(this.pointList, this.points.length ? this.points.map((point) => chip(point.label, point.color, () => this.removePoint(point.label), `point ${point.label}`)) : h("li", { class: "empty" }, "none yet"));
  }

  /** Profiles of every line for the current frame and the pinned ones: [{ line, frame, profile }], one request
   * per line (the server samples the full-resolution grid). */
  async profiles() {
    const frames = [this.frame, ...[...this.pinned].filter((f) => f !== this.frame).sort((a, b) => a - b)];
    const perLine = await Promise.all(this.lines.map((line) => this.source.profiles(frames, line)));
    return this.lines.flatMap((line, i) => perLine[i].map((profile) => ({ line, frame: profile.frame, profile })));
  }

  async drawProfiles(profiles = null) {
    this.shownProfiles = profiles || (await this.profiles());
    const frames = [...new Set(this.shownProfiles.map((p) => p.frame))];
    const series = this.shownProfiles.map(({ line, frame, profile }) => ({
      name: `${line.label}, ${timeLabel(this.meta, frame)}`,
      x: profile.s,
      y: profile.w,
      color: line.color,
      dash: DASHES[frames.indexOf(frame) % DASHES.length],
    }));
    return this.profileFigure.react(lineTraces(series), lineLayout({
      note: series.length ? null : "Drag on the map to draw a section line",
      xAxis: axis("distance along the line", "mm"),
      yAxis: axis("deflection w", "mm", { range: this.meta.w_range_mm }),
    }));
  }

  profileCSV() {
    const rows = [];
    for (const { line, frame, profile } of this.shownProfiles || []) {
      for (let i = 0; i < profile.s.length; i += 1) rows.push([line.label, frame, profile.s[i], profile.x[i], profile.y[i], profile.w[i]]);
    }
    // Profiles are sampled (bilinear) from the result grid on the server, whatever the map shows.
    const step = this.meta.grid.step_mm;
    return { columns: ["line", "frame", "s_mm", "x_mm", "y_mm", "w_mm", "grid", "grid_step_mm"], rows: rows.map((r) => [...r, "result", step]) };
  }

  // ---- points and their histories -------------------------------------------------------------------------

  async addPoint(point) {
    const index = this.points.length;
    const entry = { ...point, label: `P${index + 1}`, color: MARK_COLORS[(index + 1) % MARK_COLORS.length], history: null };
    this.points.push(entry);
    this.drawChips();
    say(`Point ${entry.label} at (${num(point.x, 1)}, ${num(point.y, 1)}) mm.`);
    try {
      entry.history = await this.source.history(point);
    } catch (error) {
      showError(error, `read the history of ${entry.label}`);
    }
    await Promise.all([this.drawField(), this.drawHistories()]);
  }

  removePoint(label) {
    this.points = this.points.filter((p) => p.label !== label);
    this.drawChips();
    return Promise.all([this.drawField(), this.drawHistories()]);
  }

  timeAxis() {
    const t = this.meta.frames.time_s;
    const { unit, scale } = timeUnit(this.meta);
    return t.every(Number.isFinite)
      ? { key: "time", unit, scale, title: axis("time", unit), values: t.map((v) => v * scale) }
      : { key: "frame", title: axis("frame", "index"), values: this.frames };
  }

  drawHistories() {
    const time = this.timeAxis();
    const series = this.points.filter((p) => p.history).map((p) => ({
      name: `${p.label} (${num(p.x, 1)}, ${num(p.y, 1)}) mm`,
      x: p.history.frame.map((f) => time.values[this.frames.indexOf(f)]),
      y: p.history.w,
      color: p.color,
      mode: "lines+markers",
    }));
    return this.historyFigure.react(lineTraces(series), lineLayout({
      note: series.length ? null : "Click a point on the map to see its deflection over time",
      xAxis: time.title,
      yAxis: axis("deflection w", "mm"),
      shapes: [verticalMarker(time.values[this.position])],
    }));
  }

  historyCSV() {
    const rows = [];
    for (const p of this.points.filter((q) => q.history)) {
      p.history.frame.forEach((frame, i) => rows.push([p.label, p.x, p.y, frame, p.history.time_s[i], p.history.w[i]]));
    }
    const step = this.meta.grid.step_mm;
    return { columns: ["point", "x_mm", "y_mm", "frame", "time_s", "w_mm", "grid", "grid_step_mm"], rows: rows.map((r) => [...r, "result", step]) };
  }

  // ---- peak against punch and force; cameras --------------------------------------------------------------

  drawPeak() {
    const m = this.meta.frames;
    const i = this.position;
    const haveForce = m.force_kN.some(Number.isFinite);
    const havePunch = m.punch_displacement_mm.some(Number.isFinite);
    const xs = havePunch ? m.punch_displacement_mm : this.timeAxis().values;
    const xAxis = havePunch ? axis("punch displacement", "mm") : this.timeAxis().title;
    // A frame whose peak region was not measured has no peak: a gap in the line and a mark on the axis, not a drop.
    const unmeasured = this.meta.coverage.peak_measured.map((v) => v === false);
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
    return this.peakFigure.react(traces, lineLayout({
      xAxis,
      yAxis: axis("peak deflection w", "mm"),
      y2Axis: haveForce ? axis("force", "kN") : null,
    }));
  }

  peakCSV() {
    const m = this.meta.frames;
    const measured = this.meta.coverage.peak_measured;
    return {
      columns: ["frame", "time_s", "punch_displacement_mm", "force_kN", "peak_w_mm", "peak_region_measured", "grid", "grid_step_mm"],
      rows: this.frames.map((frame, i) => [frame, m.time_s[i], m.punch_displacement_mm[i], m.force_kN[i], m.peak_w_mm[i], measured[i] ?? "", "result", this.meta.grid.step_mm]),
    };
  }

  /** Measured share of the plate per frame (left axis, %) and the area missing by reason (stacked bars, right). */
  drawCoverage() {
    const c = this.meta.coverage;
    const time = this.timeAxis();
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
      shapes: [verticalMarker(time.values[this.position])],
      note: known ? null : "This result was written before coverage was recorded",
    });
    figureLayout.barmode = "stack";
    return this.coverageFigure.react(traces, figureLayout);
  }

  coverageCSV() {
    const c = this.meta.coverage;
    const reasons = Object.keys(c.missing_mm2);
    return {
      columns: ["frame", "time_s", "measured_fraction", ...reasons.map((r) => `missing_${r}_mm2`), "n_order_conflicts", "n_temporal_jumps"],
      rows: this.frames.map((frame, i) => [frame, this.meta.frames.time_s[i], c.measured_fraction[i], ...reasons.map((r) => c.missing_mm2[r][i]), c.n_order_conflicts[i], c.n_temporal_jumps[i]]),
    };
  }

  async findOtherCameras() {
    this.label = await attempt("name the camera of this result", () => this.source.label());
    const others = await attempt("find the other cameras' topography", () => this.source.otherTopographies());
    if (!others || !this.context.current()) return;
    fill(this.compareSelect, h("option", { value: "" }, others.length ? "choose…" : "no other camera"),
      others.map((o) => h("option", { value: o.job.id }, o.label)));
    this.others = others;
    this.compareSection.hidden = false;
    if (others.length) {
      this.compareSelect.value = others[0].job.id;
      await this.loadComparison();
    } else {
      fill(this.compareSection, h("h2", {}, "Camera against camera"),
        h("p", { class: "empty" }, "No other camera of this experiment has a topography result yet."));
    }
  }

  async loadComparison() {
    const chosen = (this.others || []).find((o) => o.job.id === this.compareSelect.value);
    this.comparison = chosen
      ? { label: chosen.label, source: chosen.source, meta: await attempt("read the other camera's result", () => chosen.source.meta()) }
      : null;
    return this.drawComparison();
  }

  /** The other camera's frame nearest in time to this one's current frame (the same index without times). */
  otherFrame(other) {
    const t = this.meta.frames.time_s[this.position];
    const times = other.frames.time_s;
    if (!Number.isFinite(t) || !times.every(Number.isFinite)) return other.frames.index.includes(this.frame) ? this.frame : null;
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
  async drawComparison() {
    const other = this.comparison && this.comparison.meta ? this.comparison : null;
    const mine = this.label || "this camera";
    const styles = {
      mine: { color: COLORS[0], dash: "solid" },
      theirs: { color: COLORS[1], dash: "dash" },
      difference: { color: "#111111", dash: "dot", yaxis: "y2" },
    };
    const differenceAxis = axis("difference w (this − other)", "mm");
    const show = (series, differences, xAxis, yAxis, extra = {}) => {
      const traces = lineTraces(series);
      traces.forEach((trace, i) => {
        if (i === 1) trace.marker = { size: 7, symbol: "x" };
      });
      const finite = differences.filter(Number.isFinite);
      const rms = finite.length ? Math.sqrt(finite.reduce((a, d) => a + d * d, 0) / finite.length) : NaN;
      this.compareStats.textContent = other
        ? `Difference this − other: RMS ${num(rms, 3)} mm, largest ${num(finite.length ? Math.max(...finite.map(Math.abs)) : NaN, 3)} mm over ${finite.length} points where both measured.`
        : "Choose another camera to see the difference.";
      return this.compareFigure.react(traces, { ...lineLayout({ xAxis, yAxis, y2Axis: other ? differenceAxis : null, ...extra }), uirevision: this.compareWhat.value });
    };
    if (this.compareWhat.value === "map") return this.drawDifferenceMap(other);
    if (this.compareWhat.value === "profile" && !this.lines.length) {
      this.comparedSeries = null;
      this.compareStats.textContent = "";
      return this.compareFigure.react([], { ...lineLayout({ xAxis: axis("distance along the line", "mm"), yAxis: axis("deflection w", "mm"), note: "Draw a section line on the map first" }), uirevision: "profile" });
    }
    if (this.compareWhat.value === "profile" && this.lines.length) {
      const line = this.lines[0];
      const [ours] = await this.source.profiles([this.frame], line);
      const series = [{ name: `${mine}, frame ${this.frame}`, x: ours.s, y: ours.w, ...styles.mine }];
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
    const time = this.timeAxis();
    const series = [{ name: mine, x: time.values, y: this.meta.frames.peak_w_mm, mode: "lines+markers", ...styles.mine }];
    let differences = [];
    if (other) {
      const t = other.meta.frames.time_s;
      const byTime = time.key === "time" && t.every(Number.isFinite);
      const x = byTime ? t.map((v) => v * time.scale) : other.meta.frames.index;
      const y = other.meta.frames.peak_w_mm;
      series.push({ name: other.label, x, y, mode: "lines+markers", ...styles.theirs });
      // The other camera's peak at this camera's instants (linear in time; by frame number without times).
      differences = time.values.map((v, i) => this.meta.frames.peak_w_mm[i] - interpolate(x, y, v));
      series.push({ name: "difference (this − other)", x: time.values, y: differences, ...styles.difference });
    }
    this.comparedSeries = { columns: ["series", time.key === "time" ? `time_${time.unit}` : "frame", "peak_w_mm", "grid", "grid_step_mm"], series, grid: "result" };
    await show(series, differences, time.title, axis("peak deflection w", "mm"), { shapes: [verticalMarker(time.values[this.position])] });
    // Each peak is the largest w over that camera's own measured area: say so, since areas differ.
    if (other) this.compareStats.append(" Each peak is taken over that camera's own measured area; the difference map compares the same points.");
    return null;
  }

  /** This frame's field minus the other camera's (its frame nearest in time), on this field's nodes. */
  async drawDifferenceMap(other) {
    const frame = other ? this.otherFrame(other.meta) : null;
    if (!other || frame === null || !this.current) {
      this.compareStats.textContent = other ? `${other.label} has no frame at this instant.` : "Choose another camera to see the difference.";
      this.comparedSeries = null;
      return this.compareFigure.react([], { ...lineLayout({ xAxis: axis("x", "mm"), yAxis: axis("y", "mm"), note: this.compareStats.textContent }), uirevision: "map" });
    }
    const region = this.fullResolution ? this.zoomRegion() : null;
    const theirs = resampleField(await other.source.field(frame, region), this.current);
    const difference = { x: this.current.x, y: this.current.y, z: this.current.z.map((row, j) => row.map((w, i) => w - theirs.z[j][i])) };
    const range = fieldRange(difference);
    const reach = range ? Math.max(Math.abs(range[0]), Math.abs(range[1])) : 1;
    const values = difference.z.flatMap((row) => Array.from(row).filter(Number.isFinite));
    const rms = values.length ? Math.sqrt(values.reduce((a, d) => a + d * d, 0) / values.length) : NaN;
    this.compareStats.textContent = `Difference map this − ${other.label} (frame ${this.frame} − frame ${frame}): RMS ${num(rms, 3)} mm, largest ${num(reach, 3)} mm over ${values.length} nodes where both measured; the other field is interpolated (bilinear) at this field's nodes.`;
    this.comparedSeries = { map: { difference, theirs, frame, grid: this.gridOf(this.current) } };
    const traces = mapTraces(difference, { range: [-reach, reach], valueName: "Δw", rangeNote: " this − other" });
    return this.compareFigure.react(traces, { ...mapLayout({ uirevision: "map" }), dragmode: "zoom" });
  }

  compareCSV() {
    const compared = this.comparedSeries;
    if (compared && compared.map) {
      const { difference, theirs, frame, grid } = compared.map;
      const rows = [];
      difference.z.forEach((row, j) => row.forEach((d, i) => rows.push([this.frame, frame, difference.x[i], difference.y[j], this.current.z[j][i], theirs.z[j][i], d, grid.grid, grid.step_mm])));
      return {
        filename: `topography-${this.job.id.slice(0, 8)}-difference-frame${this.frame}-${grid.name}`,
        columns: ["frame", "other_frame", "x_mm", "y_mm", "w_mm", "other_w_mm", "difference_w_mm", "grid", "grid_step_mm"],
        rows,
      };
    }
    const { columns, series } = compared || { columns: ["series", "x", "y", "grid", "grid_step_mm"], series: [] };
    const rows = [];
    for (const one of series) one.x.forEach((x, i) => rows.push([one.name, x, one.y[i], "result", this.meta.grid.step_mm]));
    return { columns, rows };
  }

}
