// Where the viewer's numbers come from: the topography results API of a job. One place to change when the API
// changes; the viewer only sees fields ({ x, y, z rows }), profiles ({ s, x, y, w }) and histories.
import { getBuffer, getJSON, query } from "../api.js";
import { lineProfile, numbers } from "../fields.js";

export class TopographySource {
  constructor(job) {
    this.job = job;
    this.base = `jobs/${job.id}/topography`;
  }

  /** Frames (index, time_s, punch_displacement_mm, force_kN, peak_w_mm), grid { nx, ny, step_mm }, w_range_mm. */
  async meta() {
    const body = await getJSON(this.base);
    return {
      ...body,
      frames: {
        index: body.frames.index,
        time_s: numbers(body.frames.time_s),
        punch_displacement_mm: numbers(body.frames.punch_displacement_mm),
        force_kN: numbers(body.frames.force_kN),
        peak_w_mm: numbers(body.frames.peak_w_mm),
      },
    };
  }

  /** The deflection field of a frame, decimated by the server to the display budget (or a region at full size). */
  async field(frame, region = null) {
    const { buffer, headers } = await getBuffer(`${this.base}/frames/${frame}/field${query({ ...(region || {}) })}`);
    const nx = Number(headers.get("X-Grid-Nx"));
    const ny = Number(headers.get("X-Grid-Ny"));
    const values = new Float32Array(buffer);
    const x = JSON.parse(headers.get("X-Grid-X-Mm"));
    const y = JSON.parse(headers.get("X-Grid-Y-Mm"));
    const z = Array.from({ length: ny }, (_, j) => values.subarray(j * nx, (j + 1) * nx));
    return { x, y, z };
  }

  /** The profile along a line: sampled in the browser from the field shown. */
  async profile(_frame, line, fieldOfFrame) {
    return lineProfile(fieldOfFrame, line);
  }

  /** w at a point in every frame. */
  async history(point) {
    const body = await getJSON(`${this.base}/history${query({ x_mm: point.x, y_mm: point.y })}`);
    return { frame: body.frame, time_s: numbers(body.time_s), w: numbers(body.w_mm) };
  }

  /** Succeeded topography jobs of the same experiment on other recordings (other cameras). */
  async otherTopographies() {
    if (!this.job.experiment_id) return [];
    const jobs = await getJSON(`jobs${query({ experiment_id: this.job.experiment_id, kind: "topography", state: "succeeded", limit: 100 })}`);
    return jobs.items
      .filter((other) => other.id !== this.job.id && other.spec.recording_id !== this.job.spec.recording_id)
      .map((other) => ({ job: other, label: `recording ${other.spec.recording_id} (job ${other.id.slice(0, 8)})`, source: new TopographySource(other) }));
  }
}
