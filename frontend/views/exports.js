// Exports from the dashboard: a form that starts an export job (POST /api/v1/jobs, kind "export") in any of the
// API's formats for its kind of result (read from its own schema, so the list is the server's one list): of a
// topography result for a frame range and, for profiles, the viewer's current section lines; of a comparison
// with a simulation (comparisonExportPanel). The jobs it starts are followed live and each gets its download link
// when done. The jobs lists show the same links (`downloadLinks` of job-helpers.js).
import { postJSON } from "../api.js";
import { apiSchema, resolve, specSchema } from "../specform.js";
import { field, fill, formatBytes, h, say, showError } from "../ui.js";
import { downloadLinks, followJob, jobName } from "./job-helpers.js";

const FORMAT_NAMES = {
  "points-csv": "points CSV (frame, x, y, z of every point)",
  "grid-npz": "grid NPZ (numpy)",
  mat: "MATLAB .mat",
  vtk: "VTK time series for ParaView (zipped)",
  "profile-csv": "profile CSV (the section lines)",
};

/** The export formats of a `source` result ("topography" or "comparison") in the server's job spec schemas:
 * ExportSpec's format holds one list per source, each titled ("Topography export", "Comparison export"). */
export async function exportFormats(source = "topography") {
  const root = await apiSchema();
  const schema = specSchema(root, "export");
  let format = schema.properties.format;
  format = resolve(format, root);
  const lists = format.anyOf ? format.anyOf.map((s) => resolve(s, root)) : [format];
  const title = source === "comparison" ? "Comparison export" : "Topography export";
  const chosen = lists.find((s) => s.title === title) || lists[0];
  return chosen.enum || [chosen.const].filter(Boolean);
}

/** Follow an export job started from a form: its state, then its download link, in `item` (an <li>). */
export function followExport(exportJob, item, context) {
  const state = h("span", { class: "badge" }, exportJob.state);
  const links = h("span");
  fill(item, h("a", { href: `#/jobs/${exportJob.id}` }, jobName(exportJob)), ` ${exportJob.spec.format} `, state, " ", links);
  const close = followJob(exportJob.id, {
    onJob: (current) => {
      state.textContent = current.state;
      state.className = `badge state-${current.state}`;
      if (current.error) fill(links, h("span", { class: "error" }, current.error));
      const files = downloadLinks(current);
      if (files) fill(links, files, ` (${formatBytes(current.files.reduce((a, f) => a + f.size_bytes, 0))})`);
    },
  });
  context.onLeave(close);
}

/**
 * The export form of topography job `job`. `frames` is the result's frame numbers; `lines()` returns the section
 * lines drawn in the viewer now ([{ label, x0, y0, x1, y1 }]; none on a page without a viewer).
 */
export function exportPanel(job, { frames, lines = () => [], context }) {
  const format = field("Export format", h("select", {}, h("option", { value: "" }, "reading the formats…")));
  const first = field("First frame", h("input", { type: "number", min: frames[0], max: frames[frames.length - 1], step: 1, value: frames[0] }));
  const last = field("Last frame", h("input", { type: "number", min: frames[0], max: frames[frames.length - 1], step: 1, value: frames[frames.length - 1] }));
  const about = h("p", { class: "hint wide-row", "aria-live": "polite" });
  const started = h("ul", { class: "exports wide-row", "aria-label": "Exports started here" });
  const submit = h("button", { type: "submit", class: "primary" }, "Export");
  const describe = () => {
    const chosen = lines();
    about.textContent = format.input.value === "profile-csv"
      ? chosen.length
        ? `Profiles along the ${chosen.length} section line${chosen.length > 1 ? "s" : ""} drawn now (${chosen.map((l) => l.label).join(", ")}), sampled on the result grid.`
        : "No section line drawn: the profile runs along X through the punch axis."
      : "The result grid itself (not the display grid), every point measured.";
  };
  format.input.addEventListener("change", describe);
  exportFormats()
    .then((formats) => {
      fill(format.input, formats.map((f) => h("option", { value: f }, FORMAT_NAMES[f] || f)));
      describe();
    })
    .catch((error) => showError(error, "read the export formats"));

  const form = h(
    "form",
    {
      class: "card grid-form",
      "aria-label": "Export the result",
      onsubmit: async (event) => {
        event.preventDefault();
        const spec = { kind: "export", job_id: job.id, format: format.input.value, frames: { first: Number(first.input.value), last: Number(last.input.value) } };
        const chosen = lines();
        if (spec.format === "profile-csv" && chosen.length) spec.lines = chosen.map((l) => [l.x0, l.y0, l.x1, l.y1]);
        await startExport(spec, `${spec.format}, frames ${spec.frames.first}–${spec.frames.last}`, { submit, started, context });
      },
    },
    h("h2", {}, "Export"),
    format.wrap,
    first.wrap,
    last.wrap,
    h("div", { class: "actions" }, submit),
    about,
    started,
  );
  return { element: form, describe };
}

/** Start export job `spec` from a form (its `submit` button held while it is sent), said as `what`, and follow it
 * in the form's list `started`. */
async function startExport(spec, what, { submit, started, context }) {
  submit.disabled = true;
  try {
    const exportJob = await postJSON("jobs", spec);
    say(`${jobName(exportJob)} started: ${what}.`);
    const item = h("li", {});
    started.prepend(item);
    followExport(exportJob, item, context);
  } catch (error) {
    showError(error, "start the export");
  } finally {
    submit.disabled = false;
  }
}

const COMPARISON_FORMAT_NAMES = {
  csv: "CSV, one row per frame (RMS, largest and mean difference, both curves)",
  hdf5: "HDF5, the whole comparison file",
  mat: "MATLAB .mat (the fields of every frame)",
  vtk: "VTK time series for ParaView (zipped): w measured, simulated, difference, σ",
  "profile-csv": "profile CSV along the profile shown (measured, simulated, σ, beyond 2σ)",
};

/** The export form of comparison job `job`; `line()` returns the profile's line now ([X0, Y0, X1, Y1] mm). */
export function comparisonExportPanel(job, { line, context }) {
  const format = field("Comparison export format", h("select", {}, h("option", { value: "" }, "reading the formats…")));
  const started = h("ul", { class: "exports wide-row", "aria-label": "Exports started here" });
  const submit = h("button", { type: "submit", class: "primary" }, "Export");
  exportFormats("comparison")
    .then((formats) => fill(format.input, formats.map((f) => h("option", { value: f }, COMPARISON_FORMAT_NAMES[f] || f))))
    .catch((error) => showError(error, "read the export formats"));
  return h(
    "form",
    {
      class: "card grid-form",
      "aria-label": "Export the comparison",
      onsubmit: async (event) => {
        event.preventDefault();
        const spec = { kind: "export", job_id: job.id, format: format.input.value };
        if (spec.format === "profile-csv") spec.line = line();
        await startExport(spec, spec.format, { submit, started, context });
      },
    },
    h("h2", {}, "Export"),
    format.wrap,
    h("div", { class: "actions" }, submit),
    started,
  );
}
