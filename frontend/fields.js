// Fields on a regular grid in the browser: a field is { x: number[nx] (mm, increasing), y: number[ny] (mm,
// increasing), z: Float32Array[ny] (rows, mm; NaN where there is no data) }. Sampling follows the science's
// worker/measurement/fields.py (bilinear; NaN when any of the four nodes around a point is NaN or outside).
// No network code and no plotting here.

/** Bilinear value of `field` at (x, y) in mm; NaN outside the grid or next to a hole. */
export function sampleField(field, x, y) {
  const { x: xs, y: ys, z } = field;
  const nx = xs.length;
  const ny = ys.length;
  if (nx < 2 || ny < 2) return NaN;
  const stepX = (xs[nx - 1] - xs[0]) / (nx - 1);
  const stepY = (ys[ny - 1] - ys[0]) / (ny - 1);
  const fx = (x - xs[0]) / stepX;
  const fy = (y - ys[0]) / stepY;
  let ix = Math.floor(fx);
  let iy = Math.floor(fy);
  if (ix === nx - 1) ix = nx - 2; // a point on the last node belongs to the last cell
  if (iy === ny - 1) iy = ny - 2;
  if (!(ix >= 0 && ix < nx - 1 && iy >= 0 && iy < ny - 1)) return NaN;
  const ax = fx - ix;
  const ay = fy - iy;
  const f00 = z[iy][ix];
  const f01 = z[iy][ix + 1];
  const f10 = z[iy + 1][ix];
  const f11 = z[iy + 1][ix + 1];
  return (f00 * (1 - ax) + f01 * ax) * (1 - ay) + (f10 * (1 - ax) + f11 * ax) * ay;
}

/** Grid step of a field in mm (the smaller of the two directions). */
export function gridStep(field) {
  const sx = (field.x[field.x.length - 1] - field.x[0]) / (field.x.length - 1);
  const sy = (field.y[field.y.length - 1] - field.y[0]) / (field.y.length - 1);
  return Math.min(Math.abs(sx), Math.abs(sy));
}

/**
 * The profile of `field` along the straight line { x0, y0, x1, y1 } (mm), every `step` mm (default: half the grid
 * step, as the science's line_profile): { s: distance along the line (mm), x, y (mm), w (mm) }.
 */
export function lineProfile(field, line, step = 0.5 * gridStep(field)) {
  const length = Math.hypot(line.x1 - line.x0, line.y1 - line.y0);
  const count = Math.floor(length / step) + 1;
  const out = { s: [], x: [], y: [], w: [] };
  for (let i = 0; i < count; i += 1) {
    const s = count > 1 ? (length * i) / (count - 1) : 0;
    const x = line.x0 + ((line.x1 - line.x0) * s) / (length || 1);
    const y = line.y0 + ((line.y1 - line.y0) * s) / (length || 1);
    out.s.push(s);
    out.x.push(x);
    out.y.push(y);
    out.w.push(sampleField(field, x, y));
  }
  return out;
}

/** [min, max] of the finite values of a field (null when it has none). */
export function fieldRange(field) {
  let low = Infinity;
  let high = -Infinity;
  for (const row of field.z) {
    for (let i = 0; i < row.length; i += 1) {
      const v = row[i];
      if (v < low) low = v;
      if (v > high) high = v;
    }
  }
  return Number.isFinite(low) ? [low, high] : null;
}

/** NaN for JSON nulls: arrays from the API carry null where there is no number. */
export const numbers = (values) => Array.from(values || [], (v) => (v === null || v === undefined ? NaN : Number(v)));
