// The queue of a shared server: running jobs with the worker each runs on, waiting jobs in the order they will
// start, and the storage each user's experiments take (GET /api/v1/queue, /api/v1/storage). Live: it listens to
// the jobs' event stream (GET /api/v1/jobs/events), which says when any job starts, moves on or ends.
import { getJSON, subscribe } from "../api.js";
import { attempt, fill, formatBytes, formatTime, h, page, table } from "../ui.js";
import { JOB_KIND_NAMES, shortId } from "./job-helpers.js";

const jobLink = (job) => h("a", { href: `#/jobs/${job.id}` }, `${JOB_KIND_NAMES[job.kind] || job.kind} ${shortId(job.id)}`);
const experimentLink = (job) => (job.experiment_id ? h("a", { href: `#/experiments/${job.experiment_id}` }, job.experiment_name || `#${job.experiment_id}`) : "–");

export async function renderQueue(container, _params, context) {
  const running = h("div");
  const waiting = h("div");
  const workers = h("p", { class: "facts", "aria-label": "Workers busy" });
  const storage = h("div");
  page(container, "Queue",
    h("h2", {}, "Running"), workers, running,
    h("h2", {}, "Waiting"), waiting,
    h("h2", {}, "Storage per user"), storage);
  const draw = async () => {
    const [queue, used] = await Promise.all([
      attempt("read the queue", () => getJSON("queue")),
      attempt("read the storage", () => getJSON("storage")),
    ]);
    if (!context.current()) return;
    if (queue) {
      const busy = Object.entries(queue.workers);
      fill(workers, busy.length ? `Busy workers: ${busy.map(([w, n]) => `${w} (${n})`).join(", ")}` : "No worker is busy.");
      fill(running,
        table("Running jobs", [
          { title: "Job", value: jobLink },
          { title: "Worker", value: (j) => j.worker || "–" },
          { title: "Experiment", value: experimentLink },
          { title: "Owner", value: (j) => j.owner },
          { title: "Started", value: (j) => formatTime(j.started_at) },
        ], queue.running, { empty: "Nothing runs now." }),
        queue.hidden_running ? h("p", { class: "hint" }, `and ${queue.hidden_running} of other users' experiments`) : null);
      fill(waiting,
        table("Waiting jobs", [
          { title: "Place", value: (j) => String(j.position), class: "num" },
          { title: "Job", value: jobLink },
          { title: "Experiment", value: experimentLink },
          { title: "Owner", value: (j) => j.owner },
          { title: "Queued", value: (j) => formatTime(j.created_at) },
        ], queue.waiting, { empty: "Nothing waits." }),
        queue.hidden_waiting ? h("p", { class: "hint" }, `and ${queue.hidden_waiting} of other users' experiments (they count for the places)`) : null);
    }
    if (used) {
      fill(storage, table("Storage per user", [
        { title: "User", value: (r) => r.user },
        { title: "Experiments", value: (r) => String(r.experiments), class: "num" },
        { title: "Recordings", value: (r) => `${r.recordings} (${formatBytes(r.recording_bytes)})`, class: "num" },
        { title: "Results", value: (r) => formatBytes(r.result_bytes), class: "num" },
        { title: "In all", value: (r) => formatBytes(r.recording_bytes + r.result_bytes), class: "num" },
      ], used, { empty: "Nothing stored yet." }));
    }
  };
  await draw();
  if (!context.current()) return;
  let pending = null;
  const close = subscribe("jobs/events", {
    jobs: () => {
      // Several changes at once make one redraw.
      clearTimeout(pending);
      pending = setTimeout(draw, 200);
    },
  });
  context.onLeave(() => {
    clearTimeout(pending);
    close();
  });
}
