// What the viewer's panels share about a topography result: its time axis (s or ms, or frame numbers without
// times) and which grid a field's numbers come from. Not here: any panel's drawing (one module per panel).
import { axis } from "../../plots.js";
import { num } from "../../ui.js";

/** The unit the test's times read best in: ms for a high-speed test, s for a quasi-static one. */
export function timeUnit(meta) {
  const finite = meta.frames.time_s.filter(Number.isFinite);
  const span = finite.length ? Math.max(...finite.map(Math.abs)) : 0;
  return span >= 1 ? { unit: "s", scale: 1 } : { unit: "ms", scale: 1000 };
}

export function timeLabel(meta, frame) {
  const i = meta.frames.index.indexOf(frame);
  const t = i >= 0 ? meta.frames.time_s[i] : NaN;
  const { unit, scale } = timeUnit(meta);
  return Number.isFinite(t) ? `t = ${num(t * scale, 3)} ${unit}` : `frame ${frame}`;
}

/** The x axis of the plots over the test: time when every frame has one, else the frame numbers. */
export function timeAxis(meta) {
  const t = meta.frames.time_s;
  const { unit, scale } = timeUnit(meta);
  return t.every(Number.isFinite)
    ? { key: "time", unit, scale, title: axis("time", unit), values: t.map((v) => v * scale) }
    : { key: "frame", title: axis("frame", "index"), values: meta.frames.index };
}

/** Which grid the numbers of a field come from: the result's own, or the display grid of block averages. */
export function gridOf(meta, field) {
  const resultStep = meta.grid.step_mm;
  if (!field || field.step === 1) return { grid: "result", step_mm: resultStep, name: `result-grid-${num(resultStep, 2)}mm` };
  return { grid: `display (${field.step} × ${field.step} block averages of the ${num(resultStep, 2)} mm result grid)`, step_mm: field.stepMm, name: `display-grid-${num(field.stepMm, 2)}mm` };
}
