import { getJSON } from "./api.js";

function part(ok, detail) {
  return ok ? "up" : `down: ${detail}`;
}

async function refreshHealth() {
  const status = document.getElementById("status");
  try {
    const { body } = await getJSON("/api/v1/health");
    document.getElementById("health-version").textContent = body.version;
    document.getElementById("health-database").textContent = part(body.database.ok, body.database.detail);
    document.getElementById("health-redis").textContent = part(body.redis.ok, body.redis.detail);
    document.getElementById("health-workers").textContent = String(body.workers);
    status.textContent = body.ok ? "All parts are up." : `Not ready: ${body.failing.join(", ")} down.`;
  } catch (error) {
    status.textContent = `Cannot reach the server: ${error}`;
  }
}

refreshHealth();
setInterval(refreshHealth, 5000);
