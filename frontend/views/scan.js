// The scan view of a scan job (docs/procam.md §3): its points in 3-D (camera frame, mm) coloured by z or by σ, and
// the decoding's QA: the share of pixels decoded and why the others were not, the code map, the shading and the
// map of reasons. The points are an even sample the API sends (stripe-edge points first); every plot downloads
// its data (CSV) and its image (PNG).
import { getJSON } from "../api.js";
import { Figure, axis, layout } from "../plots.js";
import { attempt, field, h, num, page } from "../ui.js";
import { jobName } from "./job-helpers.js";

const SOURCES = ["stripe edge", "phase", "per-pixel code"];
const REASONS = ["decoded", "a bit not clear", "shading too low", "beyond the projector"];

/** Diagnostics for the browser tests: the scan view shown. */
window.fringelab = window.fringelab || {};

export async function renderScan(container, { id }, context) {
  const job = await attempt("open the job", () => getJSON(`jobs/${id}`));
  if (!job || !context.current()) return;
  if (job.kind !== "scan" || job.state !== "succeeded") {
    page(container, "Scan", h("p", {}, h("a", { href: `#/jobs/${job.id}` }, jobName(job)),
      job.kind !== "scan" ? " is not a scan job." : ` is ${job.state}; its points show when it has succeeded.`));
    return;
  }
  const scan = await attempt("read the scan", () => getJSON(`jobs/${id}/scan`));
  if (!scan || !context.current()) return;
  const view = new ScanView(job, scan);
  window.fringelab.scan = view;
  page(container, `Scan: ${jobName(job)}`, view.element);
  context.onLeave(() => {
    window.fringelab.scan = null;
  });
  await view.draw();
}

const percent = (share) => `${(100 * share).toFixed(1)} %`;

class ScanView {
  constructor(job, scan) {
    this.job = job;
    this.scan = scan;
    this.colour = h("select", { onchange: () => this.drawPoints() },
      h("option", { value: "z" }, "z (camera frame)"), h("option", { value: "sigma" }, "σ along the ray"));
    const points = scan.points;
    this.pointsFigure = new Figure({
      name: "Scan points (camera frame)",
      filename: `scan-${job.id.slice(0, 8)}-points`,
      height: 520,
      csv: () => ({
        columns: ["x_mm", "y_mm", "z_mm", "sigma_mm", "source"],
        rows: points.z_mm.map((_, i) => [points.x_mm[i], points.y_mm[i], points.z_mm[i], points.sigma_mm[i], SOURCES[points.source[i]]]),
      }),
    });
    this.codeFigure = this.mapFigure("Decoded code", "code", "code value");
    this.shadingFigure = this.mapFigure("Shading (white − black)", "shading_grey", "grey");
    this.reasonFigure = this.mapFigure("Why pixels have no code", "reason", "reason");
    this.element = h("div", { class: "scan-view" }, this.summary(), field("Colour by", this.colour).wrap, this.pointsFigure.element,
      h("div", { class: "plots-row" }, this.codeFigure.element, this.shadingFigure.element, this.reasonFigure.element));
  }

  summary() {
    const qa = this.scan.qa;
    const bySource = qa.points_by_source || {};
    const shares = qa.share_by_reason || {};
    const rows = [
      ["Pixels decoded", percent(qa.valid_share)],
      ...REASONS.slice(1).map((reason) => [`No code: ${reason}`, percent(shares[reason] || 0)]),
      ["Points", `${qa.n_points} (${SOURCES.map((s) => `${bySource[s] || 0} ${s}`).join(", ")})`],
      ...SOURCES.filter((s) => (qa.median_sigma_mm_by_source || {})[s] != null)
        .map((s) => [`Median σ, ${s}`, `${num(qa.median_sigma_mm_by_source[s], 4)} mm`]),
      ["Stripe-edge points left out", `${qa.n_rejected_edge_points} (their two sides did not name neighbouring codes, or an occlusion was near)`],
    ];
    if (!qa.calibration_sigma) rows.push(["Calibration in σ", `no: ${qa.calibration_sigma_note}`]);
    return h("dl", { class: "summary", "aria-label": "Decoding quality" }, rows.flatMap(([term, value]) => [h("dt", {}, term), h("dd", {}, value)]));
  }

  mapFigure(name, key, valueName) {
    const map = this.scan[key];
    return new Figure({
      name,
      filename: `scan-${this.job.id.slice(0, 8)}-${key}`,
      height: 300,
      csv: () => ({
        columns: ["u_px", "v_px", valueName.replace(/ /g, "_")],
        rows: map.values.flatMap((row, j) => row.map((value, i) => [i * map.step_px, j * map.step_px, value])),
        filename: `scan-${this.job.id.slice(0, 8)}-${key}-every-${map.step_px}-px`,
      }),
    });
  }

  async draw() {
    await this.drawPoints();
    const maps = [
      [this.codeFigure, this.scan.code, "Viridis", "code value", "1"],
      [this.shadingFigure, this.scan.shading_grey, "Greys", "shading", "grey"],
      [this.reasonFigure, this.scan.reason, [[0, "#2ca02c"], [0.33, "#ff7f0e"], [0.66, "#555555"], [1, "#d62728"]], "reason (0 decoded, 1 bit not clear, 2 shading low, 3 beyond)", "1"],
    ];
    for (const [figure, map, colorscale, title, unit] of maps) {
      const u = map.values[0].map((_, i) => i * map.step_px);
      const v = map.values.map((_, j) => j * map.step_px);
      await figure.react(
        [{ type: "heatmap", x: u, y: v, z: map.values, colorscale, colorbar: { title: { text: `${title} (${unit})` } },
           hovertemplate: `u %{x} px<br>v %{y} px<br>%{z}<extra></extra>` }],
        layout({ xaxis: axis("u", "px"), yaxis: axis("v", "px", { autorange: "reversed", scaleanchor: "x" }) }),
      );
    }
  }

  async drawPoints() {
    const points = this.scan.points;
    const bySigma = this.colour.value === "sigma";
    const color = bySigma ? points.sigma_mm : points.z_mm;
    await this.pointsFigure.react(
      [{
        type: "scatter3d", mode: "markers", x: points.x_mm, y: points.y_mm, z: points.z_mm,
        marker: { size: 1.5, color, colorscale: bySigma ? "YlOrRd" : "Viridis", cmin: bySigma ? 0 : undefined,
                  cmax: bySigma ? quantile(points.sigma_mm, 0.95) : undefined,
                  colorbar: { title: { text: bySigma ? "σ (mm)" : "z (mm)" } } },
        hovertemplate: "x %{x:.2f} mm<br>y %{y:.2f} mm<br>z %{z:.3f} mm<extra></extra>",
      }],
      layout({
        margin: { l: 0, r: 0, t: 10, b: 0 },
        scene: { xaxis: axis("x", "mm"), yaxis: axis("y", "mm", { autorange: "reversed" }), zaxis: axis("z", "mm", { autorange: "reversed" }),
                 aspectmode: "data", camera: { eye: { x: 0.2, y: -0.4, z: -2.0 }, up: { x: 0, y: -1, z: 0 } } },
      }),
    );
    this.colouredBy = bySigma ? "sigma" : "z";
  }
}

function quantile(values, q) {
  const finite = values.filter((v) => v !== null && Number.isFinite(v)).sort((a, b) => a - b);
  return finite.length ? finite[Math.min(finite.length - 1, Math.floor(q * finite.length))] : 1;
}
