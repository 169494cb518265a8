// Experiments: the list (with a form to create one, and the demo button) and an experiment's page with its
// cameras, their recordings and uploads, its jobs and its results.
import { apiUrl, getJSON, postJSON } from "../api.js";
import { attempt, field, fill, formatBytes, formatTime, h, page, say, showError, table } from "../ui.js";
import { Uploader } from "../upload.js";
import { jobName } from "./job-helpers.js";
import { jobsPanel } from "./jobs.js";
import { deleteButton } from "./deletion.js";
import { simulationsPanel } from "./simulations.js";

/** Show the current route again (after a delete changed what it lists). */
const reshow = () => window.dispatchEvent(new HashChangeEvent("hashchange"));

export const KIND_NAMES = {
  camera_calibration: "Camera calibration",
  projector_calibration: "Projector calibration",
  test: "Test",
  coded: "Coded sequence (Gray code)",
};

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
  // The virtual tests (POST /demo `scenario`): the paper's, and the hard ones the method is built for.
  const demoScenario = field(
    "Virtual test",
    h("select", {},
      h("option", { value: "quasi-static" }, "Quasi-static punch test (the paper's)"),
      h("option", { value: "fast" }, "Fast: large motion per frame, springback at perforation"),
      h("option", { value: "petals" }, "Petals: fast, with radial cracks and petals around the hole"),
      h("option", { value: "highlight" }, "Highlight: a specular highlight on the plate"),
      h("option", { value: "shadow" }, "Shadow: fast, the punch shadows part of the stripes"),
      h("option", { value: "hard" }, "Hard: all of these at once"),
      h("option", { value: "dim" }, "Dim: soft partial shadows, photon noise, a third of the grey range")),
  );
  const demo = h(
    "button",
    {
      type: "button",
      class: "primary",
      onclick: async () => {
        demo.disabled = true;
        try {
          const cameras = demoCameras.input.value;
          const made = await postJSON("demo", { cameras: cameras.split(","), scenario: demoScenario.input.value });
          // The experiment page shows the demo's steps at once, from the first second.
          window.location.hash = `#/experiments/${made.experiment_id}?demo=${cameras}&since=${Date.now()}`;
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
      demoScenario.wrap,
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
        { title: "", value: (e) => deleteButton(`experiments/${e.id}`, `experiment ${e.name}`, reshow) },
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

function recordingsTable(camera, recordings, onDeleted) {
  return table(
    `Recordings of ${camera.name}`,
    [
      { title: "Recording", value: (r) => h("a", { href: `#/recordings/${r.id}` }, `#${r.id} ${r.filename}`) },
      { title: "Kind", value: (r) => KIND_NAMES[r.kind] || r.kind },
      { title: "State", value: recordingState },
      { title: "Frames", value: (r) => (r.frame_count ? `${r.frame_count} × ${r.width_px}×${r.height_px} px, ${r.bit_depth} bit` : "–") },
      { title: "Size", value: (r) => formatBytes(r.size_bytes) },
      { title: "", value: (r) => deleteButton(`recordings/${r.id}`, `recording ${r.id} ${r.filename}`, onDeleted) },
    ],
    recordings,
    { empty: "No recordings yet." },
  );
}

function cameraForm(experimentId, onAdded) {
  // Examples as placeholders, never as values: a camera added in a hurry must not get a made-up sensor.
  const name = field("Camera name", h("input", { type: "text", required: true, maxlength: 100, placeholder: "e.g. left" }));
  const width = field("Image width (px)", h("input", { type: "number", required: true, min: 1, step: 1, placeholder: "e.g. 1024" }));
  const height = field("Image height (px)", h("input", { type: "number", required: true, min: 1, step: 1, placeholder: "e.g. 1024" }));
  const pitch = field("Pixel pitch u (µm)", h("input", { type: "number", required: true, min: 0.01, step: "any", placeholder: "e.g. 20" }),
    "Along a row (the image's width). Data sheets give the pixel pitch (or pixel size, cell size) in µm: one number for square pixels, or horizontal × vertical = u × v.");
  const pitchV = field("Pixel pitch v (µm)", h("input", { type: "number", min: 0.01, step: "any", placeholder: "as u" }),
    "Along a column (the height); empty for square pixels. From a sensor size instead: pitch = sensor width (mm) × 1000 / width (px), and with the heights for v.");
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
            pixel_pitch_v_um: pitchV.input.value === "" ? null : Number(pitchV.input.value),
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
    pitchV.wrap,
    h("div", { class: "actions" }, h("button", { type: "submit" }, "Add camera")),
  );
}

/** A camera's box: its facts, its recordings and an upload control. `refreshers` gets its refresh, which the
 * page calls when the jobs' event stream says something changed (an ingest moved on: a recording's state). */
function cameraSection(camera, context, onRecordingsChanged, refreshers) {
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
      fill(recordingsBox, recordingsTable(camera, recordings, refresh));
      onRecordingsChanged(camera, recordings);
    }
    // Each upload starts an ingest job, whose events refresh this list; a recording still uploading (no job
    // yet) is looked at again in a moment.
    if (recordings.some((r) => r.state === "uploading")) timer = setTimeout(refresh, 2000);
  };
  refreshers.set(camera.id, refresh);
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
    h("div", { class: "camera-head" }, h("h3", {}, `Camera ${camera.name}`), deleteButton(`cameras/${camera.id}`, `camera ${camera.name}`, reshow)),
    h(
      "p",
      { class: "facts" },
      `${camera.image_width_px} × ${camera.image_height_px} px, pixel pitch `,
      camera.pixel_pitch_v_um && camera.pixel_pitch_v_um !== camera.pixel_pitch_um
        ? `${Number(camera.pixel_pitch_um.toPrecision(6))} × ${Number(camera.pixel_pitch_v_um.toPrecision(6))} µm (u × v)`
        : `${Number(camera.pixel_pitch_um.toPrecision(6))} µm (square pixels)`,
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
  const demoCameras = (context.query.get("demo") || "").split(",").filter(Boolean);
  const demo = demoCameras.length ? new DemoProgress(demoCameras, Number(context.query.get("since")) || Date.now(), context) : null;
  const refreshers = new Map(); // camera id → refresh of its recordings
  const jobs = jobsPanel({
    experimentId: experiment.id,
    context,
    recordings: () => [...recordingsByCamera.values()].flat(),
    // The jobs' event stream drives this page: a job added, moving on or ending may mean new cameras or
    // recordings (the demo's worker) or a recording's new state (its ingest).
    onJobs: (items) => {
      if (demo) demo.jobsChanged(items);
      latestJobs = items;
      simulations.jobsChanged();
      const signature = JSON.stringify(items.map((j) => [j.id, j.state]));
      if (signature === lastJobs) return;
      lastJobs = signature;
      loadCameras();
      for (const refresh of refreshers.values()) refresh();
    },
  });
  let lastJobs = null;
  let latestJobs = [];
  // The experiment's finite-element simulations and their comparison with its succeeded topography results.
  const simulations = simulationsPanel({
    experimentId: experiment.id,
    context,
    topographies: () => latestJobs
      .filter((job) => job.kind === "topography" && job.state === "succeeded")
      .map((job) => {
        const recording = [...recordingsByCamera.values()].flat().find((r) => r.id === (job.spec && job.spec.recording_id));
        const source = recording ? ` · recording #${recording.id} ${recording.filename} (${recording.camera_name})` : "";
        const frames = job.result && Array.isArray(job.result.frames) ? ` · frames ${job.result.frames[0]}–${job.result.frames[1]}` : "";
        return { id: job.id, label: `${jobName(job)}${source}${frames}` };
      }),
  });
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
        if (demo) demo.recordingsChanged(cam, recordings);
      }, refreshers);
      sections.set(camera.id, section);
      camerasBox.append(section);
    }
    if (demo) demo.camerasChanged(cameras);
    // The demo's worker adds its cameras before any of their jobs exist: look every second until they are all
    // here. Otherwise new cameras come with jobs' events, or from this page's form.
    if (demo && !demo.allCameras()) camerasTimer = setTimeout(loadCameras, 1000);
  };
  context.onLeave(() => clearTimeout(camerasTimer));
  page(
    container,
    experiment.name,
    h("p", {}, deleteButton(`experiments/${experiment.id}`, `experiment ${experiment.name}`, () => {
      window.location.hash = "#/experiments";
    }, { small: false })),
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
    demo ? demo.element : null,
    h("section", { "aria-labelledby": "cameras-title" }, h("h2", { id: "cameras-title" }, "Cameras and recordings"), camerasBox, cameraForm(experiment.id, loadCameras)),
    jobs.element,
    simulations.element,
  );
  await loadCameras();
}

// ---- the demo's progress -------------------------------------------------------------------------------------------

const DEMO_STEPS = [
  ["camera", "camera added"],
  ["simulated", "recordings simulated"],
  ["ingested", "recordings checked"],
  ["camera_calibration", "camera calibration"],
  ["projector_calibration", "projector calibration"],
  ["topography", "topography"],
];

/**
 * What the demo's worker has done for each virtual camera, shown from the first second after the click (the
 * simulation itself takes tens of seconds before anything else appears): a step list per camera with the time
 * since the click, drawn from the cameras, recordings and jobs the page reads anyway.
 */
class DemoProgress {
  constructor(cameras, since, context) {
    this.names = cameras;
    this.since = since;
    this.state = Object.fromEntries(cameras.map((name) => [name, { camera: null, recordings: [], jobs: [] }]));
    this.cameraIds = new Map();
    this.list = h("ul", { class: "demo-steps", "aria-label": "Demo progress" });
    this.clock = h("span", { class: "facts" });
    this.title = h("span", {}, "Demo in progress ");
    this.element = h("section", { class: "card demo-progress", "aria-labelledby": "demo-title" },
      h("h2", { id: "demo-title" }, this.title, this.clock), this.list);
    this.timer = setInterval(() => this.draw(), 1000);
    context.onLeave(() => clearInterval(this.timer));
    this.draw();
  }

  allCameras() {
    return this.names.every((name) => this.state[name].camera);
  }

  camerasChanged(cameras) {
    for (const camera of cameras) {
      if (!this.state[camera.name]) continue;
      this.state[camera.name].camera = camera;
      this.cameraIds.set(camera.id, camera.name);
    }
    this.draw();
  }

  recordingsChanged(camera, recordings) {
    if (this.state[camera.name]) this.state[camera.name].recordings = recordings;
    this.draw();
  }

  jobsChanged(jobs) {
    this.jobs = jobs;
    this.draw();
  }

  /** [step, "done" | "doing" | "waiting" | "failed", detail] for one camera. */
  steps(name) {
    const { camera, recordings } = this.state[name];
    const ids = new Set(recordings.map((r) => r.id));
    const jobs = (this.jobs || []).filter((job) => ids.has(job.spec && job.spec.recording_id));
    const jobOf = (kind) => jobs.find((job) => job.kind === kind);
    const out = [];
    let before = "done";
    const push = (key, status, detail = "") => {
      const shown = before === "done" ? status : "waiting";
      out.push([key, shown, detail]);
      before = shown;
    };
    push("camera", camera ? "done" : "doing");
    push("simulated", recordings.length >= 3 ? "done" : "doing", recordings.length ? `${recordings.length} of 3` : "");
    const ready = recordings.filter((r) => r.state === "ready").length;
    const invalid = recordings.some((r) => r.state === "invalid");
    push("ingested", invalid ? "failed" : recordings.length >= 3 && ready === recordings.length ? "done" : "doing", `${ready} of 3`);
    for (const kind of ["camera_calibration", "projector_calibration", "topography"]) {
      const job = jobOf(kind);
      const status = !job ? "doing" : job.state === "succeeded" ? "done" : ["failed", "cancelled"].includes(job.state) ? "failed" : "doing";
      const percent = job && job.progress && Number.isFinite(job.progress.fraction) ? `${Math.floor(100 * job.progress.fraction)} %` : "";
      push(kind, status, job && status === "doing" ? percent : "");
    }
    return out;
  }

  draw() {
    const seconds = Math.max(0, Math.round((Date.now() - this.since) / 1000));
    const finished = this.names.every((name) => this.steps(name).every(([, status]) => status === "done"));
    this.title.textContent = finished ? "Demo done " : "Demo in progress ";
    this.clock.textContent = finished ? `· in about ${seconds} s` : `· ${seconds} s since the click`;
    if (finished) clearInterval(this.timer);
    const labels = Object.fromEntries(DEMO_STEPS);
    const mark = { done: "✓", doing: "…", waiting: "·", failed: "✗" };
    fill(this.list, this.names.map((name) => h("li", {}, h("strong", {}, `Camera ${name}: `),
      this.steps(name).map(([key, status, detail], i) => [i ? " → " : "",
        h("span", { class: `demo-step demo-${status}`, "data-step": key, "data-status": status },
          `${mark[status]} ${labels[key]}${detail ? ` (${detail})` : ""}`)]))));
  }
}
