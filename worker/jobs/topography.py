"""The topography job: a test recording, a camera and a projector calibration in; the topography result out.

Two fan-outs, each joined by a pass in frame order, computing exactly what
`fringelab.pipelines.topography.topography_recording` computes in one sequential pass (a test holds them to the
bit):

    phase 0, chunks:   edges of each frame (a pure function of the frame)        -> chunks/edges-<first>.h5
    merge 0, in order: identity fixed on frame 0 and carried frame to frame;
                       Z, X, Y of every point; the grid from frame 0             -> chunks/track.npz, measure-*.npz
    phase 1, chunks:   the deflection grid and peak of each frame (pure again)   -> chunks/grid-<first>.npz
    merge 1, in order: the result file (TopographyWriter) and its summary        -> topography.h5

Gridding is the largest part of the per-frame work, which is why it is not left in the sequential pass.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from fringelab.pipelines.topography import result_writer
from fringelab.science.topography import SummaryTally
from worker.jobs.inputs import calibration_file, recording_input
from worker.runner import (
    Chunked,
    JobContext,
    chunk_frames_of,
    finite_or_none,
    frame_ranges,
    load_arrays,
    remove_chunk_files,
    save_arrays,
)


@dataclass
class _TopographyInputs:
    source: Any
    camera_model: Any
    projector: Any
    wanted: range
    settings: Any

    def close(self) -> None:
        self.source.close()


def _topography_inputs(context: JobContext) -> _TopographyInputs:
    """The recording (open: close it), calibrations, frames to write and settings of a topography job."""
    from fringelab.formats.camera import read_camera_json
    from fringelab.formats.projector import read_projector_calibration
    from fringelab.formats.recordings import open_recording
    from fringelab.science.topography import TopographySettings, frame_range

    spec = context.spec
    _recording, _camera, path = recording_input(context)
    camera_model = read_camera_json(calibration_file(context, spec["camera_calibration_id"]))
    projector = read_projector_calibration(calibration_file(context, spec["projector_calibration_id"]))
    source = open_recording(path)
    frames = spec.get("frames") or {}
    last = frames.get("last")
    wanted = frame_range(range(frames.get("first", 0), len(source) if last is None else last + 1), len(source))
    settings = TopographySettings(
        grid_step_mm=spec["grid_step_mm"], temporal_smoothing_frames=spec["temporal_smoothing_frames"]
    )
    return _TopographyInputs(source, camera_model, projector, wanted, settings)


def topography_entry(context: JobContext) -> Chunked:
    from fringelab.science.topography import check_recording_against, check_stripes_against

    inputs = _topography_inputs(context)
    try:
        first_frame = inputs.source[0]
        check_recording_against(first_frame.shape[:2], inputs.projector, inputs.camera_model)
        check_stripes_against(first_frame, inputs.projector)
        # identity is fixed on frame 0: edges are needed from there to the last frame written (+ the smoothing)
        stop = min(inputs.wanted.stop + inputs.settings.temporal_smoothing_frames, len(inputs.source))
    finally:
        inputs.close()
    context.log(f"topography of frames {inputs.wanted.start}..{inputs.wanted.stop - 1} (edges of 0..{stop - 1})")
    return Chunked(frame_ranges(stop, chunk_frames_of(context.spec, context.settings)), stage="locating edges")


def topography_locate(context: JobContext, first: int, stop: int) -> None:
    """Phase 0, any worker: the edges of frames [first, stop)."""
    from fringelab.formats.edges import write_edges
    from fringelab.science.topography import locate_test_edges

    inputs = _topography_inputs(context)
    try:
        frames = (inputs.source[i] for i in range(first, stop))
        edges = []
        for done, frame_edges in enumerate(locate_test_edges(frames, inputs.projector)):
            edges.append(frame_edges)
            context.progress(done + 1, stop - first, "locating edges")
    finally:
        inputs.close()
    with context.output(f"chunks/edges-{first:07d}.h5", publish=False) as temporary:
        write_edges(temporary, list(range(first, stop)), edges)


_MEASURE_COUNTS = ("n_tracks", "n_ended", "n_out_of_range", "n_unmatched")


def _sigma(measurement: Any) -> np.ndarray:
    sigma = measurement.sigma_z_mm
    return np.full(len(measurement.k), np.nan) if sigma is None else np.asarray(sigma, np.float64)


def _save_measurements(context: JobContext, first: int, measurements: list[Any]) -> None:
    sizes = [len(m.k) for m in measurements]
    save_arrays(
        context, f"chunks/measure-{first:07d}.npz",
        frame=np.array([m.frame for m in measurements], np.int64),
        offsets=np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64),
        k=np.concatenate([m.k for m in measurements]), line=np.concatenate([m.line for m in measurements]),
        points_obj_mm=np.concatenate([m.points_obj_mm for m in measurements]).reshape(-1, 3),
        edge_noise_px=np.array([m.edge_noise_px for m in measurements], np.float64),
        sigma_z_mm=np.concatenate([_sigma(m) for m in measurements]),
        **{name: np.array([getattr(m, name) for m in measurements], np.int64) for name in _MEASURE_COUNTS},
    )  # fmt: skip


def _load_measurements(context: JobContext, first: int) -> list[Any]:
    from fringelab.science.topography import FrameMeasurement

    data = load_arrays(context, f"chunks/measure-{first:07d}.npz")
    offsets = data["offsets"]
    return [
        FrameMeasurement(
            frame=int(frame),
            k=data["k"][lo:hi],
            line=data["line"][lo:hi],
            points_obj_mm=data["points_obj_mm"][lo:hi],
            edge_noise_px=float(data["edge_noise_px"][i]),
            sigma_z_mm=data["sigma_z_mm"][lo:hi],
            **{name: int(data[name][i]) for name in _MEASURE_COUNTS},
        )  # fmt: skip
        for i, (frame, lo, hi) in enumerate(zip(data["frame"], offsets[:-1], offsets[1:], strict=True))
    ]


def topography_track(context: JobContext, ranges: list[tuple[int, int]]) -> Chunked:
    """Merge of phase 0, in frame order: identity, tracking and 3-D points over the stored edges; the grid comes
    from the flat first frame. Then the gridding fans out over the frames to write."""
    from fringelab.formats.edges import read_edges
    from fringelab.science.topography import clamp_circle, grid_for_first_frame, track_and_measure

    inputs = _topography_inputs(context)
    inputs.close()  # only its length and path are used from here on
    wanted, settings, projector = inputs.wanted, inputs.settings, inputs.projector
    stop = ranges[-1][1]

    def stored_edges() -> Any:
        for first, chunk_stop in ranges:
            path = context.directory / f"chunks/edges-{first:07d}.h5"
            if not path.is_file():
                raise RuntimeError(f"the located edges of frames {first}..{chunk_stop - 1} are missing")
            frames, edges = read_edges(path)
            if list(frames) != list(range(first, chunk_stop)):
                raise RuntimeError(f"{path.name} holds frames {frames[0]}..{frames[-1]}, not {first}..{chunk_stop - 1}")
            for done, frame_edges in zip(frames, edges, strict=True):
                yield frame_edges
                context.progress(int(done) + 1, stop, "tracking")

    grid_ranges = [(wanted.start + a, wanted.start + b) for a, b in frame_ranges(len(wanted), chunk_frames_of(
        context.spec, context.settings))]  # fmt: skip
    pending: list[Any] = []
    for measurement in track_and_measure(stored_edges(), projector, inputs.camera_model, settings=settings):
        if measurement.frame == 0:
            grid, max_edge_mm = grid_for_first_frame(measurement, projector, settings)
            z = measurement.points_obj_mm[:, 2]
            z_flat = float(np.median(z))
            save_arrays(context, "chunks/track.npz", x_mm=grid.x_mm, y_mm=grid.y_mm, max_edge_mm=max_edge_mm,
                  z_flat_mm=z_flat, flat_rms_mm=float(np.sqrt(np.mean((z - z_flat) ** 2))),
                  clamp=np.array(clamp_circle(measurement.points_obj_mm[:, :2])),
                  n_tracks_first_frame=measurement.n_tracks)  # fmt: skip
        if measurement.frame not in wanted:
            continue
        pending.append(measurement)
        first, chunk_stop = next(r for r in grid_ranges if r[0] <= measurement.frame < r[1])
        if measurement.frame == chunk_stop - 1:
            _save_measurements(context, first, pending)
            pending = []
    return Chunked(grid_ranges, stage="gridding")


def topography_grid(context: JobContext, first: int, stop: int) -> None:
    """Phase 1, any worker: the deflection grid and peak of frames [first, stop)."""
    from fringelab.science.fields import Grid, field_peak
    from fringelab.science.topography import grid_measurement

    inputs = _topography_inputs(context)
    inputs.close()
    track = load_arrays(context, "chunks/track.npz")
    grid, z_flat = Grid(x_mm=track["x_mm"], y_mm=track["y_mm"]), float(track["z_flat_mm"])
    grids, peaks = [], []
    for done, measurement in enumerate(_load_measurements(context, first)):
        z_grid = grid_measurement(measurement, inputs.projector, grid, max_edge_mm=float(track["max_edge_mm"]))
        grids.append(z_grid)
        peaks.append(list(vars(field_peak(z_grid - z_flat, grid)).values()))
        context.progress(done + 1, stop - first, "gridding")
    save_arrays(context, f"chunks/grid-{first:07d}.npz", z_mm=np.array(grids), peak=np.array(peaks, np.float64))


def topography_write(context: JobContext, ranges: list[tuple[int, int]]) -> dict[str, Any]:
    """Merge of phase 1, in frame order: the result file, as `topography_recording` writes it."""
    from dataclasses import fields

    from fringelab.formats.sidecars import FrameTable, read_frames_csv
    from fringelab.science.fields import Grid, Peak

    inputs = _topography_inputs(context)
    source, wanted, projector = inputs.source, inputs.wanted, inputs.projector
    frames_text = source.sidecar_text("frames.csv")
    n_frames, where = len(source), str(source.path)
    inputs.close()
    log = (read_frames_csv(frames_text) if frames_text is not None else FrameTable.empty()).rows(list(range(n_frames)))
    track = load_arrays(context, "chunks/track.npz")
    z_flat, clamp = float(track["z_flat_mm"]), [float(v) for v in track["clamp"]]
    peak_names = [f.name for f in fields(Peak)]
    tally = SummaryTally()
    with context.output("topography.h5", media_type="application/x-hdf5") as temporary:
        writer = result_writer(
            temporary, grid=Grid(x_mm=track["x_mm"], y_mm=track["y_mm"]), max_edge_mm=float(track["max_edge_mm"]),
            z_flat_mm=z_flat, camera_model=inputs.camera_model, projector=projector, settings=inputs.settings,
            where=where, n_frames=n_frames, wanted=wanted,
        )  # fmt: skip
        with writer:
            for first, _stop in ranges:
                gridded = load_arrays(context, f"chunks/grid-{first:07d}.npz")
                for i, measurement in enumerate(_load_measurements(context, first)):
                    peak = Peak(**dict(zip(peak_names, map(float, gridded["peak"][i]), strict=True)))
                    row = tuple(float(log[name][measurement.frame]) for name in FrameTable.COLUMNS)
                    writer.append(measurement, gridded["z_mm"][i], peak, log=row)  # type: ignore[arg-type]
                    tally.add(peak, n_out_of_range=measurement.n_out_of_range)
                    context.progress(measurement.frame - wanted.start + 1, len(wanted), "writing")
            writer.close(tally.attrs(flat_rms_mm=float(track["flat_rms_mm"]),
                                     n_tracks_first_frame=int(track["n_tracks_first_frame"]), clamp=clamp))  # fmt: skip
    remove_chunk_files(context.directory)
    result = {
        "frames": [wanted.start, wanted.stop - 1],
        "flat_rms_mm": float(track["flat_rms_mm"]),
        "max_peak_w_mm": tally.max_peak_w_mm,
        "n_out_of_range_total": tally.n_out_of_range,
        "punch_axis_xy_mm": list(tally.punch_axis_xy_mm),
        "clamp_centre_xy_mm": clamp[:2],
        "clamp_radius_mm": clamp[2],
    }
    context.log(
        f"topography of {len(wanted)} frames: flat first frame RMS {result['flat_rms_mm']:.3f} mm, "
        f"peak deflection {result['max_peak_w_mm'] or float('nan'):.2f} mm"
    )
    return {key: finite_or_none(value) for key, value in result.items()}
