// "System": is every part of the server up (database, Redis, workers), and the version.
import { getHealth } from "../api.js";
import { h, page, showError, table } from "../ui.js";

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
  page(container, "System health", body, h("p", {}, h("a", { href: "/api/docs" }, "API documentation (OpenAPI)")));
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
