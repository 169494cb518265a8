// The app shell: routes, navigation highlight, the account corner, the login on 401, the health footer, and
// errors nobody caught shown in the status region.
import { getHealth, getJSON, postJSON, setUnauthorizedHandler } from "./api.js";
import { Router } from "./router.js";
import { clearError, h, page, say, showError } from "./ui.js";
import { loginView } from "./views/login.js";
import { healthSummary, renderSystem } from "./views/system.js";
import { renderTokens } from "./views/tokens.js";
import { renderExperiment, renderExperiments } from "./views/experiments.js";
import { renderRecording } from "./views/recording.js";
import { renderJob, renderJobs } from "./views/jobs.js";
import { renderCalibration } from "./views/calibration.js";
import { renderViewer } from "./views/viewer.js";
import { renderComparison } from "./views/comparison.js";
import { renderScan } from "./views/scan.js";
import { renderHelp, renderHelpIndex } from "./views/help.js";
import { renderQueue } from "./views/queue.js";

const container = document.getElementById("view");

function notFound(target, { path }) {
  page(target, "Not found", h("p", {}, `There is no page at ${path}. `, h("a", { href: "#/experiments" }, "Experiments")));
}

function highlight(path) {
  for (const link of document.querySelectorAll("header.top nav a")) {
    const target = link.getAttribute("href").replace(/^#/, "");
    if (target.startsWith("/api")) continue;
    if (path === target || path.startsWith(`${target}/`)) link.setAttribute("aria-current", "page");
    else link.removeAttribute("aria-current");
  }
}

const router = new Router(container, {
  notFound,
  onChange: (path) => {
    clearError();
    say("");
    highlight(path);
  },
});

document.getElementById("alert-dismiss").addEventListener("click", clearError);

// Every view shows its own errors; a rejected promise nobody handled still reaches the user.
window.addEventListener("unhandledrejection", (event) => showError(event.reason));
window.addEventListener("error", (event) => showError(event.message));

router
  .add("/", () => window.location.replace("#/experiments"))
  .add("/experiments", renderExperiments)
  .add("/experiments/:id", renderExperiment)
  .add("/recordings/:id", renderRecording)
  .add("/jobs", renderJobs)
  .add("/jobs/:id", renderJob)
  .add("/jobs/:id/report", renderCalibration)
  .add("/jobs/:id/viewer", renderViewer)
  .add("/jobs/:id/comparison", renderComparison)
  .add("/jobs/:id/scan", renderScan)
  .add("/queue", renderQueue)
  .add("/help", renderHelpIndex)
  .add("/help/:name", renderHelp)
  .add("/tokens", renderTokens)
  .add("/system", renderSystem);

// ---- accounts -----------------------------------------------------------------------------------------------------

const account = document.getElementById("account");
let loginShown = false;

async function showAccount() {
  try {
    const me = await getJSON("auth/me");
    if (!me.auth_enabled) {
      account.replaceChildren();
      return;
    }
    account.replaceChildren(
      h("span", {}, `${me.username} (${me.role})`),
      h(
        "button",
        {
          type: "button",
          class: "small",
          onclick: async () => {
            try {
              await postJSON("auth/logout");
              window.location.reload();
            } catch (error) {
              showError(error, "log out");
            }
          },
        },
        "Log out",
      ),
    );
  } catch {
    // a 401 here opens the login form (setUnauthorizedHandler); other errors show when a view loads
  }
}

setUnauthorizedHandler(() => {
  if (loginShown) return;
  loginShown = true;
  router.showInstead(
    loginView(() => {
      loginShown = false;
      showAccount();
      router.show();
    }),
  );
});

// ---- health footer ---------------------------------------------------------------------------------------------

const footer = document.getElementById("footer-health");
async function refreshFooter() {
  try {
    footer.textContent = healthSummary(await getHealth());
  } catch (error) {
    footer.textContent = `Cannot reach the server: ${error.message}`;
  }
}

refreshFooter();
setInterval(refreshFooter, 15_000);
showAccount();
router.show();
