// Experiments: the list (with a form to create one, and the demo button) and an experiment's page with its
// cameras, their recordings and uploads, its jobs and its results.
import { apiUrl, getJSON, postJSON } from "../api.js";
import { attempt, field, fill, formatBytes, formatTime, h, page, say, showError, table } from "../ui.js";
import { Uploader } from "../upload.js";
import { jobsPanel } from "./jobs.js";

export const KIND_NAMES = {
  camera_calibration: "Camera calibration",
  projector_calibration: "Projector calibration",
  test: "Test",
};
const BUSY_STATES = ["uploading", "ingesting"];

// ---- the list -----------------------------------------------------------------------------------------------------

export async function renderExperiments(container, _params, context) {
  const list = h("div", {}, h("p", {}, "Loading…"));
  const name = field("Name", h("input", { type: "text", required: true, maxlength: 200, placeholder: "Plate 12, 20 m/s" }));
  const plate = field("Plate", h("input", { type: "text", maxlength: 200, placeholder: "AA6016-T4, 1.5 mm" }));
  const punch = field("Punch", h("input", { type: "text", maxlength: 200, placeholder: "hemispherical, Ø 20 mm" }));
  const date = field("Test date", h("input", { type: "date" }));
  const notes = field("Notes", h("textarea", { rows: 2, maxlength: 20000 }));
  const form = h(
    "form",
    {
      class: "card grid-form",
      "aria-label": "New experiment",
      onsubmit: async (event) => {
        event.preventDefault();
        try {
          const created = await postJSON("experiments", {
            name: name.input.value,
            plate: plate.input.value,
            punch: punch.input.value,
            test_date: date.input.value,
            notes: notes.input.value,
          });
          say(`Experiment ${created.name} created.`);
          window.location.hash = `#/experiments/${created.id}`;
        } catch (error) {
          showError(error, "create the experiment");
        }
      },
    },
    h("h2", {}, "New experiment"),
    name.wrap,
    plate.wrap,
    punch.wrap,
    date.wrap,
    notes.wrap,
    h("div", { class: "actions" }, h("button", { type: "submit", class: "primary" }, "Create experiment")),
  );
  const demoCameras = field(
    "Virtual cameras",
    h("select", {},
      h("option", { value: "kodak,phantom" }, "Kodak and Phantom (about 2 minutes)"),
      h("option", { value: "kodak" }, "Kodak only (under a minute)")),
  );
  const demo = h(
    "button",
    {
      type: "button",
      class: "primary",
      onclick: async () => {
        demo.disabled = true;
        say("Making the demo experiment: simulating recordings…");
        try {
          const made = await postJSON("demo", { cameras: demoCameras.input.value.split(",") });
          say(`Demo experiment ${made.experiment_id} made; its jobs are running.`);
          window.location.hash = `#/experiments/${made.experiment_id}`;
        } catch (error) {
          showError(error, "make the demo experiment");
          demo.disabled = false;
        }
      },
    },
    "Load demo experiment",
  );
  page(
    container,
    "Experiments",
    h(
      "div",
      { class: "card demo" },
      demo,
      demoCameras.wrap,
      h("span", { class: "hint" }, "A virtual punch test: its recordings are simulated, then checked, calibrated and measured by the workers like uploaded ones."),
    ),
    list,
    form,
  );
  const experiments = await attempt("list the experiments", () => getJSON("experiments"));
  if (!experiments || !context.current()) return;
  fill(
    list,
    table(
      "Experiments",
      [
        { title: "Name", value: (e) => h("a", { href: `#/experiments/${e.id}` }, e.name) },
        { title: "Plate", value: (e) => e.plate },
        { title: "Punch", value: (e) => e.punch },
        { title: "Test date", value: (e) => e.test_date },
        { title: "Created", value: (e) => formatTime(e.created_at) },
      ],
      experiments,
      { empty: "No experiments yet: create one below, or load the demo." },
    ),
  );
}

// ---- one experiment --------------------------------------------------------------------------------------------

function recordingState(recording) {
  if (recording.state === "invalid") return h("span", { class: "bad" }, `invalid: ${recording.error}`);
  if (recording.state === "ready") {
    const warnings = recording.warnings.length;
    return h("span", { class: warnings ? "warn" : "ok" }, warnings ? `ready, ${warnings} warning${warnings > 1 ? "s" : ""}` : "ready");
  }
  return h("span", { class: "busy" }, `${recording.state}…`);
}

function recordingsTable(camera, recordings) {
  return table(
    `Recordings of ${camera.name}`,
    [
      { title: "Recording", value: (r) => h("a", { href: `#/recordings/${r.id}` }, `#${r.id} ${r.filename}`) },
      { title: "Kind", value: (r) => KIND_NAMES[r.kind] || r.kind },
      { title: "State", value: recordingState },
      { title: "Frames", value: (r) => (r.frame_count ? `${r.frame_count} × ${r.width_px}×${r.height_px} px, ${r.bit_depth} bit` : "–") },
      { title: "Size", value: (r) => formatBytes(r.size_bytes) },
    ],
    recordings,
    { empty: "No recordings yet." },
  );
}

function cameraForm(experimentId, onAdded) {
  const name = field("Camera name", h("input", { type: "text", required: true, maxlength: 100, placeholder: "left" }));
  const width = field("Image width (px)", h("input", { type: "number", required: true, min: 1, step: 1, value: 1024 }));
  const height = field("Image height (px)", h("input", { type: "number", required: true, min: 1, step: 1, value: 1024 }));
  const pitch = field("Pixel pitch (µm)", h("input", { type: "number", required: true, min: 0.01, step: "any", value: 20 }));
  return h(
    "form",
    {
      class: "card grid-form",
      "aria-label": "Add a camera",
      onsubmit: async (event) => {
        event.preventDefault();
        try {
          const camera = await postJSON(`experiments/${experimentId}/cameras`, {
            name: name.input.value,
            image_width_px: Number(width.input.value),
            image_height_px: Number(height.input.value),
            pixel_pitch_um: Number(pitch.input.value),
          });
          say(`Camera ${camera.name} added.`);
          name.input.value = "";
          onAdded();
        } catch (error) {
          showError(error, "add the camera");
        }
      },
    },
    h("h3", {}, "Add a camera"),
    name.wrap,
    width.wrap,
    height.wrap,
    pitch.wrap,
    h("div", { class: "actions" }, h("button", { type: "submit" }, "Add camera")),
  );
}

/** A camera's box: its facts, its recordings (refreshed while any is busy) and an upload control. */
function cameraSection(camera, context, onRecordingsChanged) {
  const recordingsBox = h("div", {}, h("p", {}, "Loading…"));
  const kind = field(
    `Kind of the recordings to upload to ${camera.name}`,
    h("select", {}, Object.entries(KIND_NAMES).map(([value, text]) => h("option", { value }, text))),
  );
  let timer = null;
  let shown = null;
  const refresh = async () => {
    clearTimeout(timer);
    const recordings = await attempt(`list the recordings of ${camera.name}`, () => getJSON(`cameras/${camera.id}/recordings`));
    if (!recordings || !context.current()) return;
    const signature = JSON.stringify(recordings.map((r) => [r.id, r.state, r.frame_count, r.warnings.length, r.filename]));
    if (signature !== shown) {
      shown = signature;
      fill(recordingsBox, recordingsTable(camera, recordings));
      onRecordingsChanged(camera, recordings);
    }
    // Quickly while a recording is being checked; slowly otherwise, so that recordings uploaded by scripts or
    // made by the demo appear too.
    timer = setTimeout(refresh, recordings.some((r) => BUSY_STATES.includes(r.state)) ? 1500 : 5000);
  };
  context.onLeave(() => clearTimeout(timer));
  const uploader = new Uploader({
    endpoint: apiUrl("uploads"),
    label: `Upload recordings to ${camera.name}`,
    metadata: () => ({ camera_id: String(camera.id), kind: kind.input.value }),
    onRecording: (recordingId) => {
      say(`Recording ${recordingId} uploaded to ${camera.name}; checking its frames.`);
      refresh();
    },
  });
  context.onLeave(() => uploader.abortAll());
  refresh();
  return h(
    "section",
    { class: "card camera", "aria-label": `Camera ${camera.name}` },
    h("h3", {}, `Camera ${camera.name}`),
    h(
      "p",
      { class: "facts" },
      `${camera.image_width_px} × ${camera.image_height_px} px, pixel pitch ${Number(camera.pixel_pitch_um.toPrecision(6))} µm`,
    ),
    recordingsBox,
    h("div", { class: "upload-kind" }, kind.wrap),
    uploader.element,
  );
}

export async function renderExperiment(container, { id }, context) {
  const experiment = await attempt("open the experiment", () => getJSON(`experiments/${id}`));
  if (!experiment || !context.current()) {
    if (!experiment) page(container, "Experiment", h("p", {}, h("a", { href: "#/experiments" }, "All experiments")));
    return;
  }
  const camerasBox = h("div", { class: "cameras" });
  const recordingsByCamera = new Map();
  const jobs = jobsPanel({ experimentId: experiment.id, context, recordings: () => [...recordingsByCamera.values()].flat() });
  // Cameras made elsewhere (a script, the demo's worker) appear too: new ones are added, shown ones (and their
  // uploads in progress) stay as they are.
  const sections = new Map();
  let camerasTimer = null;
  const loadCameras = async () => {
    clearTimeout(camerasTimer);
    const cameras = await attempt("list the cameras", () => getJSON(`experiments/${experiment.id}/cameras`));
    if (!cameras || !context.current()) return;
    if (!cameras.length && !sections.size) {
      fill(camerasBox, h("p", { class: "empty" }, "No cameras yet: add one to upload its recordings."));
    }
    for (const camera of cameras.filter((c) => !sections.has(c.id))) {
      if (!sections.size) camerasBox.replaceChildren();
      const section = cameraSection(camera, context, (cam, recordings) => {
        recordingsByCamera.set(cam.id, recordings.map((r) => ({ ...r, camera_name: cam.name })));
        jobs.recordingsChanged();
      });
      sections.set(camera.id, section);
      camerasBox.append(section);
    }
    camerasTimer = setTimeout(loadCameras, 5000);
  };
  context.onLeave(() => clearTimeout(camerasTimer));
  page(
    container,
    experiment.name,
    h(
      "dl",
      { class: "facts" },
      h("dt", {}, "Plate"),
      h("dd", {}, experiment.plate || "–"),
      h("dt", {}, "Punch"),
      h("dd", {}, experiment.punch || "–"),
      h("dt", {}, "Test date"),
      h("dd", {}, experiment.test_date || "–"),
      h("dt", {}, "Notes"),
      h("dd", {}, experiment.notes || "–"),
    ),
    h("section", { "aria-labelledby": "cameras-title" }, h("h2", { id: "cameras-title" }, "Cameras and recordings"), camerasBox, cameraForm(experiment.id, loadCameras)),
    jobs.element,
  );
  await loadCameras();
}
