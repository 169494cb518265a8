// Deleting experiments, cameras, recordings and jobs: a button that first asks the server what goes with the
// thing (GET .../deletion: cameras, recordings, jobs, calibrations, bytes, and the jobs that stop it now) and
// shows that in a confirmation dialog; "Delete" is only offered when nothing stops it.
import { deleteJSON, getJSON } from "../api.js";
import { h, say, showError } from "../ui.js";
import { jobName } from "./job-helpers.js";

/** A confirmation dialog for `plan`; resolves true when the user confirms. */
function confirmPlan(plan, label) {
  return new Promise((resolve) => {
    const blocked = plan.blocked_by.length > 0;
    const dialog = h(
      "dialog",
      { class: "confirm", "aria-label": `Delete ${label}?` },
      h("h2", {}, `Delete ${label}?`),
      h("p", { class: "deletion-summary" }, plan.summary),
      blocked
        ? [
            h("p", { class: "error" }, "Deleting is not possible while these jobs use it; cancel them or wait until they end:"),
            h("ul", {}, plan.blocked_by.map((job) => h("li", {}, h("a", { href: `#/jobs/${job.id}` }, jobName(job)), ` (${job.state})`))),
          ]
        : h("p", { class: "warn" }, "This cannot be undone."),
      h(
        "div",
        { class: "actions" },
        h("button", { type: "button", class: "danger", disabled: blocked, onclick: () => close(true) }, "Delete"),
        " ",
        h("button", { type: "button", onclick: () => close(false) }, blocked ? "Close" : "Keep it"),
      ),
    );
    const close = (answer) => {
      dialog.close();
      dialog.remove();
      resolve(answer);
    };
    dialog.addEventListener("cancel", () => close(false));
    document.body.append(dialog);
    dialog.showModal();
  });
}

/**
 * A "Delete" button for `path` ("experiments/3", "jobs/<id>", ...) named `label` ("experiment plate 3"); after a
 * confirmed delete, `onDeleted()` runs.
 */
export function deleteButton(path, label, onDeleted, { small = true } = {}) {
  return h(
    "button",
    {
      type: "button",
      class: small ? "small danger-outline" : "danger-outline",
      "aria-label": `Delete ${label}`,
      onclick: async () => {
        let plan;
        try {
          plan = await getJSON(`${path}/deletion`);
        } catch (error) {
          showError(error, `find out what goes with ${label}`);
          return;
        }
        if (!(await confirmPlan(plan, label))) return;
        try {
          await deleteJSON(path);
          say(`Deleted ${label}.`);
          onDeleted();
        } catch (error) {
          showError(error, `delete ${label}`);
        }
      },
    },
    "Delete",
  );
}
