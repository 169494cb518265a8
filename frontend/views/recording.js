// A recording: its facts, the QA warnings (each naming its frames), a frame scrubber over the previews, and the
// per-frame QA (grey level, saturation, contrast, board detection) with the current frame marked.
import { apiUrl, getJSON, putText } from "../api.js";
import { Figure, axis, lineLayout, lineTraces, verticalMarker } from "../plots.js";
import { attempt, field, formatBytes, formatTime, h, page, say, showError } from "../ui.js";
import { KIND_NAMES } from "./experiments.js";

const BOARD_TEXT = { true: "board found", false: "board NOT found", null: "board not checked" };

/** The frame rate (from the frame times where they exist), with the header's beside it where the two differ. */
function frameRate(recording) {
  if (!recording.fps) return "–";
  const rate = `${Number(recording.fps.toPrecision(5))} frames/s`;
  return recording.fps_header ? `${rate} (header: ${Number(recording.fps_header.toPrecision(5))} frames/s)` : rate;
}

function facts(recording) {
  const rows = [
    ["Kind", KIND_NAMES[recording.kind] || recording.kind],
    ["State", recording.state + (recording.error ? `: ${recording.error}` : "")],
    ["File", `${recording.filename} (${recording.format || "?"}, ${formatBytes(recording.size_bytes)})`],
    ["Frames", recording.frame_count ? `${recording.frame_count} × ${recording.width_px}×${recording.height_px} px, ${recording.bit_depth} bit` : "–"],
    ["Frame rate", frameRate(recording)],
    ["Sidecars", Object.entries(recording.sidecars || {}).map(([name, found]) => (found && found.error ? `${name} (unreadable)` : name)).join(", ") || "none"],
    ["SHA-256", h("code", {}, recording.sha256 || "–")],
    ["Uploaded", formatTime(recording.created_at)],
  ];
  if (recording.duplicate_of) rows.push(["Same bytes as", h("a", { href: `#/recordings/${recording.duplicate_of}` }, `recording ${recording.duplicate_of}`)]);
  return h("dl", { class: "facts" }, rows.map(([term, value]) => [h("dt", {}, term), h("dd", {}, value)]));
}

const SIDECARS = {
  "z.csv": "z.csv: the stage Z of each frame (frame,z_mm)",
  "frames.csv": "frames.csv: the test log (frame,time_s,punch_displacement_mm,force_kN)",
  "board.json": 'board.json: the chessboard ({"cols": 9, "rows": 6, "square_mm": 25})',
};

/** Add or replace a sidecar (PUT .../sidecars/{name}); the ingest runs again and the page shows its outcome. */
function sidecarForm(recording, context) {
  const name = field("Sidecar", h("select", {}, Object.entries(SIDECARS).map(([value, text]) => h("option", { value }, text))));
  const file = field("Sidecar file", h("input", { type: "file", accept: ".csv,.json,text/plain,application/json" }));
  const submit = h("button", { type: "submit" }, "Replace the sidecar");
  const outcome = h("p", { class: "hint", "aria-live": "polite" });
  const settle = async () => {
    for (let i = 0; i < 240 && context.current(); i += 1) {
      const now = await getJSON(`recordings/${recording.id}`);
      if (!["ingesting", "uploading"].includes(now.state)) return now;
      await new Promise((resolve) => setTimeout(resolve, 500));
    }
    return null;
  };
  return h(
    "form",
    {
      class: "card grid-form",
      "aria-label": "Replace a sidecar",
      onsubmit: async (event) => {
        event.preventDefault();
        const chosen = file.input.files[0];
        if (!chosen) return showError("choose the file first", "replace the sidecar");
        submit.disabled = true;
        try {
          await putText(`recordings/${recording.id}/sidecars/${name.input.value}`, await chosen.text());
          outcome.textContent = `${name.input.value} stored; checking the recording again…`;
          const now = await settle();
          if (now && context.current()) {
            // Shown again first (a new view clears the status line), then the outcome is said.
            window.dispatchEvent(new HashChangeEvent("hashchange"));
            say(`${name.input.value} replaced: the recording is ${now.state}.`);
          }
        } catch (error) {
          showError(error, `replace ${name.input.value}`);
        } finally {
          submit.disabled = false;
        }
      },
    },
    h("h2", {}, "Sidecars"),
    h("p", { class: "hint wide-row" }, "A sidecar stored here wins over one inside the recording's ZIP; the frames are checked again with it."),
    name.wrap,
    file.wrap,
    h("div", { class: "actions" }, submit),
    outcome,
  );
}

export async function renderRecording(container, { id }, context) {
  const recording = await attempt("open the recording", () => getJSON(`recordings/${id}`));
  if (!recording || !context.current()) return;
  const back = h("p", {}, h("a", { href: `#/experiments/${recording.experiment_id}` }, "Back to the experiment"));
  if (recording.state !== "ready") {
    page(container, `Recording ${recording.id}: ${recording.filename}`, back, facts(recording),
      h("p", { class: recording.state === "invalid" ? "bad" : "busy" },
        recording.state === "invalid"
          ? "This recording cannot be used as it is. When the reason above is a sidecar (z.csv, frames.csv, board.json), replace it below; else upload the recording again."
          : "Its frames are being checked; reload in a moment."),
      recording.state === "invalid" ? sidecarForm(recording, context) : null);
    return;
  }
  const qa = await attempt("read the recording's QA", () => getJSON(`recordings/${id}/qa`));
  if (!context.current()) return;
  const last = recording.frame_count - 1;

  // ---- scrubber ----
  const slider = h("input", { type: "range", min: 0, max: last, step: 1, value: 0, "aria-label": "Frame", class: "scrubber" });
  const number = h("input", { type: "number", min: 0, max: last, step: 1, value: 0, "aria-label": "Frame number" });
  const image = h("img", { class: "frame", alt: "Frame 0 of the recording", width: recording.width_px, height: recording.height_px });
  const frameFacts = h("p", { class: "frame-facts", "aria-live": "polite" });
  let current = -1;
  const qaFrames = qa ? qa.frames : null;
  const show = (index) => {
    const frame = Math.max(0, Math.min(last, Math.round(Number(index) || 0)));
    if (frame === current) return;
    current = frame;
    slider.value = frame;
    number.value = frame;
    image.src = apiUrl(`recordings/${recording.id}/frames/${frame}`);
    image.alt = `Frame ${frame} of the recording`;
    const parts = [`Frame ${frame} (${frame + 1} of ${recording.frame_count})`]; // frames count from 0
    if (qaFrames) {
      parts.push(`grey level ${(100 * qaFrames.mean_fraction[frame]).toFixed(1)} %`);
      parts.push(`saturated ${qaFrames.saturation_pct[frame].toFixed(2)} %`);
      parts.push(`contrast ${qaFrames.contrast[frame].toFixed(2)}`);
      if (recording.kind === "camera_calibration") parts.push(BOARD_TEXT[String(qaFrames.board_found[frame])]);
    }
    frameFacts.textContent = parts.join(" · ");
    for (const cell of container.querySelectorAll(".board-strip button")) cell.removeAttribute("aria-current");
    container.querySelector(`.board-strip li:nth-child(${frame + 1}) button`)?.setAttribute("aria-current", "true");
    if (qaFigure.drawn) qaFigure.react(qaTraces(), qaLayout());
  };
  slider.addEventListener("input", () => show(slider.value));
  number.addEventListener("change", () => show(number.value));
  const stepButton = (text, delta) =>
    h("button", { type: "button", class: "small", "aria-label": text, onclick: () => show(current + delta) }, delta < 0 ? "◀" : "▶");

  // ---- QA plot ----
  const frames = Array.from({ length: recording.frame_count }, (_, i) => i);
  const boardFound = qaFrames ? qaFrames.board_found : [];
  const hasBoard = boardFound.some((v) => v !== null);
  const qaSeries = () =>
    qaFrames
      ? [
          { name: "mean grey level", x: frames, y: qaFrames.mean_fraction.map((v) => 100 * v) },
          { name: "saturated pixels", x: frames, y: qaFrames.saturation_pct },
          { name: "contrast × 100", x: frames, y: qaFrames.contrast.map((v) => 100 * v) },
        ]
      : [];
  const qaTraces = () => {
    const traces = lineTraces(qaSeries(), { mode: "lines+markers" });
    if (hasBoard) {
      const missing = frames.filter((i) => boardFound[i] === false);
      traces.push({
        type: "scatter",
        mode: "markers",
        name: "board not found",
        x: missing,
        y: missing.map(() => 0),
        marker: { symbol: "x", size: 10, color: "#d62728" },
      });
    }
    return traces;
  };
  const qaLayout = () => lineLayout({ xAxis: axis("frame", "index"), yAxis: axis("level", "%"), shapes: current >= 0 ? [verticalMarker(current)] : [] });
  const qaFigure = new Figure({
    name: "Per-frame QA",
    filename: `recording-${recording.id}-qa`,
    height: 300,
    csv: () => ({
      columns: ["frame", "mean_grey_fraction", "saturation_pct", "contrast", "board_found"],
      rows: frames.map((i) => [i, qaFrames.mean_fraction[i], qaFrames.saturation_pct[i], qaFrames.contrast[i], boardFound[i] === null ? "" : boardFound[i]]),
    }),
  });

  // ---- board detection, one cell per frame (a click shows the frame) ----
  const boardStrip = hasBoard
    ? h("div", { class: "board-strip-box" },
        h("h2", {}, "Board detection per frame"),
        h("ol", { class: "board-strip", "aria-label": "Board detection per frame" },
          frames.map((i) => h("li", {},
            h("button", {
              type: "button",
              class: `board-${String(boardFound[i])}`,
              "aria-label": `Frame ${i}: ${BOARD_TEXT[String(boardFound[i])]}`,
              title: `Frame ${i}: ${BOARD_TEXT[String(boardFound[i])]}`,
              onclick: () => show(i),
            }, boardFound[i] === true ? "✓" : boardFound[i] === false ? "✗" : "–")))),
        h("p", { class: "hint" }, `${boardFound.filter((v) => v === true).length} of ${frames.length} frames show the board.`))
    : null;

  // ---- warnings ----
  const warnings = h(
    "ul",
    { class: "warnings", "aria-label": "QA warnings" },
    recording.warnings.map((w) =>
      h(
        "li",
        { class: "warn" },
        w.message,
        w.frames.length ? " Frames: " : "",
        w.frames.slice(0, 40).map((frame) => h("button", { type: "button", class: "link", "aria-label": `Show frame ${frame}`, onclick: () => show(frame) }, String(frame))),
        w.frames.length > 40 ? ` … (${w.frames.length} in all)` : "",
      ),
    ),
  );
  page(
    container,
    `Recording ${recording.id}: ${recording.filename}`,
    back,
    h("div", { class: "two-columns" },
      h("div", {}, facts(recording),
        h("h2", {}, "QA warnings"),
        recording.warnings.length ? warnings : h("p", { class: "ok" }, "No QA warnings."),
        // Notes are facts about the file (a duplicate, colour converted to grey), not warnings: a heading of
        // their own, so that "No QA warnings" is never followed by something that reads like one.
        recording.notes.length ? [h("h2", {}, "Notes"), h("ul", { class: "notes", "aria-label": "Notes" }, recording.notes.map((n) => h("li", {}, n)))] : null),
      h("section", { "aria-label": "Frames", class: "scrubber-box" },
        h("div", { class: "frame-box" }, image),
        h("div", { class: "scrubber-row" }, stepButton("Previous frame", -1), slider, stepButton("Next frame", 1), number),
        frameFacts,
        boardStrip),
    ),
    qaFrames ? qaFigure.element : null,
    sidecarForm(recording, context),
  );
  context.onLeave(() => qaFigure.purge());
  if (qaFrames) await qaFigure.react(qaTraces(), qaLayout());
  show(0);
}
