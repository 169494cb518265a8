// "System": is every part of the server up (database, Redis, workers), and the version.
import { getHealth, postJSON } from "../api.js";
import { specInputs } from "../specform.js";
import { h, page, say, showError, table } from "../ui.js";
import { followJob, jobName, JobProgress } from "./job-helpers.js";

function part(ok, detail) {
  return ok ? "up" : `down: ${detail}`;
}

/** One line for the footer of every page. */
export function healthSummary(health) {
  return health.ok
    ? `All parts are up · ${health.workers} worker${health.workers === 1 ? "" : "s"} · fringelab ${health.version}`
    : `Not ready: ${health.failing.join(", ")} down · fringelab ${health.version}`;
}

export async function renderSystem(container, _params, context) {
  const body = h("div", {}, h("p", {}, "Checking…"));
  page(container, "System health", body, h("p", {}, h("a", { href: "/api/docs" }, "API documentation (OpenAPI)")), selftestForm(context));
  const refresh = async () => {
    try {
      const health = await getHealth();
      if (!context.current()) return;
      body.replaceChildren(
        table(
          "Health of each part",
          [
            { title: "Part", value: (row) => row[0] },
            { title: "State", value: (row) => row[1] },
          ],
          [
            ["Version", health.version],
            ["Database", part(health.database.ok, health.database.detail)],
            ["Redis", part(health.redis.ok, health.redis.detail)],
            ["Live workers", String(health.workers)],
          ],
        ),
        h("p", { class: health.ok ? "ok" : "bad" }, healthSummary(health)),
      );
    } catch (error) {
      showError(error, "check the server's health");
    }
  };
  await refresh();
  const timer = setInterval(refresh, 5000);
  context.onLeave(() => clearInterval(timer));
}

/** Run the job system's self-test (synthetic frames on every worker) and watch it live; its parameters come
 * from the API's schema of the selftest spec. */
function selftestForm(context) {
  const inputs = h("div", { class: "grid-form wide-row" });
  const about = h("p", { class: "hint wide-row" });
  const progressBox = h("div", { class: "selftest-progress" });
  let current = null;
  specInputs("selftest")
    .then((made) => {
      current = made;
      about.textContent = made.description;
      inputs.replaceChildren(...made.elements);
    })
    .catch((error) => showError(error, "read the self-test's parameters from the server"));
  const watch = (job) => {
    const link = h("a", { href: `#/jobs/${job.id}` }, jobName(job));
    const progress = new JobProgress(job, { onRetried: watch });
    progressBox.replaceChildren(h("p", {}, link), progress.element);
    context.onLeave(followJob(job.id, { onJob: (latest) => progress.update(latest) }));
  };
  return h(
    "form",
    {
      class: "card grid-form",
      "aria-label": "Self-test of the workers",
      onsubmit: async (event) => {
        event.preventDefault();
        try {
          const job = await postJSON("jobs", current.spec());
          say(`${jobName(job)} started.`);
          watch(job);
        } catch (error) {
          showError(error, "start the self-test");
        }
      },
    },
    h("h2", {}, "Self-test of the workers"),
    about,
    inputs,
    h("div", { class: "actions" }, h("button", { type: "submit" }, "Run the self-test")),
    h("div", { class: "wide-row" }, progressBox),
  );
}
