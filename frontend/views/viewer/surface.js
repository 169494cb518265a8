// The viewer's 3-D surface of a frame's deflection field (the whole frame; its z axis is the whole test's range).
import { Figure } from "../../plots.js";
import { surfaceLayout, surfaceTraces } from "../../plot_fields.js";

export class SurfacePanel {
  constructor(viewer) {
    this.viewer = viewer;
    this.figure = new Figure({
      name: "Deflection surface",
      filename: `topography-${viewer.job.id.slice(0, 8)}-surface`,
      height: 470,
      csv: () => viewer.fieldCSV(),
    });
  }

  draw({ range, rangeNote }) {
    return this.figure.react(surfaceTraces(this.viewer.current, { range, rangeNote }), surfaceLayout({ zRange: this.viewer.meta.w_range_mm }));
  }
}
