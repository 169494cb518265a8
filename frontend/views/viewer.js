// The topography viewer of a topography job: the deflection field of a frame as a 2-D map and a 3-D surface,
// a frame slider with play/pause, section lines drawn on the map with their profiles for the chosen frames,
// time histories of clicked points, peak deflection against punch displacement (force on a second axis), what of
// the plate each frame measured and why the rest is missing (outlined on the map too), and one camera against
// another. Every plot downloads its data (CSV) and its image (PNG).
//
// This module is the orchestration: the frame player, the field cache, the section lines, points and pinned
// frames that several panels show, and the page's layout. Each panel is its own module in views/viewer/ (map,
// surface, profiles, histories, peak, coverage, cameras) and reads the shared state from the viewer it is given.
import { getJSON } from "../api.js";
import { MARK_COLORS } from "../plots.js";
import { fieldRange, fieldRows, listenToMap } from "../plot_fields.js";
import { attempt, field, fill, h, latestOnly, num, page, say, showError } from "../ui.js";
import { TopographySource } from "./topography-source.js";
import { exportPanel } from "./exports.js";
import { explained } from "./calibration.js";
import { jobName } from "./job-helpers.js";
import { CamerasPanel } from "./viewer/cameras.js";
import { CoveragePanel } from "./viewer/coverage.js";
import { HistoriesPanel } from "./viewer/histories.js";
import { MapPanel } from "./viewer/map.js";
import { PeakPanel } from "./viewer/peak.js";
import { ProfilesPanel } from "./viewer/profiles.js";
import { gridOf, timeLabel } from "./viewer/shared.js";
import { SurfacePanel } from "./viewer/surface.js";

const LINE_LABELS = "ABCDEFGHIJKLMNOPQRSTUVWXYZ";
const FRAME_CACHE = 64; // fields kept in memory for quick back-and-forth (each ≤ 250 × 250 float32 = 250 kB)
const SPEEDS = [2, 5, 10, 25];

/** Diagnostics for the browser tests and curious users (devtools): the viewer shown, and how long each frame
 * switch took (fetch, decode and Plotly.react of the field and the profiles), in ms. */
window.fringelab = { frameSwitchMs: [], viewer: null };

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
  page(container, viewerTitle(job), viewer.element);
  context.onLeave(() => {
    viewer.dispose();
    window.fringelab.viewer = null;
  });
  await viewer.start();
}

/** "Topography of camera left, recording 12": what was measured, not only the job's id. */
export function viewerTitle(job) {
  const recording = job.spec.recording_id ? `recording ${job.spec.recording_id}` : null;
  const what = [job.camera_name ? `camera ${job.camera_name}` : null, recording].filter(Boolean).join(", ");
  return what ? `Topography of ${what}` : `Topography: ${jobName(job)}`;
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
    this.mapPanel = new MapPanel(this);
    this.surfacePanel = new SurfacePanel(this);
    this.surfacePanel.figure.element.hidden = true;
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
    this.mapPanel.figure.element.id = "field-map";
    this.surfacePanel.figure.element.id = "field-surface";
    this.mapPanel.figure.element.setAttribute("role", "tabpanel");
    this.surfacePanel.figure.element.setAttribute("role", "tabpanel");
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

    // Profiles, histories, peak against punch displacement and force, coverage; camera against camera.
    this.profilePanel = new ProfilesPanel(this);
    this.historyPanel = new HistoriesPanel(this);
    this.peakPanel = new PeakPanel(this);
    this.coveragePanel = new CoveragePanel(this);
    this.cameraPanel = new CamerasPanel(this);

    this.exports = exportPanel(this.job, { frames: this.frames, lines: () => this.lines, context: this.context });
    const m = this.meta;
    this.element = h(
      "div",
      { class: "viewer" },
      h("p", { class: "facts" },
        h("a", { href: `#/jobs/${this.job.id}` }, jobName(this.job)), " · ",
        this.job.experiment_id ? [h("a", { href: `#/experiments/${this.job.experiment_id}` }, `experiment ${this.job.experiment_name || this.job.experiment_id}`), " · "] : null,
        `${this.frames.length} frames · grid ${m.grid.nx} × ${m.grid.ny} nodes, ${num(m.grid.step_mm, 2)} mm apart · `,
        `peak deflection up to ${num(m.w_range_mm[1], 2)} mm · `,
        explained("how w is measured and what is left unmeasured", "6-topography-and-results")),
      m.warnings.length ? h("ul", { class: "warnings result-warnings", "aria-label": "Warnings about this result" }, m.warnings.map((w) => h("li", {}, `⚠ ${w}`))) : null,
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
          this.mapPanel.figure.element,
          this.surfacePanel.figure.element,
          h("p", { class: "hint" }, "Drag on the map to draw a section line; click a point to add its time history.")),
        h("div", {},
          this.profilePanel.figure.element,
          h("div", { class: "chip-row" }, h("span", {}, "Lines: "), this.profilePanel.lineList),
          h("div", { class: "chip-row" }, h("span", {}, "Profiles of: the current frame, and "),
            this.profilePanel.pinList,
            h("button", { type: "button", class: "small", onclick: () => this.pinFrame() }, "Pin this frame")),
          h("details", {}, h("summary", {}, "Type a section line"), this.profilePanel.lineForm))),
      h("div", { class: "plot-grid" },
        h("div", {}, this.historyPanel.figure.element, h("div", { class: "chip-row" }, h("span", {}, "Points: "), this.historyPanel.pointList),
          h("details", {}, h("summary", {}, "Type a point"), this.historyPanel.pointForm)),
        h("div", {}, this.peakPanel.figure.element)),
      h("div", { class: "plot-grid" },
        h("div", {}, this.coveragePanel.figure.element,
          h("p", { class: "hint" }, "Share of the plate (as the first frame sees it) measured in each frame, and the area missing by reason (bars; hover for what each covers); missing regions are outlined on the map."))),
      this.cameraPanel.element,
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
    if (!this.context.current() || !this.mapPanel.figure.drawn) return;
    // Plotly adds its event methods to the plot once it has drawn it.
    listenToMap(this.mapPanel.figure, { onLine: (line) => this.addLine(line), onPoint: (point) => this.addPoint(point) });
    this.mapPanel.figure.plot.on("plotly_relayout", (update) => {
      const zoomed = Object.keys(update).some((key) => key.startsWith("xaxis.") || key.startsWith("yaxis."));
      if (zoomed && this.fullResolution) this.redraw(); // fetch the new window at full resolution
      else if (zoomed && this.viewRangeBox.checked) this.drawField(); // the colours follow the zoom
    });
    await this.peakPanel.draw();
    await this.coveragePanel.draw();
    this.cameraPanel.findOtherCameras();
  }

  dispose() {
    this.playing = false;
    clearTimeout(this.timer);
    const panels = [this.mapPanel, this.surfacePanel, this.profilePanel, this.historyPanel, this.peakPanel, this.coveragePanel, this.cameraPanel];
    for (const panel of panels) panel.figure.purge();
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
    return this.mapPanel.zoomRegion();
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
      const [current, profiles] = await Promise.all([this.field(frame), this.profilePanel.profiles()]);
      if (!this.context.current()) return;
      this.current = current;
      await Promise.all([this.drawField(), this.profilePanel.draw(profiles)]);
      window.fringelab.frameSwitchMs.push(performance.now() - started);
      await Promise.all([
        this.historyPanel.draw(),
        this.peakPanel.figure.drawn ? this.peakPanel.draw() : null,
        this.coveragePanel.figure.drawn ? this.coveragePanel.draw() : null,
        this.cameraPanel.figure.drawn ? this.cameraPanel.draw() : null,
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
    this.mapPanel.figure.element.hidden = view !== "map";
    this.surfacePanel.figure.element.hidden = view !== "surface";
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
    const panel = this.fieldView === "surface" ? this.surfacePanel : this.mapPanel;
    return panel.draw({ range, rangeNote });
  }

  fieldCSV() {
    const grid = gridOf(this.meta, this.current);
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
    return Promise.all([this.drawField(), this.profilePanel.draw(), this.cameraPanel.figure.drawn ? this.cameraPanel.draw() : null]);
  }

  removeLine(label) {
    this.lines = this.lines.filter((line) => line.label !== label);
    this.drawChips();
    return Promise.all([this.drawField(), this.profilePanel.draw()]);
  }

  pinFrame() {
    this.pinned.add(this.frame);
    this.drawChips();
    return this.profilePanel.draw();
  }

  drawChips() {
    if (this.exports) this.exports.describe();
    const chip = (text, color, remove, name) =>
      h("li", {}, h("span", { class: "swatch", style: `background:${color}` }), text,
        h("button", { type: "button", class: "link", "aria-label": `Remove ${name}`, onclick: remove }, "×"));
    fill(this.profilePanel.lineList, this.lines.length ? this.lines.map((line) => chip(line.label, line.color, () => this.removeLine(line.label), `line ${line.label}`)) : h("li", { class: "empty" }, "none yet"));
    fill(this.profilePanel.pinList, [...this.pinned].sort((a, b) => a - b).map((frame) => chip(`frame ${frame}`, "#888", () => {
      this.pinned.delete(frame);
      this.drawChips();
      this.profilePanel.draw();
    }, `pinned frame ${frame}`)));
    fill(this.historyPanel.pointList, this.points.length ? this.points.map((point) => chip(point.label, point.color, () => this.removePoint(point.label), `point ${point.label}`)) : h("li", { class: "empty" }, "none yet"));
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
    await Promise.all([this.drawField(), this.historyPanel.draw()]);
  }

  removePoint(label) {
    this.points = this.points.filter((p) => p.label !== label);
    this.drawChips();
    return Promise.all([this.drawField(), this.historyPanel.draw()]);
  }
}
