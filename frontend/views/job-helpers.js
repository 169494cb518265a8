// What every page that shows jobs shares: their names, what they work on, their progress with its buttons, their
// event stream, and the links to (and marks on) their results. Not here: the jobs list and page and the form
// (jobs.js), exports (exports.js), deletes (deletion.js), which all build on these.
import { postJSON, subscribe } from "../api.js";
import { formatDuration, h, say, showError } from "../ui.js";

export const JOB_KIND_NAMES = {
  ingest: "Ingest",
  camera_calibration: "Camera calibration",
  projector_calibration: "Projector calibration",
  topography: "Topography",
  export: "Export",
  comparison: "Comparison",
  selftest: "Self-test",
  procam_calibration: "Camera–projector calibration",
  scan: "Scan",
};
export const ACTIVE = ["queued", "running"];

export const shortId = (id) => id.slice(0, 8);
export const jobName = (job) => `${JOB_KIND_NAMES[job.kind] || job.kind} ${shortId(job.id)}`;
export const isActive = (job) => ACTIVE.includes(job.state) || job.stopping;

/** Download links of a succeeded job's files (an export's files, wherever the job is listed). */
export function downloadLinks(job) {
  if (job.state !== "succeeded" || !job.files || !job.files.length) return null;
  return job.files.map((file, i) => [i ? " " : "", h("a", { href: file.url, download: file.name, class: "download" }, `Download ${file.name}`)]);
}

/** Where a finished job's results are shown: its report, its viewer, or (an export) its files. */
export function resultLink(job) {
  if (job.state !== "succeeded") return null;
  if (job.kind === "export") return downloadLinks(job);
  if (["camera_calibration", "projector_calibration", "procam_calibration"].includes(job.kind)) {
    return h("a", { href: `#/jobs/${job.id}/report` }, "Calibration report");
  }
  if (job.kind === "topography") return h("a", { href: `#/jobs/${job.id}/viewer` }, "Topography viewer");
  if (job.kind === "comparison") return h("a", { href: `#/jobs/${job.id}/comparison` }, "Comparison view");
  if (job.kind === "scan") return h("a", { href: `#/jobs/${job.id}/scan` }, "Scan view");
  return null;
}

/** What a finished job's results must be read with: a calibration whose verdict is bad, the warnings a job using
 * one carries (consented to). Shown wherever the job is listed. */
export function resultMarks(job) {
  const marks = [];
  if (job.state === "succeeded" && job.result && job.result.verdict === "bad") {
    marks.push(" ", h("span", { class: "badge verdict-bad", title: (job.result.reasons || []).join("; ") }, "verdict: bad"));
  }
  for (const warning of job.warnings || []) marks.push(h("p", { class: "result-warning" }, `⚠ ${warning}`));
  return marks;
}

// ---- one job's progress, with its buttons ------------------------------------------------------------------

/** A live view of a job: state, progress bar, stage, time left, error, cancel/retry. `update(job)` redraws it. */
export class JobProgress {
  constructor(job, { onRetried = () => {}, onChange = () => {} } = {}) {
    this.onRetried = onRetried;
    this.onChange = onChange;
    this.bar = h("progress", { max: 1, "aria-label": `Progress of ${jobName(job)}` });
    this.text = h("span", { class: "progress-text" });
    this.stateBadge = h("span", { class: "badge" });
    this.error = h("p", { class: "error job-error", hidden: true });
    this.cancelButton = h("button", { type: "button", class: "small", "aria-label": `Cancel ${jobName(job)}`, onclick: () => this.cancel() }, "Cancel");
    this.retryButton = h("button", { type: "button", class: "small", "aria-label": `Retry ${jobName(job)}`, onclick: () => this.retry() }, "Retry");
    this.element = h(
      "div",
      { class: "job-progress" },
      this.stateBadge,
      this.bar,
      this.text,
      this.cancelButton,
      this.retryButton,
      this.error,
    );
    this.update(job);
  }

  update(job) {
    this.job = job;
    const p = job.progress;
    this.stateBadge.textContent = job.stopping ? "stopping" : job.state;
    this.stateBadge.className = `badge state-${job.state}`;
    if (job.state === "succeeded") {
      this.bar.value = 1;
    } else if (p.fraction === null || p.fraction === undefined) {
      if (job.state === "queued" || job.state === "running") this.bar.removeAttribute("value"); // indeterminate
      else this.bar.value = 0;
    } else {
      this.bar.value = p.fraction;
    }
    const percent = job.state === "succeeded" ? 100 : p.fraction !== null && p.fraction !== undefined ? Math.floor(p.fraction * 100) : null;
    const parts = [];
    if (percent !== null) parts.push(`${percent} %`);
    // The stage and the count say what a running job is doing; a finished one is not "writing" any more.
    if (p.stage && isActive(job)) parts.push(p.stage);
    if (p.total && isActive(job)) parts.push(`${p.done}/${p.total}`);
    if (isActive(job) && p.eta_s !== null && p.eta_s !== undefined) parts.push(`${formatDuration(p.eta_s)} left`);
    if (!isActive(job) && job.duration_s !== null && job.duration_s !== undefined) parts.push(`took ${formatDuration(job.duration_s)}`);
    this.text.textContent = parts.join(" · ");
    this.error.textContent = job.error || "";
    this.error.hidden = !job.error;
    this.cancelButton.hidden = !ACTIVE.includes(job.state) || job.stopping;
    this.retryButton.hidden = !["failed", "cancelled"].includes(job.state) || job.stopping || Boolean(job.retried_by);
    this.onChange(job);
  }

  async cancel() {
    try {
      this.update(await postJSON(`jobs/${this.job.id}/cancel`));
      say(`${jobName(this.job)} cancelled.`);
    } catch (error) {
      showError(error, `cancel ${jobName(this.job)}`);
    }
  }

  async retry() {
    try {
      const retried = await postJSON(`jobs/${this.job.id}/retry`);
      say(`${jobName(this.job)} started again as ${jobName(retried)}.`);
      this.retryButton.hidden = true;
      this.onRetried(retried);
    } catch (error) {
      showError(error, `retry ${jobName(this.job)}`);
    }
  }
}

/** Follow a job's events; returns the function that stops following. */
export function followJob(jobId, { onJob, onLog = () => {}, onEnd = () => {} }) {
  return subscribe(
    `jobs/${jobId}/events`,
    { job: onJob, log: onLog, end: onEnd },
    { onError: (message) => showError(message, `follow job ${shortId(jobId)}`) },
  );
}

/** What a job works on, in words, from its spec. */
export function describeInput(job) {
  const spec = job.spec || {};
  const parts = [];
  if (spec.recording_id) parts.push(h("a", { href: `#/recordings/${spec.recording_id}` }, `recording ${spec.recording_id}`));
  if (spec.camera_calibration_id) parts.push(`camera cal. ${spec.camera_calibration_id}`);
  if (spec.projector_calibration_id) parts.push(`projector cal. ${spec.projector_calibration_id}`);
  if (spec.job_id) parts.push(`job ${shortId(spec.job_id)}`);
  if (spec.simulation_id) parts.push(`simulation ${spec.simulation_id}`);
  if (spec.format) parts.push(spec.format);
  return parts.flatMap((part, i) => (i ? [", ", part] : [part]));
}
