// The calibration report of a calibration job. Camera: the verdict with its reasons, the parameters with
// ± standard errors and units, per-frame RMS bars and the residual vectors drawn over the image area, from
// GET /calibrations/{id}/report (the fields of the camera-calibration document, units in every name).
// Projector: the verdict with its thresholds, the look-up table's curves, and maps over the whole image of its
// sensitivity, the Z resolution that gives at the measured edge noise, and its coverage (over the image and Z),
// from GET /calibrations/{id}/projector-report. Every check and quantity links to the section of docs/method.md
// that explains it (the help pages).
import { getJSON } from "../api.js";
import { Figure, axis, barTraces, imageLayout, layout, vectorTraces } from "../plots.js";
import { attempt, field, h, num, page, showError, table } from "../ui.js";
import { describeInput, jobName } from "./job-helpers.js";
import { procamReport } from "./procam-report.js";

const PARAMETER_NAMES = {
  su: "scale factor s_u", // on v when the calibration scaled on v: see parameterName
  f_mm: "focal length f",
  u0_px: "principal point u₀",
  v0_px: "principal point v₀",
  k1_per_mm2: "radial distortion k₁",
  k2_per_mm4: "radial distortion k₂",
  p1_per_mm: "tangential distortion p₁",
  p2_per_mm: "tangential distortion p₂",
  x0_mm: "plate origin in camera coordinates x₀",
  y0_mm: "plate origin in camera coordinates y₀",
  z0_mm: "plate origin in camera coordinates z₀",
  omega_deg: "rotation ω",
  phi_deg: "rotation φ",
  kappa_deg: "rotation κ",
};
const FRAME_COLORS = { used: "#1f77b4", rejected: "#d62728", skipped: "#9aa4b1" };

/** A link to where docs/method.md explains `term` (its section, and the term found and marked there). */
export function explained(text, section, term = null) {
  const search = new URLSearchParams({ section });
  if (term) search.set("find", term);
  return h("a", { href: `#/help/method?${search}`, class: "explained", title: "What this means (method documentation)" }, text);
}

/** A value and its standard error with digits that suit the error: 12.3456 ± 0.0012. */
export function plusMinus(value, error) {
  if (value === null || value === undefined) return "–";
  if (error === null || error === undefined || !Number.isFinite(error) || error <= 0) return num(value, 6);
  const digits = Math.min(10, Math.max(0, 1 - Math.floor(Math.log10(error))));
  const small = Math.abs(value) < 1e-3 && value !== 0;
  if (small) return `${value.toExponential(2)} ± ${error.toExponential(1)}`;
  return `${value.toFixed(digits)} ± ${error.toFixed(digits)}`;
}

/** What a calibration was built on and whether it may be used without consent (CalibrationOut: camera_calibration_id,
 * bad, bad_reason): a projector calibration built on a bad camera calibration is bad too, whatever its own verdict. */
function standingNote(calibration) {
  const parts = [];
  if (calibration.camera_calibration_id) {
    parts.push(h("p", {}, "Built on camera calibration #", String(calibration.camera_calibration_id), "."));
  }
  if (calibration.bad) {
    parts.push(h("p", { class: "calibration-bad", role: "note" },
      `⚠ Bad: ${calibration.bad_reason || "its verdict is bad"}. A job uses it only with the person's explicit consent, and its results carry the warning.`));
  }
  return parts;
}

/** A check that holds or does not (the solver converged): shown as yes/no, not as 1.000 (older reports have no
 * unit for it). */
const yesNo = (check) => check.unit === "yes/no" || (check.name === "solver" && !check.unit);

function verdictBox(verdict, section) {
  return h(
    "section",
    { class: `card verdict verdict-${verdict.level}`, "aria-label": "Verdict" },
    h("h2", {}, `Verdict: ${verdict.level}`),
    h("ul", {}, verdict.reasons.map((reason) => h("li", {}, reason))),
    table(
      "Verdict checks",
      [
        { title: "Check", value: (c) => explained(c.name, section, c.name) },
        { title: "Value", value: (c) => (yesNo(c) ? (c.value >= c.good_limit ? "yes" : "no") : `${num(c.value, 3)} ${c.unit}`), class: "num" },
        { title: "Good if", value: (c) => (yesNo(c) ? "yes" : `${c.higher_is_better ? "≥" : "≤"} ${c.good_limit} ${c.unit}`), class: "num" },
        { title: "Bad if", value: (c) => (yesNo(c) ? "no" : `${c.higher_is_better ? "<" : ">"} ${c.bad_limit} ${c.unit}`), class: "num" },
        { title: "Level", value: (c) => h("span", { class: `level-${c.level}` }, c.level) },
        { title: "Meaning", value: (c) => c.message },
      ],
      verdict.checks,
    ),
  );
}

/** A camera parameter's name for people; the scale factor names the axis it scales (the spec's scale_on). */
export function parameterName(name, sensor) {
  if (name === "su" && sensor && sensor.scale_on === "v") return "scale factor s_v";
  return PARAMETER_NAMES[name] || name;
}

function parametersTable(document) {
  const rows = Object.entries(document.parameters).map(([name, p]) => ({ name, ...p }));
  return table(
    "Camera parameters",
    [
      { title: "Parameter", value: (p) => explained(parameterName(p.name, document.sensor), "3-camera-model") },
      { title: "Value ± standard error", value: (p) => plusMinus(p.value, p.standard_error), class: "num" },
      { title: "Unit", value: (p) => (p.unit === "1" ? "–" : p.unit.replace(/\^-(\d)/, (_, d) => `⁻${"⁰¹²³⁴⁵⁶⁷⁸⁹"[d]}`)) },
    ],
    rows,
  );
}

/** The pose read both ways, each named for what it is (older files lack it: say so). */
function poseFacts(document) {
  const xyz = (v) => `(${v.map((c) => num(c, 1)).join(", ")}) mm`;
  if (!document.pose) {
    return [["Camera centre in plate coordinates", "not in this calibration file (made before it was added); run the calibration again to see it"]];
  }
  return [
    [explained("Plate origin in camera coordinates", "2-conventions"), `${xyz(document.pose.object_origin_in_camera_mm)}: x₀, y₀, z₀ above, where the plate's origin lies seen from the camera`],
    [explained("Camera centre in plate coordinates", "2-conventions"), `${xyz(document.pose.camera_centre_in_object_mm)}: where the camera's projection centre is, in the plate's X, Y, Z`],
  ];
}

function summary(document, job) {
  const size = document.image_size_px;
  const sensor = document.sensor;
  return h(
    "dl",
    { class: "facts" },
    [
      ["Input", describeInput(job)],
      ["Mode", document.mode === "zstack" ? "board moved along Z (Z-stack)" : "free board poses"],
      ["Image", `${size.width} × ${size.height} px`],
      ["Sensor", `D_u ${num(sensor.du_px_per_mm, 3)} px/mm, D_v ${num(sensor.dv_px_per_mm, 3)} px/mm${sensor.scale_on ? `, scale factor on ${sensor.scale_on}` : ""}`],
      ["RMS reprojection error", `${num(document.rms_px, 4)} px over ${document.n_points} corners`],
      ["Residual standard deviation", `${num(document.residual_std_px, 4)} px per coordinate`],
      ["Systematic residual", `${num(document.residual_map.systematic_px, 4)} px (image coverage ${num(100 * document.residual_map.coverage, 0)} %)`],
      ["Converged", document.converged ? "yes" : "NO"],
      ...poseFacts(document),
    ].map(([term, value]) => [h("dt", {}, term), h("dd", {}, value)]),
  );
}

/** Per-frame RMS bars, coloured by what the solver did with the frame. */
function frameFigure(document, name) {
  const frames = document.frames;
  const figure = new Figure({
    name: "Per-frame RMS",
    filename: `${name}-frame-rms`,
    height: 320,
    csv: () => ({
      columns: ["frame", "status", "z_mm", "n_corners", "rms_px", "max_px", "reason"],
      rows: frames.map((f) => [f.frame, f.status, f.z_mm, f.n_corners, f.rms_px, f.max_px, f.reason]),
    }),
  });
  const traces = Object.keys(FRAME_COLORS)
    .map((status) => {
      const chosen = frames.filter((f) => f.status === status);
      if (!chosen.length) return null;
      return {
        ...barTraces({ x: chosen.map((f) => f.frame), y: chosen.map((f) => f.rms_px ?? 0), name: status, color: FRAME_COLORS[status] })[0],
        customdata: chosen.map((f) => [f.z_mm ?? "", f.reason || ""]),
        hovertemplate: "%{x}<br>RMS %{y:.3f} px<br>Z %{customdata[0]} mm<br>%{customdata[1]}<extra></extra>",
      };
    })
    .filter(Boolean);
  const draw = () =>
    figure.react(traces, {
      ...layout({ xaxis: { ...axis("frame", "file name"), type: "category" }, yaxis: axis("RMS reprojection error", "px"), barmode: "group" }),
    });
  return { figure, draw };
}

/** Residual vectors over the image area, magnified by a chosen factor. */
function residualFigure(document, name) {
  const r = document.residuals;
  const size = document.image_size_px;
  const lengths = r.du_px.map((du, i) => Math.hypot(du, r.dv_px[i])).sort((a, b) => a - b);
  const median = lengths.length ? lengths[Math.floor(lengths.length / 2)] : 0;
  // Magnify so that a median residual is drawn about 1 % of the image width long.
  const auto = median > 0 ? Math.max(1, Math.round((0.01 * size.width) / median)) : 100;
  const scale = field("Residual magnification (×)", h("input", { type: "number", min: 1, step: 1, value: auto }));
  const figure = new Figure({
    name: "Residual vectors over the image",
    filename: `${name}-residuals`,
    height: 520,
    csv: () => ({
      columns: ["frame_index", "x_mm", "y_mm", "z_mm", "u_px", "v_px", "du_px", "dv_px"],
      rows: r.u_px.map((u, i) => [r.frame_index[i], r.x_mm[i], r.y_mm[i], r.z_mm[i], u, r.v_px[i], r.du_px[i], r.dv_px[i]]),
    }),
  });
  const draw = () =>
    figure.react(
      vectorTraces({ u: r.u_px, v: r.v_px, du: r.du_px, dv: r.dv_px, scale: Number(scale.input.value) || auto }),
      imageLayout({ widthPx: size.width, heightPx: size.height }),
    );
  scale.input.addEventListener("change", draw);
  return { figure, draw, control: scale.wrap };
}

async function cameraReport(container, job, context) {
  const calibrationId = job.result && job.result.calibration_id;
  if (!calibrationId) {
    showError(`${jobName(job)} names no calibration in its result`, "show the calibration report");
    return;
  }
  const answer = await attempt("read the calibration report", () => getJSON(`calibrations/${calibrationId}/report`));
  if (!answer || !context.current()) return;
  const { calibration, report: document } = answer;
  const file = { url: calibration.file_url, name: `camera-calibration-${calibration.id}.json` };
  const name = `camera-calibration-${job.id.slice(0, 8)}`;
  const frames = frameFigure(document, name);
  const residuals = residualFigure(document, name);
  page(
    container,
    `Camera calibration ${calibration.id} (version ${calibration.version})`,
    h("p", {}, h("a", { href: `#/jobs/${job.id}` }, jobName(job)), " · ", h("a", { href: file.url, download: file.name }, `Download ${file.name}`)),
    standingNote(calibration),
    verdictBox(document.verdict, "3-1-calibration"),
    h(
      "div",
      { class: "two-columns" },
      h("section", { "aria-labelledby": "params-title" }, h("h2", { id: "params-title" }, "Parameters"), parametersTable(document)),
      h("section", { "aria-labelledby": "summary-title" }, h("h2", { id: "summary-title" }, "Summary"), summary(document, job)),
    ),
    frames.figure.element,
    h("div", { class: "plot-controls" }, residuals.control),
    residuals.figure.element,
  );
  context.onLeave(() => {
    frames.figure.purge();
    residuals.figure.purge();
  });
  await frames.draw();
  await residuals.draw();
}

export async function renderCalibration(container, { id }, context) {
  const job = await attempt("open the job", () => getJSON(`jobs/${id}`));
  if (!job || !context.current()) return;
  if (job.state !== "succeeded") {
    page(container, "Calibration report", h("p", {}, h("a", { href: `#/jobs/${job.id}` }, jobName(job)), ` is ${job.state}; its report comes when it has succeeded.`));
    return;
  }
  if (job.kind === "camera_calibration") return cameraReport(container, job, context);
  if (job.kind === "projector_calibration") return projectorReport(container, job, context);
  if (job.kind === "procam_calibration") return procamReport(container, job, context);
  page(container, "Calibration report", h("p", {}, `${jobName(job)} is not a calibration.`));
}

const CURVES = 24; // edges drawn on the curves plot

/** Least-squares slope of t against z over the finite samples (px/mm), or NaN with fewer than 2. */
function slope(z, t) {
  const pairs = z.map((zi, i) => [zi, t[i]]).filter(([zi, ti]) => Number.isFinite(zi) && Number.isFinite(ti));
  if (pairs.length < 2) return NaN;
  const mz = pairs.reduce((a, p) => a + p[0], 0) / pairs.length;
  const mt = pairs.reduce((a, p) => a + p[1], 0) / pairs.length;
  const szz = pairs.reduce((a, p) => a + (p[0] - mz) ** 2, 0);
  return szz > 0 ? pairs.reduce((a, p) => a + (p[0] - mz) * (p[1] - mt), 0) / szz : NaN;
}

const numbersOf = (values) => values.map((v) => (v === null ? NaN : v));

/** The edge's position at the reference height, px: from its nearest sample there, carried along its slope
 * when the edge was not seen at that height (NaN when it was seen at fewer than two heights). */
function tAtReference(lut, curve) {
  const z = numbersOf(lut.z_mm);
  const t = numbersOf(curve.t_px);
  const seen = z.map((_, j) => j).filter((j) => Number.isFinite(t[j]));
  if (!seen.length) return NaN;
  const near = seen.reduce((best, j) => (Math.abs(z[j] - lut.reference_z_mm) < Math.abs(z[best] - lut.reference_z_mm) ? j : best));
  const offset = lut.reference_z_mm - z[near];
  return offset === 0 ? t[near] : t[near] + slope(z, t) * offset;
}

/** The projector calibration: its settings and QA, the table's curves along a scan line, and its sensitivity. */
async function projectorReport(container, job, context) {
  const calibrationId = job.result && job.result.calibration_id;
  if (!calibrationId) {
    showError(`${jobName(job)} names no calibration in its result`, "show the calibration report");
    return;
  }
  const first = await attempt("read the projector table", () => getJSON(`calibrations/${calibrationId}/table`));
  if (!first || !context.current()) return;
  const calibration = first.calibration;
  const name = `projector-calibration-${calibration.id}`;
  const lineInput = field("Scan line", h("input", { type: "number", min: 0, max: first.n_lines - 1, step: 1, value: first.line }),
    `0 … ${first.n_lines - 1}; scan lines are image ${first.axis === "rows" ? "rows" : "columns"}`);
  let lut = first;
  const curves = new Figure({
    name: "Look-up table curves",
    filename: `${name}-curves`,
    height: 420,
    csv: () => ({
      columns: ["line", "edge", "z_mm", "t_px"],
      rows: lut.curves.flatMap((c) => lut.z_mm.map((z, j) => [lut.line, c.edge, z, c.t_px[j]])),
    }),
  });
  // Every edge's curve t(Z) drawn as its shift from the reference height, for about CURVES edges spread over
  // the line: the slopes (the sensitivity) and any bend read at a glance; the CSV has every edge.
  const drawCurves = () => {
    const every = Math.max(1, Math.ceil(lut.curves.length / CURVES));
    const shown = lut.curves.filter((_, i) => i % every === 0);
    return curves.react(
      shown.map((c, i) => {
        const reference = tAtReference(lut, c);
        return {
          type: "scatter",
          mode: "lines",
          x: numbersOf(lut.z_mm),
          y: numbersOf(c.t_px).map((t) => t - reference),
          name: `edge ${c.edge}`,
          line: { width: 1.5, color: `hsl(${Math.round((260 * i) / Math.max(1, shown.length - 1))}, 70%, 45%)` },
          hovertemplate: `edge ${c.edge}<br>Z %{x:.2f} mm<br>shift %{y:.2f} px<extra></extra>`,
        };
      }),
      layout({
        xaxis: axis("plate height Z", "mm"),
        yaxis: axis(`edge shift t − t(Z_ref) on line ${lut.line}`, "px"),
        showlegend: false,
        annotations: [{ text: `${shown.length} of ${lut.curves.length} edges`, xref: "paper", yref: "paper", x: 0, y: 1.08, showarrow: false, font: { color: "#5b6472" } }],
      }),
    );
  };
  lineInput.input.addEventListener("change", async () => {
    const answer = await attempt("read the projector table", () => getJSON(`calibrations/${calibrationId}/table?line=${Number(lineInput.input.value)}`));
    if (!answer || !context.current()) return;
    lut = answer;
    await drawCurves();
  });

  // Maps over the whole image from the server (every entry of the table, binned in square cells): sensitivity,
  // the Z resolution it gives at the measured edge noise, coverage; and the coverage over Z.
  const report = await attempt("read the projector report", () => getJSON(`calibrations/${calibrationId}/projector-report`));
  if (!report || !context.current()) return;
  const size = { widthPx: report.image_size_px.width, heightPx: report.image_size_px.height };
  const centres = (n) => Array.from({ length: n }, (_, i) => (i + 0.5) * report.cell_px - 0.5);
  const mapKinds = {
    sensitivity: { name: "|dt/dZ|", unit: "px/mm", values: report.sensitivity_px_per_mm, scale: "Viridis", title: "sensitivity: edge shift per mm of Z" },
    resolution: { name: "Z resolution", unit: "mm", values: report.z_resolution_mm, scale: "Viridis", reverse: true, title: `Z resolution at the measured edge noise (${num(report.qa.edge_noise_px, 4)} px)` },
    coverage: { name: "coverage", unit: "share", values: report.coverage, scale: "Greens", title: "share of the edges seen that have a table entry" },
  };
  const mapKind = field("Map of", h("select", {}, Object.entries(mapKinds).map(([value, k]) => h("option", { value }, k.title))));
  const map = new Figure({
    name: "Sensitivity map",
    filename: `${name}-maps`,
    height: 420,
    csv: () => ({
      columns: ["u_px", "v_px", "cell_px", "sensitivity_px_per_mm", "z_resolution_mm", "coverage"],
      rows: report.sensitivity_px_per_mm.flatMap((row, j) => row.map((value, i) => [centres(report.cells_u)[i], centres(report.cells_v)[j], report.cell_px, value, report.z_resolution_mm[j][i], report.coverage[j][i]])),
    }),
  });
  const drawMap = () => {
    const kind = mapKinds[mapKind.input.value];
    return map.react(
      [{
        type: "heatmap",
        x: centres(report.cells_u),
        y: centres(report.cells_v),
        z: kind.values.map((row) => row.map((v) => (v === null ? NaN : v))),
        colorscale: kind.scale,
        reversescale: Boolean(kind.reverse),
        colorbar: { title: { text: `${kind.name} (${kind.unit})` } },
        hovertemplate: `u %{x:.0f} px, v %{y:.0f} px<br>${kind.name} %{z:.4f} ${kind.unit}<extra></extra>`,
      }],
      { ...imageLayout(size), showlegend: false },
    );
  };
  mapKind.input.addEventListener("change", drawMap);
  const resolutions = report.z_resolution_mm.flat().filter((v) => v !== null).sort((a, b) => a - b);
  const mapNote = h("p", { class: "hint", "aria-label": "About the sensitivity map" },
    `Over the whole ${size.widthPx} × ${size.heightPx} px image in ${report.cell_px} px cells (each the median of the table's entries there; blank: no edge seen). `,
    `At the measured edge noise of ${num(report.qa.edge_noise_px, 4)} px the table's sensitivity gives a Z resolution of ${num(resolutions[Math.floor(resolutions.length / 2)], 4)} mm (median cell), ${num(resolutions[resolutions.length - 1], 4)} mm in the least sensitive cell. `,
    explained("How the sensitivity is found", "4-projector-calibration-look-up-table", "sensitivity"));
  const zCoverage = new Figure({
    name: "Coverage over Z",
    filename: `${name}-coverage-z`,
    height: 300,
    csv: () => ({ columns: ["z_mm", "share_of_entries"], rows: report.z_mm.map((z, i) => [z, report.coverage_z[i]]) }),
  });
  // A short axis title (a long one was clipped by the plot's height); what it counts is said under the plot.
  const drawZ = () => zCoverage.react(
    [{ type: "bar", x: report.z_mm, y: report.coverage_z.map((v) => (v === null ? NaN : 100 * v)), marker: { color: "#2ca02c" }, hovertemplate: "Z %{x:.1f} mm: %{y:.1f} % of the entries<extra></extra>" }],
    layout({ xaxis: axis("plate height Z", "mm"), yaxis: axis("entries", "%", { range: [0, 100] }), showlegend: false }),
  );
  const zCoverageNote = h("p", { class: "hint" }, "Share of the table's entries (edge × scan line) whose fitted range holds each height Z.");

  const qa = Object.entries(first.qa || {}).filter(([, v]) => v === null || ["number", "string", "boolean"].includes(typeof v));
  const limits = Object.entries(report.limits).map(([key, l]) => `${key}: good ${l.good}, bad ${l.bad}`).join("; ");
  page(
    container,
    `Projector calibration ${calibration.id} (version ${calibration.version})`,
    h("p", {}, h("a", { href: `#/jobs/${job.id}` }, jobName(job)), " · ", h("a", { href: calibration.file_url }, "Download the table (HDF5)")),
    standingNote(calibration),
    verdictBox(report.verdict, "4-projector-calibration-look-up-table"),
    h("p", { class: "hint" }, "Thresholds, with units as in the table above: ", limits, ". ", explained("What the table's numbers mean", "4-projector-calibration-look-up-table")),
    h("div", { class: "two-columns" },
      h("dl", { class: "facts" }, [
        ["Scan", first.axis === "rows" ? "along image rows (vertical stripes)" : "along image columns (horizontal stripes)"],
        ["Stripe period", `${num(first.period_px, 2)} px`],
        ["Reference height", `${num(first.reference_z_mm, 2)} mm`],
        ["Table", `${first.n_edges} edges × ${first.n_lines} scan lines × ${first.z_mm.length} heights (${num(first.z_mm[0], 1)} … ${num(first.z_mm[first.z_mm.length - 1], 1)} mm)`],
      ].map(([term, value]) => [h("dt", {}, term), h("dd", {}, value)])),
      table("Projector table QA", [
        { title: "Quantity", value: (r) => explained(r[0], "4-projector-calibration-look-up-table", r[0]) },
        { title: "Value", value: (r) => (typeof r[1] === "number" ? String(Number(r[1].toPrecision(6))) : String(r[1])) },
      ], qa)),
    h("div", { class: "plot-controls" }, lineInput.wrap),
    h("div", { class: "plot-grid" }, curves.element, h("div", {}, h("div", { class: "plot-controls" }, mapKind.wrap), map.element, mapNote)),
    zCoverage.element,
    zCoverageNote,
  );
  context.onLeave(() => {
    curves.purge();
    map.purge();
    zCoverage.purge();
  });
  await drawCurves();
  await attempt("draw the maps", drawMap);
  await attempt("draw the coverage over Z", drawZ);
}
