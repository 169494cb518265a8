// The one module that talks to the server: every fetch and every EventSource of the dashboard lives here.
// Error bodies of the API are `{"detail", "code"}` (sometimes with `field`); they become ApiError objects whose
// message a person can read. Views never look at HTTP responses themselves.

export const API = "/api/v1";

export class ApiError extends Error {
  constructor(status, code, detail, field = null) {
    super(field && !detail.includes(field) ? `${field}: ${detail}` : detail);
    this.name = "ApiError";
    this.status = status;
    this.code = code;
    this.detail = detail;
    this.field = field;
  }
}

let onUnauthorized = () => {};

/** Called with the ApiError of any 401 (auth is on and there is no valid session): the app shows its login. */
export function setUnauthorizedHandler(handler) {
  onUnauthorized = handler;
}

function describeStatus(status) {
  return {
    400: "the server refused the request",
    401: "log in to continue",
    403: "your account may not do this",
    404: "not found",
    409: "not possible in the current state",
    413: "the request is too large",
    422: "the input is invalid",
    429: "too many requests; wait a moment",
    500: "the server failed; its log has the details",
    502: "the server is unreachable (bad gateway)",
    503: "a part of the server is down",
  }[status] || `the server answered HTTP ${status}`;
}

/** The ApiError for a response that is not ok, read from its `{"detail", "code"}` body when it has one. */
async function errorOf(response) {
  let body = null;
  try {
    body = await response.json();
  } catch {
    body = null;
  }
  const detail = body && typeof body.detail === "string" ? body.detail : describeStatus(response.status);
  const code = (body && body.code) || `http_${response.status}`;
  return new ApiError(response.status, code, detail, (body && body.field) || null);
}

const BUSY_RETRIES = 2;

async function send(method, path, { json, text, as = "json", headers = {} } = {}) {
  const init = { method, headers: { Accept: as === "json" ? "application/json" : "*/*", ...headers } };
  if (json !== undefined) {
    init.headers["Content-Type"] = "application/json";
    init.body = JSON.stringify(json);
  } else if (text !== undefined) {
    init.headers["Content-Type"] = "text/plain; charset=utf-8";
    init.body = text;
  }
  let response;
  for (let attempt = 0; ; attempt += 1) {
    try {
      response = await fetch(path.startsWith("/") ? path : `${API}/${path}`, init);
    } catch (error) {
      throw new ApiError(0, "network", `cannot reach the server (${error.message}); is fringelab still running?`);
    }
    // A busy server sheds load with 503 and Retry-After: a read is asked again, twice at most, after the pause.
    const retryAfterS = Number(response.headers.get("Retry-After"));
    if (response.status !== 503 || method !== "GET" || attempt >= BUSY_RETRIES || !(retryAfterS > 0)) break;
    await new Promise((resolve) => setTimeout(resolve, Math.min(retryAfterS, 10) * 1000));
  }
  if (!response.ok) {
    const error = await errorOf(response);
    if (response.status === 401) onUnauthorized(error);
    throw error;
  }
  if (response.status === 204) return null;
  if (as === "buffer") return { buffer: await response.arrayBuffer(), headers: response.headers };
  return response.json();
}

/** `path` is either absolute ("/api/v1/...") or relative to /api/v1 ("experiments/3"). */
export const getJSON = (path) => send("GET", path);
export const getBuffer = (path) => send("GET", path, { as: "buffer" });
export const postJSON = (path, json = {}) => send("POST", path, { json });
export const deleteJSON = (path) => send("DELETE", path);
export const putText = (path, text) => send("PUT", path, { text });

/**
 * PUT a file as the whole request body (a simulation's streamed upload), with `onProgress(sentBytes, totalBytes)`
 * while it is sent (XMLHttpRequest: fetch cannot report upload progress). Resolves to the JSON answer; rejects
 * with an ApiError. `signal` (an AbortSignal) stops it.
 */
export function putFile(path, file, { onProgress = () => {}, signal = null } = {}) {
  return new Promise((resolve, reject) => {
    const request = new XMLHttpRequest();
    request.open("PUT", path.startsWith("/") ? path : `${API}/${path}`);
    request.setRequestHeader("Accept", "application/json");
    request.setRequestHeader("Content-Type", "application/octet-stream");
    request.upload.onprogress = (event) => onProgress(event.loaded, event.lengthComputable ? event.total : file.size);
    request.onerror = () => reject(new ApiError(0, "network", "cannot reach the server; is fringelab still running?"));
    request.onabort = () => reject(new ApiError(0, "aborted", "the upload was stopped"));
    request.onload = async () => {
      const response = new Response(request.responseText, { status: request.status });
      if (request.status >= 200 && request.status < 300) {
        resolve(request.responseText ? JSON.parse(request.responseText) : null);
        return;
      }
      const error = await errorOf(response);
      if (request.status === 401) onUnauthorized(error);
      reject(error);
    };
    if (signal) signal.addEventListener("abort", () => request.abort());
    request.send(file);
  });
}

/** The health report, also when a part is down (the server then answers 503 with the same body). */
export async function getHealth() {
  let response;
  try {
    response = await fetch(`${API}/health`, { headers: { Accept: "application/json" } });
  } catch (error) {
    throw new ApiError(0, "network", `cannot reach the server (${error.message}); is fringelab still running?`);
  }
  if (response.ok || response.status === 503) return response.json();
  throw await errorOf(response);
}

/** Query string from an object, leaving out null/undefined values. */
export function query(params) {
  const search = new URLSearchParams();
  for (const [key, value] of Object.entries(params)) {
    if (value !== null && value !== undefined && value !== "") search.set(key, String(value));
  }
  const text = search.toString();
  return text ? `?${text}` : "";
}

/**
 * Server-Sent Events from `path`: `handlers` maps event names to functions of the parsed JSON data. The stream
 * is closed after an `end` event (the server closes it too; without this the browser would reconnect).
 * `onError(message)` hears about a lost connection, and about an `end` with state "forbidden" (the reader's
 * access ended while the stream was open: a revoked token, a disabled account), which no handler sees.
 * Returns a function that closes the stream.
 */
export function subscribe(path, handlers, { onError = () => {} } = {}) {
  const source = new EventSource(path.startsWith("/") ? path : `${API}/${path}`);
  let ended = false;
  for (const [name, handle] of Object.entries({ end: () => {}, ...handlers })) {
    source.addEventListener(name, (event) => {
      let data = null;
      try {
        data = JSON.parse(event.data);
      } catch {
        data = event.data;
      }
      if (name === "end") {
        ended = true;
        source.close();
        if (data && data.state === "forbidden") {
          onError(`${data.error || "access ended"} (live updates stopped)`);
          return;
        }
      }
      handle(data);
    });
  }
  source.onerror = () => {
    if (ended) return;
    if (source.readyState === EventSource.CLOSED) {
      onError("the live progress stream closed; reload the page to reconnect");
    }
  };
  return () => {
    ended = true;
    source.close();
  };
}

/** Absolute URL of an API path, for links, <img> sources and the tus endpoint. */
export function apiUrl(path) {
  return new URL(path.startsWith("/") ? path : `${API}/${path}`, window.location.origin).href;
}
