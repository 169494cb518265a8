// The report of a camera–projector calibration (docs/procam.md §1): the verdict with its checks, the RMS of the
// camera, the projector and the pair, each pose's RMS (bars) and the residual vectors of every corner in the camera
// image and in the projector image. Every plot downloads its data (CSV) and its image (PNG).
import { getJSON } from "../api.js";
import { COLORS, Figure, axis, barTraces, imageLayout, layout, vectorTraces } from "../plots.js";
import { attempt, h, num, page, showError, table } from "../ui.js";
import { jobName } from "./job-helpers.js";

export async function procamReport(container, job, context) {
  const calibrationId = job.result && job.result.calibration_id;
  if (!calibrationId) {
    showError(`${jobName(job)} names no calibration in its result`, "show the calibration report");
    return;
  }
  const answer = await attempt("read the calibration report", () => getJSON(`calibrations/${calibrationId}/procam-report`));
  if (!answer || !context.current()) return;
  const { calibration, report } = answer;
  const name = `procam-calibration-${job.id.slice(0, 8)}`;
  const poses = poseFigure(report, name);
  const camera = residualFigure(report, name, "camera");
  const projector = residualFigure(report, name, "projector");
  const verdict = report.verdict;
  page(
    container,
    `Camera–projector calibration ${calibration.id} (version ${calibration.version})`,
    h("p", {}, h("a", { href: `#/jobs/${job.id}` }, jobName(job)), " · ",
      h("a", { href: calibration.file_url, download: `procam-calibration-${calibration.id}.json` }, "Download procam.json")),
    h("section", { class: `card verdict verdict-${verdict.level}`, "aria-label": "Verdict" },
      h("h2", {}, `Verdict: ${verdict.level}`),
      h("ul", {}, verdict.reasons.map((reason) => h("li", {}, reason))),
      table("Verdict checks", [
        { title: "Check", value: (c) => c.name },
        { title: "Value", value: (c) => `${num(c.value, 3)} ${c.unit}`, class: "num" },
        { title: "Good if", value: (c) => `${c.higher_is_better ? "≥" : "≤"} ${c.good_limit} ${c.unit}`, class: "num" },
        { title: "Bad if", value: (c) => `${c.higher_is_better ? "<" : ">"} ${c.bad_limit} ${c.unit}`, class: "num" },
        { title: "Level", value: (c) => h("span", { class: `level-${c.level}` }, c.level) },
        { title: "Meaning", value: (c) => c.message },
      ], verdict.checks)),
    h("dl", { class: "facts", "aria-label": "Calibration summary" }, [
      ["Camera", `${report.camera.size_wh_px.join(" × ")} px; RMS ${num(report.rms.camera_calibration_px, 4)} px`],
      ["Projector", `${report.projector.size_wh_px.join(" × ")} px; RMS ${num(report.rms.projector_calibration_px, 4)} px`],
      ["Stereo (both together)", `RMS ${num(report.rms.stereo_px, 4)} px over ${report.poses.length} poses`],
      ["Projector centre from the camera", `${report.stereo.t_proj_from_cam_mm.map((v) => num(v, 2)).join(", ")} mm (T)`],
    ].flatMap(([term, value]) => [h("dt", {}, term), h("dd", {}, value)])),
    poses.figure.element,
    camera.figure.element,
    projector.figure.element,
  );
  context.onLeave(() => [poses, camera, projector].forEach((item) => item.figure.purge()));
  for (const item of [poses, camera, projector]) await item.draw();
  window.fringelab = window.fringelab || {};
  window.fringelab.procamReport = { drawn: 3 }; // diagnostics for the browser tests: every plot drawn
}

function poseFigure(report, name) {
  const poses = report.poses;
  const figure = new Figure({
    name: "Per-pose RMS",
    filename: `${name}-pose-rms`,
    height: 320,
    csv: () => ({
      columns: ["pose", "camera_rms_px", "projector_rms_px", "share_from_edges"],
      rows: poses.map((p) => [p.pose, p.camera_rms_px, p.projector_rms_px, p.share_from_edges]),
    }),
  });
  const x = poses.map((p) => p.pose);
  const traces = [
    ...barTraces({ x, y: poses.map((p) => p.camera_rms_px), name: "camera", color: COLORS[0] }),
    ...barTraces({ x, y: poses.map((p) => p.projector_rms_px), name: "projector", color: COLORS[1] }),
  ];
  const draw = () => figure.react(traces, layout({ xaxis: { ...axis("pose", "name"), type: "category" }, yaxis: axis("RMS reprojection error", "px"), barmode: "group" }));
  return { figure, draw };
}

function residualFigure(report, name, device) {
  const [width, height] = report[device].size_wh_px;
  const q = report.poses.flatMap((p) => p[`${device}_q_px`].map((point) => [p.pose, ...point]));
  const r = report.poses.flatMap((p) => p[`${device}_residual_px`]);
  const lengths = r.map(([du, dv]) => Math.hypot(du, dv)).sort((a, b) => a - b);
  const median = lengths.length ? lengths[Math.floor(lengths.length / 2)] : 0;
  const scale = median > 0 ? Math.max(1, Math.round((0.02 * width) / median)) : 100;
  const title = `Residual vectors in the ${device} image (× ${scale})`;
  const figure = new Figure({
    name: title,
    filename: `${name}-${device}-residuals`,
    height: 460,
    csv: () => ({
      columns: ["pose", "u_px", "v_px", "du_px", "dv_px"],
      rows: q.map(([pose, u, v], i) => [pose, u, v, r[i][0], r[i][1]]),
    }),
  });
  const draw = () =>
    figure.react(
      vectorTraces({ u: q.map((p) => p[1]), v: q.map((p) => p[2]), du: r.map((d) => d[0]), dv: r.map((d) => d[1]), scale }),
      imageLayout({ widthPx: width, heightPx: height }),
    );
  return { figure, draw };
}
