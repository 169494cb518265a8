// Simulations of an experiment and their comparison with a measurement: the uploaded finite-element models (upload
// one file or a ZIP of a folder, list, delete), and the mapping form that starts a comparison job, with a live
// preview (POST /comparisons/preview: the measured and simulated profile through the punch axis for the form's
// choices as they are now). Every choice the server detects is shown in its control and can be changed there; the
// spec the form sends is the comparison job's own (POST /api/v1/jobs, kind "comparison").
import { getJSON, postJSON, putFile } from "../api.js";
import { COLORS, Figure, axis, bandTrace, lineLayout } from "../plots.js";
import { attempt, field, fill, formatBytes, h, num, say, showError, table } from "../ui.js";
import { filesOfDrop } from "../upload.js";
import { storedZip } from "../zip.js";
import { deleteButton } from "./deletion.js";
import { jobName, shortId } from "./job-helpers.js";

const FORMAT_NAMES = { d3plot: "LS-DYNA d3plot", vtu: "VTU", pvd: "VTU series (.pvd)", exodus: "Exodus II", csv: "nodal CSV" };
const PREVIEW_DELAY_MS = 350; // the preview follows typing without a request per key

/** A select whose first option is "detect" (empty value); `choices` = [[value, text]]. */
function detectSelect(choices, detectText = "detect") {
  return h("select", {}, h("option", { value: "" }, detectText), choices.map(([value, text]) => h("option", { value }, text)));
}

/** The ±σ band, the measured and the simulated profile: traces of one preview or comparison profile. */
export function profileTraces(profile, { measuredName = "measured", simulatedName = "simulated" } = {}) {
  const known = (w, k) => w !== null && profile.sigma_mm[k] !== null;
  const upper = profile.measured_mm.map((w, k) => (known(w, k) ? w + profile.sigma_mm[k] : null));
  const lower = profile.measured_mm.map((w, k) => (known(w, k) ? w - profile.sigma_mm[k] : null));
  return [
    bandTrace(profile.s_mm, lower, upper, { name: "measured ± σ", color: "rgba(31,119,180,0.25)" }),
    { type: "scatter", mode: "lines", name: measuredName, x: profile.s_mm, y: profile.measured_mm, line: { color: COLORS[0], width: 2 }, connectgaps: false },
    { type: "scatter", mode: "lines", name: simulatedName, x: profile.s_mm, y: profile.simulated_mm, line: { color: COLORS[1], width: 2, dash: "dash" }, connectgaps: false },
  ];
}

/** "state 5", "state 5 + 0.25 toward 6": where a frame lies among the simulation's states. */
export function stateText(lo, fraction) {
  if (fraction >= 0.9995) return `state ${lo + 1}`;
  return fraction > 0.0005 ? `state ${lo} + ${num(fraction, 2)} toward ${lo + 1}` : `state ${lo}`;
}

// ---- the list and the upload -----------------------------------------------------------------------------------

const STATE_NAMES = { checking: "checking…", ready: "ready", failed: "failed" };
const CHECK_POLL_MS = 1500; // while a simulation is checked, the list is looked at again this often

/** What a simulation holds, or where its check stands (a worker reads it after the upload). */
function simulationFacts(s) {
  if (s.state === "checking") return "being read by a worker";
  if (s.state === "failed") return s.error || "unreadable";
  const info = s.info || {};
  const parts = [`${s.n_states} states`, `${s.n_nodes} nodes`];
  if (info.n_shells) parts.push(`${info.n_shells} shells`);
  if (info.n_solids) parts.push(`${info.n_solids} solids`);
  parts.push(info.length_unit ? `in ${info.length_unit}` : "units detected when compared");
  parts.push(info.has_punch_displacement ? "punch travel" : "no punch travel");
  parts.push(info.has_force ? "force" : "no force");
  return parts.join(", ");
}

/** The simulations section of an experiment page. `topographies()` returns its succeeded topography jobs (with a
 * `label`); call `jobsChanged()` when they may have changed. */
export function simulationsPanel({ experimentId, context, topographies }) {
  const listBox = h("div", {}, h("p", {}, "Loading…"));
  let simulations = [];
  let timer = null;
  context.onLeave(() => clearTimeout(timer));
  const mapping = mappingForm({ context, simulations: () => simulations.filter((s) => s.state === "ready"), topographies });
  const refresh = async () => {
    clearTimeout(timer);
    const found = await attempt("list the simulations", () => getJSON(`experiments/${experimentId}/simulations`));
    if (!found || !context.current()) return;
    simulations = found;
    fill(listBox, table(
      "Simulations",
      [
        { title: "Simulation", value: (s) => `#${s.id} ${s.filename}` },
        { title: "State", value: (s) => STATE_NAMES[s.state] || s.state },
        { title: "Format", value: (s) => FORMAT_NAMES[s.kind] || s.kind || "—" },
        { title: "Holds", value: simulationFacts },
        { title: "Size", value: (s) => formatBytes(s.size_bytes) },
        { title: "", value: (s) => deleteButton(`simulations/${s.id}`, `simulation ${s.id} ${s.filename}`, refresh) },
      ],
      simulations,
      { empty: "No simulations yet: upload a finite-element result below." },
    ));
    mapping.simulationsChanged();
    // an upload is checked by a job in a worker: the list follows it until it is ready or failed
    if (simulations.some((s) => s.state === "checking")) timer = setTimeout(refresh, CHECK_POLL_MS);
  };

  // A simulation is one upload: a file as it is, or a folder (a d3plot family with nodout and rcforc, a .pvd with
  // its .vtu files) packed in the browser into a stored ZIP, as the recordings' uploader packs folders of frames.
  const file = field(
    "Simulation file",
    h("input", { type: "file", accept: ".zip,.csv,.vtu,.pvd,.e,.exo,.ex2,.d3plot" }),
    "One file (a nodal CSV, a .vtu, an Exodus .e/.exo) or a ZIP of a folder: a d3plot family with nodout and rcforc, a .pvd with its .vtu files, a nodal CSV with its punch CSV (time_s, force_kN, punch_displacement_mm).",
  );
  const folder = field("Simulation folder", h("input", { type: "file", webkitdirectory: true }),
    "A folder is packed into one ZIP here and uploaded; so are several files dropped together.");
  const progress = h("progress", { max: 1, value: 0, hidden: true, "aria-label": "Upload progress of the simulation" });
  const progressText = h("span", { class: "progress-text", "aria-live": "polite" });
  const submit = h("button", { type: "submit", class: "primary" }, "Upload simulation");

  /** Upload [{ file, path }] as one simulation: one file as it is, more (a folder's) as a stored ZIP. */
  const send = async (items) => {
    if (!items.length) return showError("choose a file or a folder first", "upload the simulation");
    const top = items[0].path.includes("/") ? items[0].path.split("/")[0] : "simulation";
    const name = items.length === 1 && !items[0].path.includes("/") ? items[0].file.name : `${top}.zip`;
    submit.disabled = true;
    progress.hidden = false;
    const abort = new AbortController();
    context.onLeave(() => abort.abort());
    try {
      let body = items[0].file;
      if (items.length > 1 || items[0].path.includes("/")) {
        const inFolder = items.map(({ file: f, path }) => ({ file: f, path: path.includes("/") ? path.split("/").slice(1).join("/") : path }));
        body = await storedZip(inFolder, { onProgress: (done, total) => {
          progressText.textContent = `packing ${items.length} files… ${Math.floor((100 * done) / total)} %`;
        } });
      }
      const made = await putFile(`experiments/${experimentId}/simulations/${encodeURIComponent(name)}`, body, {
        signal: abort.signal,
        onProgress: (sent, total) => {
          progress.value = total ? sent / total : 0;
          progressText.textContent = `${formatBytes(sent)} of ${formatBytes(total)}${sent >= total ? ", storing it…" : ""}`;
        },
      });
      say(`Simulation ${made.id} ${made.filename} uploaded; a worker is checking it.`);
      progressText.textContent = "";
      await refresh();
    } catch (error) {
      progressText.textContent = "";
      showError(error, `upload ${name}`);
    } finally {
      submit.disabled = false;
      progress.hidden = true;
    }
    return null;
  };
  const picked = (input) => {
    const items = [...input.files].map((f) => ({ file: f, path: f.webkitRelativePath || f.name }));
    input.value = "";
    return items;
  };
  folder.input.addEventListener("change", () => send(picked(folder.input)));
  const upload = h(
    "form",
    {
      class: "card grid-form dropzone",
      "aria-label": "Upload a simulation",
      ondragover: (event) => {
        event.preventDefault();
        upload.classList.add("over");
      },
      ondragleave: () => upload.classList.remove("over"),
      ondrop: async (event) => {
        event.preventDefault();
        upload.classList.remove("over");
        try {
          await send(await filesOfDrop(event.dataTransfer));
        } catch (error) {
          showError(error, "read the dropped files");
        }
      },
      onsubmit: (event) => {
        event.preventDefault();
        send(picked(file.input));
      },
    },
    h("h3", {}, "Upload a simulation"),
    h("p", { class: "hint wide-row" }, "Drop a simulation's file or folder here, or choose it."),
    file.wrap,
    folder.wrap,
    h("div", { class: "actions" }, submit, " ", progress, " ", progressText),
  );
  refresh();
  return {
    element: h("section", { "aria-labelledby": "simulations-title" },
      h("h2", { id: "simulations-title" }, "Simulations and comparisons"), listBox, upload, mapping.element),
    jobsChanged: () => mapping.topographiesChanged(),
  };
}

// ---- the mapping form with its live preview -------------------------------------------------------------------

/** The mapping form: what to compare, how the model lies on the plate, how frames meet states; a live preview. */
function mappingForm({ context, simulations, topographies }) {
  const topography = field("Topography result", h("select", { required: true }));
  const simulation = field("Simulation", h("select", { required: true }));
  const controls = {
    align: field("Time alignment", h("select", {},
      h("option", { value: "displacement" }, "by punch displacement"),
      h("option", { value: "time" }, "by time"),
      h("option", { value: "peak" }, "by peak deflection")),
    "Which simulation state each test frame is compared with: the state of the same punch displacement (frames.csv and the model's punch node), the same time, or the same peak deflection."),
    units: field("Units", detectSelect([["mm", "mm"], ["m", "m"]]), "The model's length unit; detected from its extent against the measured plate."),
    symmetry: field("Symmetry", detectSelect([["none", "none (full model)"], ["half-x", "half-x (one side of X = 0)"], ["half-y", "half-y (one side of Y = 0)"], ["quarter", "quarter"]]),
      "A half or quarter model is unfolded by mirroring about its own X = 0 and Y = 0 planes."),
    normal_axis: field("Normal axis", detectSelect([["x", "x"], ["y", "y"], ["z", "z"]]), "The model axis out of the plate (detected: its thinnest)."),
    w_sign: field("Sign of w", detectSelect([["1", "+1"], ["-1", "−1"]]), "+1 or −1: the sign that makes the deflection toward the cameras positive."),
    origin_x: field("Origin x (mm)", h("input", { type: "number", step: "any", placeholder: "detect" }), "Where the model's origin lies on the plate; empty: on the measured punch axis (fitted)."),
    origin_y: field("Origin y (mm)", h("input", { type: "number", step: "any", placeholder: "detect" })),
    rotation_deg: field("Rotation (°)", h("input", { type: "number", step: "any", value: 0, min: -360, max: 360 }), "Of the model about Z, after unfolding."),
    surface: field("Surface facing the cameras", h("select", {},
      h("option", { value: "toward-cameras" }, "the side +Z points to (the rear in the paper's set-up)"),
      h("option", { value: "away" }, "the other side"),
      h("option", { value: "mid" }, "the mid-surface (no thickness offset)")),
    "Which surface of a shell or solid model the cameras see; shells are offset by half their thickness."),
    shell_thickness_mm: field("Shell thickness (mm)", h("input", { type: "number", step: "any", min: 0, placeholder: "from the file" }), "Overrides the file's; the surface facing the cameras lies half of it off the mid-surface."),
    punch_node: field("Punch node", h("input", { type: "number", step: 1, min: 1, placeholder: "nodout's only node" }), "The node whose travel is the punch displacement, where the file has no punch curve."),
    time_unit_s: field("Time unit (s)", h("input", { type: "number", step: "any", min: 0, placeholder: "from the file, else 1" }), "Seconds per model time unit (0.001 for ms)."),
    time_offset_s: field("Time offset (s)", h("input", { type: "number", step: "any", value: 0 }), "Added to the model's times before aligning by time."),
  };
  const unitsConfirmed = h("input", { type: "checkbox", id: "units-confirmed" });
  const unitsLabel = h("label", { for: "units-confirmed" }, "The model's units are as detected");
  const unitsConfirm = h("div", { class: "field check-field", style: "grid-column: 1 / -1", hidden: true }, h("span", {}, unitsConfirmed, " ", unitsLabel));
  const previewAxis = field("Preview profile along", h("select", {}, h("option", { value: "x" }, "X through the punch axis"), h("option", { value: "y" }, "Y through the punch axis")));
  const previewFrame = field("Preview frame", h("select", {}, h("option", { value: "" }, "the most deflected paired frame")));
  const previewFigure = new Figure({ name: "Mapping preview", filename: "mapping-preview", height: 340, csv: () => previewCSV() });
  const previewState = h("p", { class: "facts", "aria-live": "polite", "aria-label": "Preview state" });
  const previewError = h("p", { class: "error", role: "alert", hidden: true });
  const detectedList = h("ul", { class: "warnings", "aria-label": "Detected mapping and notes" });
  const unpaired = h("ul", { class: "warnings", "aria-label": "Frames not compared" });
  const submit = h("button", { type: "submit", class: "primary" }, "Start comparison");
  const started = h("ul", { class: "exports", "aria-label": "Comparisons started here" });
  let preview = null;
  let sequence = 0;
  let timer = null;
  context.onLeave(() => clearTimeout(timer));

  const number = (input) => (input.value === "" ? null : Number(input.value));
  /** The comparison job's spec from the form (empty means: detect). */
  const spec = () => {
    const c = Object.fromEntries(Object.entries(controls).map(([key, f]) => [key, f.input]));
    const out = {
      kind: "comparison",
      job_id: topography.input.value,
      simulation_id: Number(simulation.input.value),
      align: c.align.value,
      surface: c.surface.value,
      rotation_deg: number(c.rotation_deg) || 0,
      time_offset_s: number(c.time_offset_s) || 0,
    };
    for (const key of ["units", "symmetry", "normal_axis"]) if (c[key].value) out[key] = c[key].value;
    if (c.w_sign.value) out.w_sign = Number(c.w_sign.value);
    if (c.origin_x.value !== "" || c.origin_y.value !== "") {
      // One coordinate set: the other stays where the last preview put it.
      const shown = preview ? preview.mapping.origin_xy_mm : [0, 0];
      out.origin_xy_mm = [number(c.origin_x) ?? shown[0], number(c.origin_y) ?? shown[1]];
    }
    for (const key of ["shell_thickness_mm", "punch_node", "time_unit_s"]) if (c[key].value !== "") out[key] = number(c[key]);
    return out;
  };

  const previewCSV = () => {
    const rows = [];
    if (preview) {
      for (const name of ["x", "y"]) {
        const p = preview.profiles[name];
        p.s_mm.forEach((s, i) => rows.push([preview.frame, name, s, p.x_mm[i], p.y_mm[i], p.measured_mm[i], p.simulated_mm[i], p.sigma_mm[i]]));
      }
    }
    return { columns: ["frame", "along", "s_mm", "x_mm", "y_mm", "w_meas_mm", "w_sim_mm", "sigma_w_mm"], rows };
  };

  /** Show what the server detected in the controls left on "detect", so every choice is seen and can be changed. */
  const showDetected = (m) => {
    const detected = new Set(m.detected);
    const show = (select, key, text) => {
      select.options[0].textContent = detected.has(key) ? `detected: ${text}` : "detect";
    };
    show(controls.units.input, "length_unit", m.length_unit);
    show(controls.symmetry.input, "symmetry", m.symmetry);
    show(controls.normal_axis.input, "normal_axis", m.normal_axis);
    show(controls.w_sign.input, "w_sign", m.w_sign > 0 ? "+1" : "−1");
    const origin = detected.has("origin_xy_mm") ? "detected" : "set";
    controls.origin_x.input.placeholder = `${origin}: ${num(m.origin_xy_mm[0], 2)}`;
    controls.origin_y.input.placeholder = `${origin}: ${num(m.origin_xy_mm[1], 2)}`;
    controls.shell_thickness_mm.input.placeholder = m.shell_thickness_mm ? `from the file: ${num(m.shell_thickness_mm, 3)}` : "from the file (none)";
    controls.time_unit_s.input.placeholder = `${m.time_unit_s}`;
    // Units detected from the extent must be confirmed before the comparison starts.
    const needsConfirming = detected.has("length_unit") && !controls.units.input.value;
    unitsConfirm.hidden = !needsConfirming;
    unitsConfirmed.required = needsConfirming;
    unitsLabel.textContent = `The model's units are ${m.length_unit} (detected from its extent against the measured plate)`;
    const names = { length_unit: "units", symmetry: "symmetry", normal_axis: "normal axis", w_sign: "sign of w", origin_xy_mm: "origin" };
    fill(detectedList,
      h("li", {}, `Detected: ${m.detected.map((d) => names[d] || d).join(", ") || "nothing (all set)"}.`),
      m.notes.map((note) => h("li", {}, note)));
  };

  const drawPreview = () => {
    if (!preview) return previewFigure.react([], lineLayout({ xAxis: axis("distance along the line", "mm"), yAxis: axis("deflection w", "mm"), note: "Choose a topography result and a simulation" }));
    const profile = preview.profiles[previewAxis.input.value];
    return previewFigure.react(profileTraces(profile), lineLayout({
      xAxis: axis(`distance along ${previewAxis.input.value.toUpperCase()} through the punch axis`, "mm"),
      yAxis: axis("deflection w", "mm"),
    }));
  };

  const update = async () => {
    clearTimeout(timer);
    const mine = ++sequence;
    submit.disabled = true; // a comparison starts from choices the preview has shown to work
    if (!topography.input.value || !simulation.input.value) {
      // Nothing to compare yet: a sentence says what is missing, and no form, no empty plot.
      preview = null;
      waiting.textContent = !topography.input.value
        ? "Comparisons open here once this experiment has a succeeded topography result and a simulation."
        : "Upload a simulation above to compare the topography results with it.";
      waiting.hidden = false;
      form.hidden = true;
      return null;
    }
    waiting.hidden = true;
    form.hidden = false;
    previewState.textContent = "Updating the preview…";
    try {
      const body = { spec: spec() };
      if (previewFrame.input.value !== "") body.frame = Number(previewFrame.input.value);
      const answer = await postJSON("comparisons/preview", body);
      if (mine !== sequence || !context.current()) return null;
      preview = answer;
      previewError.hidden = true;
      submit.disabled = false;
      const f = answer.frames;
      const i = f.frame.indexOf(answer.frame);
      const paired = f.state_lo.filter((s) => s >= 0).length;
      previewState.textContent = `Frame ${answer.frame} (peak ${num(f.peak_w_mm[i], 2)} mm) against ${stateText(f.state_lo[i], f.state_fraction[i])}`
        + ` · ${paired} of ${f.frame.length} frames paired `
        + `by ${answer.alignment} · the measurement covers ${Math.round(100 * answer.overlap_fraction)} % of the model.`;
      showDetected(answer.mapping);
      fill(unpaired, f.frame.map((frame, k) => (f.reason[k] ? h("li", {}, `Frame ${frame} not compared: ${f.reason[k]}`) : null)));
      const chosen = previewFrame.input.value;
      fill(previewFrame.input, h("option", { value: "" }, "the most deflected paired frame"),
        f.frame.filter((_, k) => f.state_lo[k] >= 0).map((frame) => h("option", { value: frame }, `frame ${frame}`)));
      previewFrame.input.value = chosen;
    } catch (error) {
      if (mine !== sequence || !context.current()) return null;
      preview = null;
      previewError.textContent = `This mapping cannot be compared: ${error.message}`;
      previewError.hidden = false;
      previewState.textContent = "";
      fill(detectedList);
      fill(unpaired);
    }
    return drawPreview();
  };
  const soon = () => {
    clearTimeout(timer);
    timer = setTimeout(update, PREVIEW_DELAY_MS);
  };

  const form = h(
    "form",
    {
      class: "card",
      "aria-label": "Compare with a simulation",
      oninput: (event) => (event.target === unitsConfirmed ? null : soon()),
      onchange: (event) => (event.target === unitsConfirmed || event.target === previewAxis.input ? null : soon()),
      onsubmit: async (event) => {
        event.preventDefault();
        const chosen = spec();
        // Confirmed units go into the spec: the comparison then uses what the person saw, not a new detection.
        if (!chosen.units && preview && unitsConfirmed.checked) chosen.units = preview.mapping.length_unit;
        submit.disabled = true;
        try {
          const job = await postJSON("jobs", chosen);
          say(`${jobName(job)} started: topography ${shortId(chosen.job_id)} against simulation ${chosen.simulation_id}.`);
          started.prepend(h("li", {}, h("a", { href: `#/jobs/${job.id}` }, jobName(job)), " · its ",
            h("a", { href: `#/jobs/${job.id}/comparison` }, "comparison view"), " opens when it has succeeded"));
        } catch (error) {
          showError(error, "start the comparison");
        } finally {
          submit.disabled = false;
        }
      },
    },
    h("h3", {}, "Compare with a simulation"),
    h("div", { class: "grid-form" }, topography.wrap, simulation.wrap),
    h("fieldset", { class: "sub-spec" }, h("legend", {}, "Mapping onto the plate and time alignment"),
      Object.values(controls).map((f) => f.wrap), unitsConfirm),
    h("div", { class: "compare-controls" }, previewAxis.wrap, previewFrame.wrap),
    previewState,
    previewError,
    previewFigure.element,
    detectedList,
    unpaired,
    h("div", { class: "actions" }, submit),
    started,
  );
  const waiting = h("p", { class: "hint" });
  form.hidden = true;
  previewAxis.input.addEventListener("change", drawPreview);
  context.onLeave(() => previewFigure.purge());

  const options = (select, items, emptyText) => {
    const previous = select.value;
    fill(select, items.length ? items.map((item) => h("option", { value: item.id }, item.label)) : h("option", { value: "" }, emptyText));
    if (items.some((item) => String(item.id) === previous)) select.value = previous;
    return previous !== select.value;
  };
  let shownTopographies = "";
  return {
    element: h("div", {}, waiting, form),
    simulationsChanged: () => {
      const changed = options(simulation.input, simulations().map((s) => ({ id: s.id, label: `#${s.id} ${s.filename} (${FORMAT_NAMES[s.kind] || s.kind}, ${s.n_states} states)` })), "no simulation yet");
      if (changed || !preview) update();
    },
    topographiesChanged: () => {
      const items = topographies();
      const signature = JSON.stringify(items.map((t) => t.id));
      if (signature === shownTopographies) return;
      shownTopographies = signature;
      if (options(topography.input, items, "no succeeded topography yet") || !preview) update();
    },
  };
}
