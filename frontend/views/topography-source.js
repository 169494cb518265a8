// Where the viewer's numbers come from: the topography results API of a job (GET /jobs/{id}/topography,
// .../grid, .../profile, .../history). One place to change when that API changes; the viewer only sees fields
// ({ x, y, z rows }), profiles ({ s, x, y, w, sigma }) and histories ({ frame, time_s, w, sigma }).
import { getBuffer, getJSON, query } from "../api.js";

/** NaN for JSON nulls: the API's arrays carry null where there is no number. */
const numbers = (values) => Array.from(values || [], (v) => (v === null || v === undefined ? NaN : Number(v)));

export const DISPLAY_BUDGET = 250; // nodes per side of a frame's field (the server block-averages down to it)
const PROFILE_POINTS = 300;

/** Coordinates "first,step" (header X-Grid-X-mm) → n values. */
function axisFrom(header, n) {
  const [first, step] = header.split(",").map(Number);
  return Array.from({ length: n }, (_, i) => first + i * step);
}

export class TopographySource {
  constructor(job) {
    this.job = job;
    this.base = `jobs/${job.id}/topography`;
  }

  /**
   * frames: { index, time_s, punch_displacement_mm, force_kN, peak_w_mm } (NaN where not logged),
   * grid { nx, ny, step_mm, x_min_mm, ... }, w_range_mm [min, max] over the peaks, summary, coverage.
   */
  async meta() {
    const body = await getJSON(this.base);
    const peaks = numbers(body.peak_w_mm);
    const finite = peaks.filter(Number.isFinite);
    return {
      grid: body.grid,
      summary: body.summary,
      warnings: body.warnings || [], // what the result must be read with (a bad calibration used by consent)
      notes: body.notes || [],
      frames: {
        index: body.frames,
        time_s: numbers(body.time_s),
        punch_displacement_mm: numbers(body.punch_displacement_mm),
        force_kN: numbers(body.force_kN),
        peak_w_mm: peaks, // NaN where the peak was not measured (coverage.peak_measured false)
        // Where the peak was not measured: the largest measured w (the peak is at least this), and why not.
        peak_w_lower_bound_mm: numbers(body.peak_w_lower_bound_mm || body.frames.map(() => null)),
        peak_reason: Array.from(body.peak_reason || body.frames.map(() => null)),
      },
      w_range_mm: finite.length ? [Math.min(0, ...finite), Math.max(...finite)] : [-1, 1],
      // Per frame: what of the plate was measured, what is missing by reason (mm²), order conflicts, the temporal
      // cross-check's jumps (NaN: not checked), and whether
      // the peak region was measured (false: no peak to show; null: not recorded in this result).
      coverage: {
        measured_fraction: numbers(body.measured_fraction),
        missing_mm2: Object.fromEntries(Object.entries(body.missing_mm2 || {}).map(([k, v]) => [k, numbers(v)])),
        missing_reasons: body.missing_reasons, // reason -> { label, description }
        n_order_conflicts: numbers(body.n_order_conflicts),
        n_temporal_jumps: numbers(body.n_temporal_jumps),
        peak_measured: Array.from(body.peak_measured || [], (v) => (v === null || v === undefined ? null : Boolean(v))),
      },
    };
  }

  /** A frame's deflection field as float32, within the display budget; `region` { x0, x1, y0, y1 } zooms. */
  async field(frame, region = null) {
    const window = region ? { x_min: region.x0, x_max: region.x1, y_min: region.y0, y_max: region.y1 } : {};
    const { buffer, headers } = await getBuffer(
      `${this.base}/grid${query({ frame, budget: DISPLAY_BUDGET, format: "f32", ...window })}`,
    );
    const [ny, nx] = headers.get("X-Grid-Shape").split(",").map(Number);
    const values = new Float32Array(buffer);
    return {
      x: axisFrom(headers.get("X-Grid-X-mm"), nx),
      y: axisFrom(headers.get("X-Grid-Y-mm"), ny),
      z: Array.from({ length: ny }, (_, j) => values.subarray(j * nx, (j + 1) * nx)),
      // step: result-grid nodes per side of one shown node (1: the result grid itself); stepMm: their spacing.
      step: Number(headers.get("X-Grid-Step") || 1),
      stepMm: Number(headers.get("X-Grid-X-mm").split(",")[1]),
    };
  }

  /** Profiles along `line` for several frames at once, from the full-resolution grid: [{ frame, s, x, y, w, sigma }]. */
  async profiles(frames, line) {
    const params = new URLSearchParams({ x0: line.x0, y0: line.y0, x1: line.x1, y1: line.y1, n_points: PROFILE_POINTS });
    for (const frame of frames) params.append("frames", frame);
    const body = await getJSON(`${this.base}/profile?${params}`);
    const s = numbers(body.s_mm);
    const x = numbers(body.x_mm);
    const y = numbers(body.y_mm);
    // sigma: σ of w at each sample (NaN where unknown; all NaN for a result written before σ was stored).
    return body.profiles.map((p) => ({ frame: p.frame, s, x, y, w: numbers(p.w_mm), sigma: numbers(p.sigma_w_mm || s.map(() => null)) }));
  }

  /**
   * This camera's peaks against another camera's topography job, frame by frame (GET .../against/{id}): compared
   * only where both measured the peak; { frames, difference_w_mm (NaN: not compared), left_out_frames [{ frame,
   * reason }], n_compared, rms_difference_mm, largest_difference_mm }.
   */
  async against(otherJobId) {
    const body = await getJSON(`${this.base}/against/${encodeURIComponent(otherJobId)}`);
    return { ...body, difference_w_mm: numbers(body.difference_w_mm) };
  }

  /** w and its σ at a point in every frame. */
  async history(point) {
    const body = await getJSON(`${this.base}/history${query({ x_mm: point.x, y_mm: point.y })}`);
    return { frame: body.frames, time_s: numbers(body.time_s), w: numbers(body.w_mm), sigma: numbers(body.sigma_w_mm || body.frames.map(() => null)) };
  }

  /** "camera left, recording 3": what the result was measured from. */
  async label() {
    const id = this.job.spec.recording_id;
    const recording = await getJSON(`recordings/${id}`);
    const camera = await getJSON(`cameras/${recording.camera_id}`);
    return `camera ${camera.name}, recording ${id}`;
  }

  /** Succeeded topography jobs of the same experiment on other cameras' recordings, newest first. */
  async otherTopographies() {
    if (!this.job.experiment_id) return [];
    const jobs = await getJSON(`jobs${query({ experiment_id: this.job.experiment_id, kind: "topography", state: "succeeded", limit: 100 })}`);
    const others = jobs.items.filter((other) => other.id !== this.job.id && other.spec.recording_id !== this.job.spec.recording_id);
    return Promise.all(
      others.map(async (other) => {
        const source = new TopographySource(other);
        return { job: other, label: await source.label(), source };
      }),
    );
  }
}
