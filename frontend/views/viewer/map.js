// The viewer's 2-D map of a frame's deflection field: the section lines and points drawn on it, and the regions
// not measured in this frame outlined (what the first frame saw, and the gaps inside it: a highlight, a shadow).
// Drawing on it (lines, points) is the viewer's to handle.
import { Figure } from "../../plots.js";
import { mapLayout, mapTraces, missingOutlineTraces } from "../../plot_fields.js";

export class MapPanel {
  constructor(viewer) {
    this.viewer = viewer;
    this.figure = new Figure({
      name: "Deflection map",
      filename: `topography-${viewer.job.id.slice(0, 8)}-map`,
      height: 470,
      csv: () => viewer.fieldCSV(),
      config: { modeBarButtonsToAdd: ["drawline"] },
    });
  }

  /** The window the map is zoomed to, in mm, or null before it is drawn. */
  zoomRegion() {
    const { xaxis, yaxis } = this.figure.plot.layout || {};
    if (!xaxis || !yaxis || !xaxis.range || !yaxis.range) return null;
    const [x0, x1] = xaxis.range.map(Number).sort((a, b) => a - b);
    const [y0, y1] = yaxis.range.map(Number).sort((a, b) => a - b);
    return { x0, x1, y0, y1 };
  }

  async draw({ range, rangeNote }) {
    const viewer = this.viewer;
    const lines = viewer.lines.map((line) => ({ ...line }));
    const reference = await viewer.field(viewer.frames[0]);
    const traces = [...mapTraces(viewer.current, { range, points: viewer.points, rangeNote }), ...missingOutlineTraces(viewer.current, reference)];
    return this.figure.react(traces, mapLayout({ lines }));
  }
}
