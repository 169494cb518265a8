// The calibration report of a calibration job (parameters ± standard errors, verdict, per-frame RMS, residual
// vectors, the projector table): drawn from the job's results.
import { getJSON } from "../api.js";
import { attempt, h, page } from "../ui.js";
import { jobName } from "./jobs.js";

export async function renderCalibration(container, { id }, context) {
  const job = await attempt("open the job", () => getJSON(`jobs/${id}`));
  if (!job || !context.current()) return;
  page(container, `Calibration report: ${jobName(job)}`, h("p", {}, h("a", { href: `#/jobs/${job.id}` }, "The job")),
    h("pre", {}, JSON.stringify(job.result, null, 2)));
}
