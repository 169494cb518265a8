// The upload control: drop files or folders (or pick them); each becomes one recording, sent through tus
// (resumable: an interrupted upload continues where the server stopped, also after a reload), with a progress
// bar, speed and time left per file, pause and resume, and the server's error shown on the file's row.
// A dropped folder is packed into a stored ZIP in the browser (zip.js); sidecars (z.csv, frames.csv, board.json)
// dropped beside one recording file are attached to it once it exists.
// tus-js-client is the vendored classic script vendor/tus-js-client-<version>.min.js (window.tus); it talks to the
// server with XMLHttpRequest, so api.js stays the only module that calls fetch.
import { putText } from "./api.js";
import { formatBytes, formatDuration, h, newId, showError } from "./ui.js";
import { storedZip } from "./zip.js";

const CHUNK_BYTES = 16 * 1024 * 1024; // small enough that pause takes effect soon, big enough to keep the link busy
const RETRY_DELAYS_MS = [0, 1000, 3000, 10000];

/** Every file under a dropped folder entry, with its path relative to the drop ("run1/frame_0001.png"). */
async function filesOfEntry(entry, prefix = "") {
  if (entry.isFile) {
    const file = await new Promise((resolve, reject) => entry.file(resolve, reject));
    return [{ file, path: `${prefix}${file.name}` }];
  }
  const reader = entry.createReader();
  const children = [];
  // readEntries answers in batches (100 in Chromium) until it returns an empty one.
  for (;;) {
    const batch = await new Promise((resolve, reject) => reader.readEntries(resolve, reject));
    if (!batch.length) break;
    children.push(...batch);
  }
  const nested = await Promise.all(children.map((child) => filesOfEntry(child, `${prefix}${entry.name}/`)));
  return nested.flat();
}

/** Files of a drop event, folders walked; each as { file, path }. */
export async function filesOfDrop(dataTransfer) {
  const entries = [...dataTransfer.items]
    .filter((item) => item.kind === "file")
    .map((item) => (item.webkitGetAsEntry ? item.webkitGetAsEntry() : null));
  if (entries.length && entries.every(Boolean)) {
    return (await Promise.all(entries.map((entry) => filesOfEntry(entry)))).flat();
  }
  return [...dataTransfer.files].map((file) => ({ file, path: file.name }));
}

/** The server's words from a tus error: the `detail` of its JSON body when it sent one. */
export function tusErrorText(error) {
  const response = error && error.originalResponse;
  if (response) {
    const status = response.getStatus();
    const body = response.getBody();
    try {
      const parsed = JSON.parse(body);
      if (parsed && parsed.detail) return `${parsed.detail} (HTTP ${status})`;
    } catch {
      // not JSON: fall through to the text
    }
    if (body) return `${body.slice(0, 300)} (HTTP ${status})`;
    return `the server answered HTTP ${status}`;
  }
  const text = String((error && error.message) || error);
  return text.includes("failed to upload chunk") || text.includes("xhr")
    ? "the connection to the server was lost; press Resume to continue"
    : text;
}

/** Exponentially smoothed upload rate, bytes per second. */
class Rate {
  constructor() {
    this.bytes = null;
    this.time = null;
    this.value = null;
  }

  update(bytes) {
    const now = performance.now();
    if (this.bytes !== null && now > this.time) {
      const instant = ((bytes - this.bytes) * 1000) / (now - this.time);
      this.value = this.value === null ? instant : 0.7 * this.value + 0.3 * instant;
    }
    this.bytes = bytes;
    this.time = now;
    return this.value;
  }

  reset() {
    this.bytes = null;
    this.time = null;
    this.value = null;
  }
}

export const SIDECARS = ["z.csv", "frames.csv", "board.json"];

/**
 * What a drop (or a pick) uploads: each top-level file is a recording, each top-level folder is one recording
 * (packed as a ZIP), and loose sidecars go with the single recording beside them.
 * Returns { recordings: [{ name, files: [{ file, path }], folder: bool }], sidecars: [{ file, path }] }.
 */
export function groupIntoRecordings(items) {
  const folders = new Map();
  const recordings = [];
  const sidecars = [];
  for (const item of items) {
    const parts = item.path.split("/");
    if (parts.length > 1) {
      const top = parts[0];
      if (!folders.has(top)) {
        const group = { name: `${top}.zip`, files: [], folder: true };
        folders.set(top, group);
        recordings.push(group);
      }
      folders.get(top).files.push({ file: item.file, path: parts.slice(1).join("/") });
    } else if (SIDECARS.includes(item.file.name.toLowerCase())) {
      sidecars.push(item);
    } else {
      recordings.push({ name: item.file.name, files: [item], folder: false });
    }
  }
  for (const group of folders.values()) {
    group.files.sort((a, b) => a.path.localeCompare(b.path, undefined, { numeric: true }));
  }
  return { recordings, sidecars };
}

/** One recording's upload and its row in the list. */
class RecordingUpload {
  constructor(group, { endpoint, metadata, onSuccess }) {
    this.group = group;
    this.name = group.name;
    this.endpoint = endpoint;
    this.metadata = metadata;
    this.onSuccess = onSuccess;
    this.state = "waiting";
    this.rate = new Rate();
    this.recordingId = null;
    this.upload = null;
    const size = group.files.reduce((sum, f) => sum + f.file.size, 0);
    this.bar = h("progress", { max: 100, value: 0, "aria-label": `Upload progress of ${this.name}` });
    this.info = h("span", { class: "upload-info" }, "waiting");
    this.error = h("p", { class: "error upload-error", hidden: true });
    this.button = h(
      "button",
      { type: "button", class: "small", "aria-label": `Pause upload of ${this.name}`, onclick: () => this.toggle() },
      "Pause",
    );
    this.row = h(
      "li",
      { class: "upload-row" },
      h("span", { class: "upload-name", title: this.name }, this.name),
      h("span", { class: "upload-size" }, group.folder ? `${group.files.length} files, ${formatBytes(size)}` : formatBytes(size)),
      this.bar,
      this.info,
      this.button,
      this.error,
    );
  }

  async blob() {
    if (!this.group.folder) return this.group.files[0].file;
    this.info.textContent = "packing the folder…";
    return storedZip(this.group.files, {
      onProgress: (done, total) => {
        this.info.textContent = `packing the folder… ${Math.floor((100 * done) / total)} %`;
      },
    });
  }

  async start() {
    this.state = "uploading";
    const blob = await this.blob();
    this.upload = new window.tus.Upload(blob, {
      endpoint: this.endpoint,
      chunkSize: CHUNK_BYTES,
      retryDelays: RETRY_DELAYS_MS,
      removeFingerprintOnSuccess: true,
      metadata: {
        filename: this.name,
        filetype: blob.type || "application/octet-stream",
        ...this.metadata(this),
      },
      onProgress: (sent, total) => this.progress(sent, total),
      onSuccess: (payload) => this.succeeded(payload),
      onError: (error) => this.failed(error),
    });
    this.info.textContent = "starting…";
    const previous = await this.upload.findPreviousUploads();
    if (previous.length) {
      this.upload.resumeFromPreviousUpload(previous[0]);
      this.info.textContent = "resuming an earlier upload…";
    }
    if (this.state === "uploading") this.upload.start();
  }

  progress(sent, total) {
    const fraction = total ? sent / total : 0;
    this.bar.value = Math.floor(fraction * 100);
    const rate = this.rate.update(sent);
    const left = rate && rate > 0 ? (total - sent) / rate : null;
    this.info.textContent = `${Math.floor(fraction * 100)} % · ${rate ? `${formatBytes(rate)}/s` : "–"} · ${
      left === null ? "–" : `${formatDuration(left)} left`
    }`;
  }

  succeeded(payload) {
    this.state = "done";
    const header = payload && payload.lastResponse ? payload.lastResponse.getHeader("Fringelab-Recording-Id") : null;
    this.recordingId = header ? Number(header) : null;
    this.bar.value = 100;
    this.info.textContent = this.recordingId ? `done · recording ${this.recordingId}` : "done";
    this.button.hidden = true;
    this.onSuccess(this);
  }

  toggle() {
    if (this.state === "uploading" && this.upload) {
      this.upload.abort();
      this.state = "paused";
      this.rate.reset();
      this.info.textContent = `paused at ${this.bar.value} %`;
      this.setButton("Resume");
    } else if ((this.state === "paused" || this.state === "failed") && this.upload) {
      this.error.hidden = true;
      this.row.classList.remove("failed");
      this.state = "uploading";
      this.setButton("Pause");
      this.upload.start();
    }
  }

  setButton(text) {
    this.button.textContent = text;
    this.button.setAttribute("aria-label", `${text} upload of ${this.name}`);
  }

  failed(error) {
    this.state = "failed";
    const text = tusErrorText(error);
    this.error.textContent = text;
    this.error.hidden = false;
    this.row.classList.add("failed");
    this.info.textContent = "failed";
    // The server refused the file (wrong format, too large, unknown camera): sending it again cannot help.
    // Lost connections and busy servers (409, 423, 429, 5xx) are worth a resume.
    const status = error && error.originalResponse ? error.originalResponse.getStatus() : 0;
    const refused = status >= 400 && status < 500 && ![409, 423, 429].includes(status);
    this.setButton("Resume");
    this.button.hidden = refused || !this.upload;
    showError(text.startsWith(this.name) ? text : `${this.name}: ${text}`, "upload");
  }
}

/**
 * The upload control. `endpoint` is the tus creation URL; `metadata(recordingUpload)` adds the metadata the
 * server needs beyond `filename` and `filetype` (camera_id, kind); `onRecording(recordingId)` runs after each
 * recording exists (its sidecars attached).
 */
export class Uploader {
  constructor({ endpoint, metadata = () => ({}), onRecording = () => {}, label = "Upload recordings" }) {
    this.endpoint = endpoint;
    this.metadata = metadata;
    this.onRecording = onRecording;
    this.uploads = [];
    const filesId = newId("upload-files");
    const folderId = newId("upload-folder");
    this.list = h("ul", { class: "upload-list", "aria-label": "Uploads" });
    const filesInput = h("input", {
      type: "file",
      id: filesId,
      multiple: true,
      class: "visually-hidden",
      onchange: (event) => this.pick(event.target),
    });
    const folderInput = h("input", {
      type: "file",
      id: folderId,
      webkitdirectory: true,
      class: "visually-hidden",
      onchange: (event) => this.pick(event.target),
    });
    this.zone = h(
      "div",
      {
        class: "dropzone",
        ondragover: (event) => {
          event.preventDefault();
          this.zone.classList.add("over");
        },
        ondragleave: () => this.zone.classList.remove("over"),
        ondrop: async (event) => {
          event.preventDefault();
          this.zone.classList.remove("over");
          try {
            this.add(await filesOfDrop(event.dataTransfer));
          } catch (error) {
            showError(error, "read the dropped files");
          }
        },
      },
      h(
        "p",
        {},
        "Drop recordings here (files, or folders of frames), or ",
        h("label", { for: filesId, class: "button-like" }, "Choose files"),
        filesInput,
        " ",
        h("label", { for: folderId, class: "button-like" }, "Choose a folder"),
        folderInput,
      ),
      h("p", { class: "hint" }, "ZIP, multi-page TIFF, AVI/MP4, Phantom .cine or a folder of frames; z.csv, frames.csv and board.json dropped beside one recording are attached to it."),
    );
    this.element = h("section", { class: "uploader", "aria-label": label }, this.zone, this.list);
  }

  pick(input) {
    const files = [...input.files].map((file) => ({ file, path: file.webkitRelativePath || file.name }));
    input.value = "";
    this.add(files);
  }

  /** Upload `items` ([{ file, path }]) as one drop. */
  add(items) {
    const { recordings, sidecars } = groupIntoRecordings(items);
    if (sidecars.length && recordings.length !== 1) {
      showError(
        `${sidecars.map((s) => s.path).join(", ")}: drop sidecars together with exactly one recording (or put them in its folder or ZIP)`,
        "attach the sidecars",
      );
    }
    const attach = recordings.length === 1 ? sidecars : [];
    for (const group of recordings) {
      const upload = new RecordingUpload(group, {
        endpoint: this.endpoint,
        metadata: this.metadata,
        onSuccess: (done) => this.finished(done, attach),
      });
      this.list.append(upload.row);
      this.uploads.push(upload);
      upload.start().catch((error) => upload.failed(error));
    }
  }

  async finished(upload, sidecars) {
    if (upload.recordingId === null) {
      showError(`${upload.name}: the server did not say which recording the upload became`, "finish the upload");
      return;
    }
    for (const sidecar of sidecars) {
      try {
        await putText(`recordings/${upload.recordingId}/sidecars/${sidecar.file.name.toLowerCase()}`, await sidecar.file.text());
        upload.info.textContent += ` · ${sidecar.file.name} attached`;
      } catch (error) {
        showError(error, `attach ${sidecar.file.name} to recording ${upload.recordingId}`);
      }
    }
    this.onRecording(upload.recordingId);
  }

  /** Stop every running upload (when the user leaves the page; tus resumes them when dropped again). */
  abortAll() {
    for (const upload of this.uploads) {
      if (upload.state === "uploading" && upload.upload) upload.upload.abort();
    }
  }
}
