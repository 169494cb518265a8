// Jobs: the form that starts calibration and topography jobs (the JSON spec of POST /api/v1/jobs, with its
// defaults), live progress bars (Server-Sent Events), cancel and retry, the error text of a failed job, its log,
// its files and links to its report or viewer. What other pages share of a job (its name, progress, events and
// result links) is in job-helpers.js.
import { getJSON, postJSON, query, subscribe } from "../api.js";
import { specInputs } from "../specform.js";
import { exportPanel } from "./exports.js";
import { deleteButton } from "./deletion.js";
import { describeInput, followJob, isActive, JOB_KIND_NAMES, jobName, JobProgress, resultLink, resultMarks, shortId } from "./job-helpers.js";
import { attempt, field, fill, formatBytes, formatDuration, formatTime, h, newId, page, say, showError, table } from "../ui.js";

const MAX_STREAMS = 2; // a browser keeps 6 connections per server: the list's own stream, uploads and requests need the rest

// ---- the list of jobs (of an experiment, or all) ------------------------------------------------------------------

/**
 * A table of jobs that stays live without polling: the list's event stream (GET /jobs/events) says when a job is
 * added, moves on, ends or goes, and the list is read again then; active jobs also follow their own streams (at
 * most MAX_STREAMS at once) for their progress and log.
 */
export class JobList {
  constructor({ experimentId = null, context, label = "Jobs", onRefresh = () => {} }) {
    this.experimentId = experimentId;
    this.onRefresh = onRefresh;
    this.context = context;
    this.label = label;
    this.rows = new Map(); // job id -> { progress: JobProgress, row: <tr> }
    this.streams = new Map(); // job id -> close()
    this.tbody = h("tbody");
    this.empty = h("p", { class: "empty" }, "No jobs yet.");
    this.table = h(
      "table",
      { "aria-label": label, class: "jobs", hidden: true },
      // The list of all jobs names each one's experiment; an experiment's own list does not repeat it.
      h("thead", {}, h("tr", {}, ["Job", experimentId === null ? "Experiment" : null, "Camera", "Input", "Progress", "Started", "Results", ""]
        .map((t) => (t === null ? null : h("th", { scope: "col" }, t))))),
      this.tbody,
    );
    this.element = h("div", {}, this.empty, this.table);
    this.timer = null;
    this.closeList = null;
    context.onLeave(() => this.stop());
  }

  stop() {
    clearTimeout(this.timer);
    if (this.closeList) this.closeList();
    for (const close of this.streams.values()) close();
    this.streams.clear();
  }

  /** Read the list again whenever the jobs' event stream says something changed (at most every 500 ms). */
  listen() {
    if (this.closeList) return;
    this.closeList = subscribe(`jobs/events${query({ experiment_id: this.experimentId })}`, {
      jobs: () => {
        if (this.timer) return;
        this.timer = setTimeout(() => {
          this.timer = null;
          this.refresh();
        }, 500);
      },
    }, { onError: (message) => showError(message, "follow the jobs") });
  }

  async refresh() {
    const jobs = await attempt("list the jobs", () => getJSON(`jobs${query({ experiment_id: this.experimentId, limit: 200 })}`));
    if (!this.context.current()) return;
    if (jobs) {
      this.latest = jobs.items;
      this.show(jobs.items.filter((job) => job.kind !== "ingest" || isActive(job)));
      this.onRefresh(jobs.items);
    }
    this.listen();
  }

  show(jobs) {
    this.empty.hidden = jobs.length > 0;
    this.table.hidden = jobs.length === 0;
    const ordered = [];
    for (const job of jobs) {
      let entry = this.rows.get(job.id);
      if (!entry) {
        const progress = new JobProgress(job, { onRetried: () => this.refresh() });
        const results = h("td");
        const actions = h("td");
        const row = h(
          "tr",
          { "data-job": job.id },
          h("td", {}, h("a", { href: `#/jobs/${job.id}` }, jobName(job))),
          this.experimentId === null
            ? h("td", {}, job.experiment_id === null ? "–" : h("a", { href: `#/experiments/${job.experiment_id}` }, job.experiment_name || `#${job.experiment_id}`))
            : null,
          h("td", {}, job.camera_name || "–"),
          h("td", { class: "job-input" }, describeInput(job)),
          h("td", {}, progress.element),
          h("td", {}, formatTime(job.created_at)),
          results,
          actions,
        );
        entry = { progress, row, results, actions };
        this.rows.set(job.id, entry);
      }
      if (!this.streams.has(job.id)) entry.progress.update(job);
      fill(entry.results, resultLink(entry.progress.job), resultMarks(entry.progress.job));
      // Finished jobs can go (with their results); a queued or running one is cancelled first.
      fill(entry.actions, isActive(entry.progress.job) ? null : deleteButton(`jobs/${job.id}`, jobName(job), () => {
        this.rows.delete(job.id);
        this.refresh();
      }));
      ordered.push(entry.row);
      if (isActive(job) && !this.streams.has(job.id) && this.streams.size < MAX_STREAMS) this.follow(job.id, entry);
    }
    this.tbody.replaceChildren(...ordered);
  }

  follow(jobId, entry) {
    const close = followJob(jobId, {
      onJob: (job) => {
        entry.progress.update(job);
        fill(entry.results, resultLink(job), resultMarks(job));
        // Who listens to the list hears of each live change too, not only of the next refresh.
        if (this.latest) {
          this.latest = this.latest.map((known) => (known.id === job.id ? job : known));
          this.onRefresh(this.latest);
        }
      },
      onEnd: () => {
        this.streams.delete(jobId);
        if (this.context.current()) this.refresh();
      },
    });
    this.streams.set(jobId, close);
  }
}

// ---- the form ------------------------------------------------------------------------------------------------------

const RECORDING_KIND_OF_JOB = {
  camera_calibration: "camera_calibration",
  projector_calibration: "projector_calibration",
  topography: "test",
  procam_calibration: "coded",
  scan: "coded",
};
/** A camera–projector calibration takes at least this many chessboard poses (the spec's recording_ids). */
const MIN_POSES = 3;

/**
 * The form that starts a calibration or topography job, its inputs made from the API's schema of each kind's
 * spec (specform.js): the same parameters and defaults a script sends to POST /api/v1/jobs, shown as JSON under
 * the form. `recordings()` returns the experiment's recordings (with `camera_name`); `calibrations(cameraId,
 * kind)` resolves to [{ id, label, bad }] of its calibrations, newest first, and with kind "pairs" to its
 * consistent pairs [{ cameraCalibrationId, projector }].
 */
export function jobForm({ recordings, calibrations, onStarted }) {
  const kind = field(
    "Job kind",
    h("select", {}, Object.keys(RECORDING_KIND_OF_JOB).map((value) => h("option", { value }, JOB_KIND_NAMES[value]))),
  );
  const pickers = {
    recording_id: { label: "Recording", select: h("select", { required: true }) },
    camera_calibration_id: { label: "Camera calibration", select: h("select", { required: true }) },
    projector_calibration_id: { label: "Projector calibration", select: h("select", { required: true }) },
    // A topography's Gray code recorded at rest (docs/procam.md §5): a coded recording of the test's camera, or none.
    reference_code_recording_id: { label: "Gray code at rest", select: h("select") },
  };
  // Consent to use a calibration whose verdict is bad: shown (and required) only when a chosen one is bad.
  const consentBox = h("input", { type: "checkbox", id: newId("consent") });
  const consentText = h("label", { for: consentBox.id }, consentBox, " Use it although its verdict is bad (the results will carry the warning)");
  const consentWhy = h("small", { class: "hint" });
  const consent = h("div", { class: "field check-field consent wide-row", hidden: true }, consentText, consentWhy);
  pickers.accept_bad_calibration = { control: { element: consent, value: () => (consent.hidden ? null : consentBox.checked) } };
  // A camera–projector calibration's chessboard poses: one box per ready coded recording (a pose each, uploaded on
  // the experiment's recordings with its patterns-columns.json and patterns-rows.json), at least MIN_POSES ticked.
  const poseList = h("div", { class: "pose-list" });
  const poseCount = h("small", { class: "hint", "aria-live": "polite" });
  const poses = h(
    "fieldset",
    { class: "sub-spec wide-row", "aria-label": "Chessboard poses" },
    h("legend", {}, "Chessboard poses (coded recordings, one per pose)"),
    poseList,
    poseCount,
  );
  const tickedPoses = () => [...poseList.querySelectorAll("input[type=checkbox]:checked")].map((box) => Number(box.value));
  const checkPoses = () => {
    const n = tickedPoses().length;
    const first = poseList.querySelector("input[type=checkbox]");
    if (first) first.setCustomValidity(n < MIN_POSES ? `Tick at least ${MIN_POSES} chessboard poses (${n} ticked).` : "");
    poseCount.textContent = `${n} pose${n === 1 ? "" : "s"} ticked; at least ${MIN_POSES}, each a coded recording of the board under Gray code in both directions with an all-white and an all-black frame.`;
  };
  poseList.addEventListener("change", checkPoses);
  pickers.recording_ids = { control: { element: poses, value: () => (tickedPoses().length ? tickedPoses() : null) } };
  const inputs = h("div", { class: "spec-inputs grid-form" });
  const about = h("p", { class: "hint wide-row" });
  const specView = h("pre", { class: "spec", "aria-label": "Job spec (JSON)" });
  const submit = h("button", { type: "submit", class: "primary" }, "Start job");
  let current = null;

  const showSpec = () => {
    specView.textContent = current ? JSON.stringify(current.spec(), null, 2) : "";
  };
  const options = (select, items, emptyText) => {
    const previous = select.value;
    fill(select, items.length ? items.map((item) => h("option", { value: item.id }, item.label)) : h("option", { value: "" }, emptyText));
    if (items.some((item) => String(item.id) === previous)) select.value = previous;
  };
  const boardNote = h("p", { class: "hint wide-row", "aria-label": "Where the board comes from" });
  /** A camera calibration's board, prefilled from the recording's board.json when it has a readable one. */
  let prefilledFor = null; // the recording (and kind) last prefilled: a later refresh keeps what the user typed
  const prefillBoard = (chosen) => {
    const key = chosen ? `${kind.input.value}:${chosen.id}:${JSON.stringify(chosen.sidecars || {})}` : null;
    if (key === prefilledFor) return;
    prefilledFor = key;
    boardNote.textContent = "";
    if (!current || kind.input.value !== "camera_calibration" || !chosen) return;
    const board = chosen.sidecars && chosen.sidecars["board.json"];
    if (board && Number.isInteger(board.cols)) {
      current.set({ board: { cols: board.cols, rows: board.rows, square_mm: board.square_mm, origin: board.origin } });
      boardNote.textContent = `Board from the recording's board.json: ${board.cols} × ${board.rows} inner corners, ${board.square_mm} mm squares; change it here if it is wrong.`;
    } else {
      current.set({ board: null });
      boardNote.textContent = board && board.error
        ? `The recording's board.json could not be read (${board.error}): give the board here (tick Board).`
        : "The recording has no board.json: give the board here (tick Board), or add board.json on the recording's page.";
    }
    showSpec();
  };
  let cameraCals = [];
  let pairs = [];
  /** Only consistent pairs (the server's, GET /calibrations/pairs): the projector calibrations built on the chosen
   * camera calibration; then the consent when a chosen calibration is bad. */
  const refreshPairs = () => {
    const cameraId = Number(pickers.camera_calibration_id.select.value);
    const paired = pairs.filter((p) => p.cameraCalibrationId === cameraId).map((p) => p.projector);
    options(pickers.projector_calibration_id.select, paired,
      pairs.length ? "no projector calibration built on this camera calibration" : "no projector calibration yet");
    const chosenBad = [[pickers.camera_calibration_id.select, cameraCals], [pickers.projector_calibration_id.select, paired]]
      .map(([select, items]) => items.find((c) => String(c.id) === select.value && select.isConnected))
      .filter((c) => c && c.bad);
    consent.hidden = chosenBad.length === 0;
    consentBox.required = !consent.hidden;
    if (consent.hidden) consentBox.checked = false;
    consentWhy.textContent = chosenBad.map((c) => c.label).join("; ");
    showSpec();
  };
  const refreshCodes = (chosen) => {
    const select = pickers.reference_code_recording_id.select;
    const previous = select.value;
    const codes = chosen ? recordings().filter((r) => r.kind === "coded" && r.state === "ready" && r.camera_id === chosen.camera_id) : [];
    fill(select, [h("option", { value: "" }, "none (the projector table's match)"),
      ...codes.map((r) => h("option", { value: r.id }, `#${r.id} ${r.filename} (${r.frame_count} frames)`))]);
    if (codes.some((r) => String(r.id) === previous)) select.value = previous;
  };
  const refreshCalibrations = async () => {
    const chosen = recordings().find((r) => String(r.id) === pickers.recording_id.select.value);
    prefillBoard(chosen);
    refreshCodes(chosen);
    if (chosen) {
      [cameraCals, pairs] = await Promise.all([calibrations(chosen.camera_id, "camera"), calibrations(chosen.camera_id, "pairs")]);
      options(pickers.camera_calibration_id.select, cameraCals, "no camera calibration yet");
    }
    refreshPairs();
  };
  const refreshRecordings = () => {
    const wanted = RECORDING_KIND_OF_JOB[kind.input.value];
    const ready = recordings().filter((r) => r.kind === wanted && r.state === "ready");
    const choices = ready.map((r) => ({ id: r.id, label: `#${r.id} ${r.filename} (${r.camera_name}, ${r.frame_count} frames)` }));
    options(pickers.recording_id.select, choices, "no ready recording of this kind");
    const ticked = new Set(tickedPoses());
    fill(
      poseList,
      choices.length
        ? choices.map((choice) => {
            const id = newId("pose");
            const box = h("input", { type: "checkbox", id, value: choice.id, checked: ticked.has(choice.id) });
            return h("div", { class: "check-field" }, h("label", { for: id }, box, " ", choice.label));
          })
        : h("p", { class: "empty" }, "No ready coded recording yet: upload each chessboard pose as a recording of kind coded."),
    );
    checkPoses();
    return refreshCalibrations();
  };
  // The button waits while the choices are being fetched, so that nothing stale is sent.
  const busy = async (action) => {
    submit.disabled = true;
    try {
      await action();
    } finally {
      submit.disabled = false;
    }
  };
  const changeKind = () =>
    busy(async () => {
      try {
        current = await specInputs(kind.input.value, pickers);
        prefilledFor = null;
        about.textContent = current.description;
        inputs.replaceChildren(...current.elements, boardNote);
        for (const picker of Object.values(pickers)) picker.select?.closest(".field")?.classList.add("wide");
        await refreshRecordings();
      } catch (error) {
        showError(error, "read the job parameters from the server");
      }
    });

  kind.input.addEventListener("change", changeKind);
  pickers.recording_id.select.addEventListener("change", () => busy(refreshCalibrations));
  pickers.camera_calibration_id.select.addEventListener("change", refreshPairs);
  pickers.projector_calibration_id.select.addEventListener("change", refreshPairs);
  pickers.reference_code_recording_id.select.addEventListener("change", showSpec);
  const form = h(
    "form",
    {
      class: "card",
      "aria-label": "Start a job",
      oninput: showSpec,
      onchange: showSpec,
      onsubmit: async (event) => {
        event.preventDefault();
        submit.disabled = true;
        try {
          const job = await postJSON("jobs", current.spec());
          say(`${jobName(job)} started.`);
          onStarted(job);
        } catch (error) {
          showError(error, "start the job");
        } finally {
          submit.disabled = false;
        }
      },
    },
    h("h3", {}, "Start a job"),
    h("div", { class: "grid-form" }, kind.wrap, about),
    inputs,
    h("div", { class: "actions" }, submit),
    h("details", { class: "spec-box" }, h("summary", {}, "The spec sent to POST /api/v1/jobs"), specView),
  );
  const ready = changeKind();
  return { element: form, refresh: () => ready.then(() => busy(refreshRecordings)) };
}

/**
 * The calibrations of a camera, newest first: { id, label, bad, builtOn } (builtOn: a projector calibration's
 * camera calibration, null when unknown). The label names the calibration by id, camera and date, says what a
 * projector calibration was built on, and marks a bad verdict.
 */
export function calibrationChoice(c) {
  const verdict = c.verdict || (c.summary && c.summary.verdict) || null;
  const rms = c.summary && Number.isFinite(c.summary.rms_px) ? ` · RMS ${c.summary.rms_px.toFixed(3)} px` : "";
  const name = c.label || `${c.kind} calibration #${c.id} · ${formatTime(c.created_at)}`;
  const builtOn = c.kind === "projector" ? (c.camera_calibration_id ?? null) : null;
  const on = c.kind === "projector" ? ` · built on camera calibration #${builtOn ?? "?"}` : "";
  const bad = Boolean(c.bad) || verdict === "bad";
  // The mark first: a select shows only the start of a long option.
  const label = bad ? `⚠ BAD: ${name}${on}${rms}${c.bad_reason ? ` · ${c.bad_reason}` : ""}` : `${name}${on}${rms}${verdict ? ` · ${verdict}` : ""}`;
  return { id: c.id, label, bad, builtOn };
}

/** The calibrations of a camera of `kind` ("camera", "projector"), or its consistent pairs ("pairs": [{
 * cameraCalibrationId, projector }], each projector calibration with the camera calibration it was built on). */
async function calibrationsOf(experimentId, cameraId, kind) {
  if (kind === "pairs") {
    const found = await attempt("list the calibration pairs", () => getJSON(`calibrations/pairs${query({ camera_id: cameraId })}`));
    return (found || []).map(pairChoice);
  }
  const found = await attempt(`list the ${kind} calibrations`, () =>
    getJSON(`calibrations${query({ camera_id: cameraId, kind })}`),
  );
  return (found || []).map(calibrationChoice);
}

/** One consistent pair as the form offers it (GET /calibrations/pairs). */
export function pairChoice(pair) {
  return { cameraCalibrationId: pair.camera_calibration.id, projector: calibrationChoice(pair.projector_calibration) };
}

/** The jobs section of an experiment page: the live list and the form. */
export function jobsPanel({ experimentId, context, recordings, onJobs = () => {} }) {
  let form = null;
  let succeeded = -1;
  const list = new JobList({
    experimentId,
    context,
    label: "Jobs of this experiment",
    // A calibration that has just succeeded becomes a choice of the form.
    onRefresh: (jobs) => {
      onJobs(jobs);
      const now = jobs.filter((job) => job.state === "succeeded").length;
      if (now !== succeeded && form) form.refresh();
      succeeded = now;
    },
  });
  form = jobForm({
    recordings,
    calibrations: (cameraId, kind) => calibrationsOf(experimentId, cameraId, kind),
    onStarted: () => list.refresh(),
  });
  list.refresh();
  return {
    element: h("section", { "aria-labelledby": "jobs-title" }, h("h2", { id: "jobs-title" }, "Jobs and results"), list.element, form.element),
    recordingsChanged: () => form.refresh(),
  };
}

// ---- pages ---------------------------------------------------------------------------------------------------------

export async function renderJobs(container, _params, context) {
  const list = new JobList({ context, label: "All jobs" });
  page(container, "Jobs", list.element);
  await list.refresh();
}

const MAX_CHUNK_ROWS = 40;

/** A chunked job's parts: a table when there are few, else how many are in each state and which workers. */
function chunksView(chunks) {
  if (!chunks.length) return null;
  const count = (state) => chunks.filter((c) => c.state === state).length;
  const workers = [...new Set(chunks.map((c) => c.worker).filter(Boolean))];
  const line = h("p", { class: "facts" },
    `${chunks.length} chunks: ${count("done")} done, ${count("running")} running, ${count("pending")} pending`,
    workers.length ? ` · workers: ${workers.join(", ")}` : "");
  if (chunks.length > MAX_CHUNK_ROWS) return line;
  return [
    line,
    table(
      "Chunks",
      [
        { title: "Phase", value: (c) => (c.phase === undefined ? "–" : String(c.phase)) },
        { title: "Chunk", value: (c) => String(c.index) },
        { title: "Frames", value: (c) => `${c.first_frame}–${c.stop_frame - 1}` },
        { title: "State", value: (c) => c.state },
        { title: "Done", value: (c) => `${c.done}/${c.stop_frame - c.first_frame}` },
        { title: "Worker", value: (c) => c.worker || "–" },
        { title: "Took", value: (c) => (c.started_at && c.finished_at ? formatDuration((new Date(c.finished_at) - new Date(c.started_at)) / 1000) : "–") },
      ],
      chunks,
    ),
  ];
}

function logLine(line) {
  return h("div", { class: `log-${line.level}` }, `${formatTime(line.at)}  ${line.level.padEnd(7)} ${line.message}`);
}

/** [first, …, last] frame numbers from a result's [first, last]. */
const rangeOf = ([first, last]) => Array.from({ length: last - first + 1 }, (_, i) => first + i);

export async function renderJob(container, { id }, context) {
  const job = await attempt("open the job", () => getJSON(`jobs/${id}`));
  if (!job || !context.current()) return;
  const facts = h("dl", { class: "facts" });
  const files = h("div");
  const links = h("p");
  const resultBox = h("div");
  const chunksBox = h("div");
  const logBox = h("div", { class: "log", role: "log", "aria-label": "Job log", tabindex: 0 });
  const drawFacts = (current) => {
    fill(
      facts,
      [
        ["Kind", JOB_KIND_NAMES[current.kind] || current.kind],
        ["State", current.stopping ? "stopping" : current.state],
        ["Input", current.spec && current.spec.recording_id ? describeInput(current) : null],
        ["Attempt", current.retry_of ? [`${current.attempt}, retry of `, h("a", { href: `#/jobs/${current.retry_of}` }, shortId(current.retry_of))] : String(current.attempt)],
        ["Retried as", current.retried_by ? h("a", { href: `#/jobs/${current.retried_by}` }, shortId(current.retried_by)) : null],
        ["Worker", current.worker || "–"],
        ["Created", formatTime(current.created_at)],
        ["Started", formatTime(current.started_at)],
        ["Finished", formatTime(current.finished_at)],
        ["Experiment", current.experiment_id ? h("a", { href: `#/experiments/${current.experiment_id}` }, current.experiment_name || `#${current.experiment_id}`) : null],
        ["Camera", current.camera_name || null],
      ]
        .filter(([, value]) => value !== null)
        .map(([term, value]) => [h("dt", {}, term), h("dd", {}, value)]),
    );
    fill(
      files,
      table(
        "Result files",
        [
          { title: "File", value: (f) => h("a", { href: f.url, download: f.name }, f.name) },
          { title: "Size", value: (f) => formatBytes(f.size_bytes) },
          { title: "SHA-256", value: (f) => h("code", {}, f.sha256.slice(0, 16)) },
        ],
        current.files,
        { empty: "No files." },
      ),
    );
    fill(links, resultLink(current), resultMarks(current));
    const scalars = Object.entries(current.result || {}).filter(([, v]) => v === null || ["number", "string", "boolean"].includes(typeof v));
    fill(
      resultBox,
      scalars.length
        ? table("Result", [{ title: "Quantity", value: (r) => r[0] }, { title: "Value", value: (r) => (typeof r[1] === "number" ? String(Number(r[1].toPrecision(6))) : String(r[1])) }], scalars)
        : null,
    );
    fill(chunksBox, chunksView(current.chunks));
  };
  const progress = new JobProgress(job, {
    onRetried: (retried) => {
      window.location.hash = `#/jobs/${retried.id}`;
    },
    onChange: drawFacts,
  });
  page(
    container,
    jobName(job),
    isActive(job) ? null : h("p", {}, deleteButton(`jobs/${job.id}`, jobName(job), () => {
      window.location.hash = job.experiment_id ? `#/experiments/${job.experiment_id}` : "#/jobs";
    }, { small: false })),
    progress.element,
    links,
    facts,
    resultBox,
    chunksBox,
    h("details", { class: "spec-box" }, h("summary", {}, "Spec and provenance"), h("pre", {}, JSON.stringify({ spec: job.spec, provenance: job.provenance }, null, 2))),
    h("h2", {}, "Files"),
    files,
    job.kind === "topography" && job.state === "succeeded" && job.result && Array.isArray(job.result.frames)
      ? exportPanel(job, { frames: rangeOf(job.result.frames), context }).element
      : null,
    h("h2", {}, "Log"),
    logBox,
  );
  drawFacts(job);
  let lastLine = 0;
  const addLines = (lines) => {
    for (const line of lines) {
      if (line.id <= lastLine) continue;
      lastLine = line.id;
      logBox.append(logLine(line));
    }
    logBox.scrollTop = logBox.scrollHeight;
  };
  const lines = await attempt("read the job's log", () => getJSON(`jobs/${id}/log`));
  if (!context.current()) return;
  if (lines) addLines(lines);
  if (!lines || !lines.length) logBox.replaceChildren(h("div", { class: "empty" }, "No log lines yet."));
  if (isActive(job)) {
    const close = followJob(job.id, {
      onJob: (current) => progress.update(current),
      onLog: (line) => {
        if (lastLine === 0) logBox.replaceChildren();
        addLines([line]);
      },
      onEnd: () => {},
    });
    context.onLeave(close);
  }
}
