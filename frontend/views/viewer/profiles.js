// The viewer's section profiles: w along every section line, for the current frame and the pinned ones (one dash
// per frame, one colour per line), sampled by the server on the full-resolution result grid, each with its ±2σ_w
// band (shaded in the line's colour; a gap where σ is unknown).
import { Figure, axis, lineLayout, lineTraces, sigmaBandTrace, translucent } from "../../plots.js";
import { field, h, showError } from "../../ui.js";
import { timeLabel } from "./shared.js";

const DASHES = ["solid", "dash", "dot", "dashdot", "longdash", "longdashdot"];

export class ProfilesPanel {
  constructor(viewer) {
    this.viewer = viewer;
    this.figure = new Figure({ name: "Section profiles", filename: `topography-${viewer.job.id.slice(0, 8)}-profiles`, height: 360, csv: () => this.csv() });
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
          viewer.addLine({ x0, y0, x1, y1 });
        },
      },
      lineInputs.map((f) => f.wrap),
      h("button", { type: "submit", class: "small" }, "Add line"),
    );
  }

  /** Profiles of every line for the current frame and the pinned ones: [{ line, frame, profile }], one request
   * per line (the server samples the full-resolution grid). */
  async profiles() {
    const viewer = this.viewer;
    const frames = [viewer.frame, ...[...viewer.pinned].filter((f) => f !== viewer.frame).sort((a, b) => a - b)];
    const perLine = await Promise.all(viewer.lines.map((line) => viewer.source.profiles(frames, line)));
    return viewer.lines.flatMap((line, i) => perLine[i].map((profile) => ({ line, frame: profile.frame, profile })));
  }

  async draw(profiles = null) {
    const meta = this.viewer.meta;
    this.shownProfiles = profiles || (await this.profiles());
    const frames = [...new Set(this.shownProfiles.map((p) => p.frame))];
    const series = this.shownProfiles.map(({ line, frame, profile }) => ({
      name: `${line.label}, ${timeLabel(meta, frame)}`,
      x: profile.s,
      y: profile.w,
      color: line.color,
      dash: DASHES[frames.indexOf(frame) % DASHES.length],
    }));
    const bands = this.shownProfiles.map(({ profile }, i) => sigmaBandTrace(profile.s, profile.w, profile.sigma, { name: `${series[i].name} ±2σ_w`, color: translucent(series[i].color, 0.18) }));
    return this.figure.react([...bands, ...lineTraces(series)], lineLayout({
      note: series.length ? null : "Drag on the map to draw a section line",
      xAxis: axis("distance along the line", "mm"),
      yAxis: axis("deflection w", "mm", { range: meta.w_range_mm }),
    }));
  }

  csv() {
    const rows = [];
    for (const { line, frame, profile } of this.shownProfiles || []) {
      for (let i = 0; i < profile.s.length; i += 1) rows.push([line.label, frame, profile.s[i], profile.x[i], profile.y[i], profile.w[i], profile.sigma[i]]);
    }
    // Profiles are sampled (bilinear) from the result grid on the server, whatever the map shows.
    const step = this.viewer.meta.grid.step_mm;
    return { columns: ["line", "frame", "s_mm", "x_mm", "y_mm", "w_mm", "sigma_w_mm", "grid", "grid_step_mm"], rows: rows.map((r) => [...r, "result", step]) };
  }
}
