"""The topography job: a test recording, a camera and a projector calibration in; the topography result out.

One fan-out over the frames and a merge in frame order, computing exactly what
`fringelab.pipelines.topography.topography_recording` computes in one sequential pass (a test holds them to the
bit, whatever the chunking):

    entry:             the reference: frame 0's edges matched to the table, the rim that anchors the fringe
                       order, frame 0 measured, the grid from it                    -> chunks/reference.arrays
    phase 0, chunks:   for each frame on its own: edges, fringe order, Z, X, Y, what is missing, the grids of Z
                       and of its σ (compressed as the file stores them) and the peak (with temporal smoothing, h
                       frames either side are read too)                             -> chunks/frames-<first>.arrays
    merge 0, in order: the temporal cross-check of consecutive frames, the result file (TopographyWriter, which
                       stores the packed grids as they are) and its summary        -> topography.h5
                       (a chunk whose turn comes before anybody measured it is measured by the merge, straight
                       into the file: `_frames_of`)

No frame depends on the frames before it (the order is found per frame, anchored on the reference), so there is
no long in-order phase: the merge only writes, as the chunks come. Each worker process reads a calibration file
once (`_calibration`).
"""

from __future__ import annotations

import functools
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from fringelab.core.specs import TopographySpec
from fringelab.pipelines.topography import plate_nodes, result_writer
from fringelab.science.topography import SummaryTally, TemporalCrossCheck
from worker.jobs.inputs import calibration_file, recording_input
from worker.runner import (
    Chunked,
    InOrder,
    JobContext,
    array_records,
    finite_or_none,
    has_hand_over,
    load_arrays,
    planned_frame_ranges,
    read_array_records,
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


@functools.lru_cache(maxsize=4)
def _calibration(kind: str, path: Path, _stamp: tuple[int, int]) -> Any:
    """A calibration file read once per worker process (and per version of the file: its mtime and size are in
    the key), so the chunks of a job, and the jobs after it, reuse it and what is built from it once (the
    projector's packed table, the camera's scan-line rays)."""
    from fringelab.formats.camera import read_camera_json
    from fringelab.formats.projector import read_projector_calibration

    return read_camera_json(path) if kind == "camera" else read_projector_calibration(path)


def _cached_calibration(kind: str, path: Path) -> Any:
    stat = path.stat()
    return _calibration(kind, path, (stat.st_mtime_ns, stat.st_size))


def _topography_inputs(context: JobContext[TopographySpec]) -> _TopographyInputs:
    """The recording (open: close it), calibrations, frames to write and settings of a topography job."""
    from fringelab.formats.recordings import open_recording
    from fringelab.science.topography import TopographySettings, frame_range

    spec = context.spec
    _recording, _camera, path = recording_input(context)
    camera_model = _cached_calibration("camera", calibration_file(context, spec.camera_calibration_id))
    projector = _cached_calibration("projector", calibration_file(context, spec.projector_calibration_id))
    source = open_recording(path)
    last = spec.frames.last
    wanted = frame_range(range(spec.frames.first, len(source) if last is None else last + 1), len(source))
    settings = TopographySettings(
        grid_step_mm=spec.grid_step_mm, temporal_smoothing_frames=spec.temporal_smoothing_frames
    )
    return _TopographyInputs(source, camera_model, projector, wanted, settings)


def topography_entry(context: JobContext[TopographySpec]) -> Chunked:
    """The reference (frame 0), then the frames to write in chunks on any worker."""
    from fringelab.science.topography import (
        check_recording_against,
        check_stripes_against,
        clamp_circle,
        grid_for_first_frame,
        locate_test_edges,
        measure_frame,
        reference_for,
    )

    inputs = _topography_inputs(context)
    try:
        first_frame = inputs.source[0]
        check_recording_against(first_frame.shape[:2], inputs.projector, inputs.camera_model)
        check_stripes_against(first_frame, inputs.projector)
        edges = next(iter(locate_test_edges([first_frame], inputs.projector)))
    finally:
        inputs.close()
    projector, settings = inputs.projector, inputs.settings
    reference = reference_for(edges, projector, inputs.camera_model, settings)
    # Frame 0 is never smoothed (its window has no frame before it), so measured alone it is what a run gives.
    first = measure_frame(edges, reference, projector, inputs.camera_model, frame=0, settings=settings)
    grid, max_edge_mm = grid_for_first_frame(first, projector, settings)
    z = first.points_obj_mm[:, 2]
    z_flat = float(np.median(z))
    save_arrays(
        context, "chunks/reference.arrays",
        reference_t_px=reference.reference_t_px, rim=reference.rim, rim_circle_mm=np.array(reference.rim_circle_mm),
        cell_area_mm2=reference.cell_area_mm2, x_mm=grid.x_mm, y_mm=grid.y_mm, max_edge_mm=max_edge_mm,
        z_flat_mm=z_flat, flat_rms_mm=float(np.sqrt(np.mean((z - z_flat) ** 2))),
        clamp=np.array(clamp_circle(first.points_obj_mm[:, :2])), n_tracks_first_frame=first.n_tracks,
        plate_nodes=plate_nodes(first, projector, grid, max_edge_mm=max_edge_mm),
    )  # fmt: skip
    wanted = inputs.wanted
    context.log(f"topography of frames {wanted.start}..{wanted.stop - 1}, each ordered on its own")
    ranges = [(wanted.start + a, wanted.start + b)
              for a, b in planned_frame_ranges(len(wanted), context.spec.chunk_frames, context.settings)]  # fmt: skip
    return Chunked(ranges, stage="measuring")


def _reference(context: JobContext[TopographySpec]) -> Any:
    from fringelab.science.order import OrderReference

    data = load_arrays(context, "chunks/reference.arrays")
    reference = OrderReference(
        reference_t_px=data["reference_t_px"], rim=data["rim"],
        rim_circle_mm=tuple(float(v) for v in data["rim_circle_mm"]),  # type: ignore[arg-type]
        cell_area_mm2=data["cell_area_mm2"],
    )  # fmt: skip
    return reference, data


_MEASURE_COUNTS = (
    "n_tracks", "n_ended", "n_out_of_range", "n_unmatched", "n_order_unresolved", "n_order_conflict_points",
    "n_order_conflicts",
)  # fmt: skip


def topography_measure(context: JobContext[TopographySpec], first: int, stop: int) -> None:
    """Phase 0, any worker: frames [first, stop) measured (`_measured`) and handed over one record per frame."""
    with array_records(context, _hand_over_name(first)) as write:
        for record in _measured(context, first, stop):
            write(**record)


def _hand_over_name(first: int) -> str:
    return f"chunks/frames-{first:07d}.arrays"


def _measured(
    context: JobContext[TopographySpec], first: int, stop: int, *, report: bool = True
) -> Iterator[dict[str, np.ndarray]]:
    """Frames [first, stop), each on its own: measured, gridded (Z and σ) and packed as the result file stores
    them, as records (one per frame) that `_frames_of` reads, whether handed over or not: the merge only writes.
    report: the progress is the context's chunk's."""
    from fringelab.formats.topography import pack_grids
    from fringelab.science.coverage import MISSING_REASONS
    from fringelab.science.fields import Grid, field_peak
    from fringelab.science.topography import grid_measurement_with_sigma, locate_test_edges, track_and_measure

    inputs = _topography_inputs(context)
    projector, settings = inputs.projector, inputs.settings
    reference, data = _reference(context)
    grid, z_flat = Grid(x_mm=data["x_mm"], y_mm=data["y_mm"]), float(data["z_flat_mm"])
    # Temporal smoothing looks h frames either way: read them too (the sequential pass reads no further).
    h = settings.temporal_smoothing_frames
    lo, hi = max(0, first - h), min(len(inputs.source), stop + h)
    try:
        frames = (inputs.source[i] for i in range(lo, hi))
        located = locate_test_edges(frames, projector)
        for m in track_and_measure(
            located, projector, inputs.camera_model, settings=settings, first_frame=lo, reference=reference
        ):
            if not first <= m.frame < stop:
                continue
            if m.coverage is None:
                raise RuntimeError("a measurement came without its coverage")
            z_grid, sigma_grid = grid_measurement_with_sigma(m, projector, grid, max_edge_mm=float(data["max_edge_mm"]))
            packed = pack_grids(z_grid, sigma_grid)
            sigma = np.full(len(m.k), np.nan) if m.sigma_z_mm is None else m.sigma_z_mm
            scalars = [m.frame, m.edge_noise_px, m.coverage.visible_area_mm2, m.coverage.measured_area_mm2,
                       *(m.coverage.missing_mm2[name] for name in MISSING_REASONS),
                       *vars(field_peak(z_grid - z_flat, grid)).values(),
                       *(getattr(m, name) for name in _MEASURE_COUNTS)]  # fmt: skip
            yield dict(
                k=m.k, line=m.line,
                # X, Y and σ as the file stores them; Z in full, for the temporal cross-check of the merge
                xy_mm=m.points_obj_mm[:, :2].astype(np.float32), z_mm=m.points_obj_mm[:, 2],
                sigma_z_mm=np.asarray(sigma, np.float32),
                packed_z_mm=np.frombuffer(packed.z_mm, np.uint8),
                packed_sigma_w_mm=np.frombuffer(packed.sigma_w_mm, np.uint8), z_finite=np.packbits(packed.z_finite),
                scalars=np.array(scalars, np.float64),  # in one record (each costs a header); counts exact
            )  # fmt: skip
            if report:  # (the chunk's end is recorded when it is marked done: the last frame need not be)
                context.progress(m.frame - first, stop - first, "measuring")
    finally:
        inputs.close()


def _frames_of(
    context: JobContext[TopographySpec], turn: InOrder, grid_shape: tuple[int, int]
) -> Iterator[tuple[Any, Any, Any]]:
    """The frames of a chunk's turn one at a time, (measurement, peak, packed grids): measured here when the turn
    says so, or when its hand-over is missing (a merge that ran before, and died, measured it straight into its
    own file or kept it in its process), else read from the hand-over. Either way from the same records, so the
    file is the same."""
    from dataclasses import fields

    from fringelab.formats.topography import PackedGrids
    from fringelab.science.coverage import MISSING_REASONS, FrameCoverage
    from fringelab.science.fields import Peak
    from fringelab.science.topography import FrameMeasurement

    if turn.measure_here is not None:
        records = _measured(turn.measure_here, turn.first, turn.stop)
    elif not has_hand_over(context, _hand_over_name(turn.first)):
        records = _measured(context, turn.first, turn.stop, report=False)  # the chunk is done already
    else:
        records = read_array_records(context, _hand_over_name(turn.first))
    peak_names = [f.name for f in fields(Peak)]
    n_missing, n_peak = len(MISSING_REASONS), len(peak_names)
    for record in records:
        scalars = record["scalars"].tolist()
        frame, edge_noise_px, visible_area_mm2, measured_area_mm2 = scalars[:4]
        missing, peak_values, count_values = np.split(scalars[4:], [n_missing, n_missing + n_peak])
        counts = dict(zip(_MEASURE_COUNTS, map(int, count_values), strict=True))
        points = np.empty((len(record["k"]), 3))  # float64 as measured: X, Y in float32 lose nothing written
        points[:, :2], points[:, 2] = record["xy_mm"], record["z_mm"]
        measurement = FrameMeasurement(
            frame=int(frame), k=record["k"], line=record["line"], points_obj_mm=points,
            edge_noise_px=edge_noise_px, sigma_z_mm=record["sigma_z_mm"],
            coverage=FrameCoverage(
                visible_area_mm2=visible_area_mm2, measured_area_mm2=measured_area_mm2,
                missing_mm2={name: float(v) for name, v in zip(MISSING_REASONS, missing, strict=True)},
                n_order_conflicts=counts["n_order_conflicts"],
            ),
            **counts,  # type: ignore[arg-type]  # (the counts by name: mypy cannot match a dict's keys)
        )  # fmt: skip
        peak = Peak(**dict(zip(peak_names, map(float, peak_values), strict=True)))
        finite = np.unpackbits(record["z_finite"], count=grid_shape[0] * grid_shape[1]).reshape(grid_shape)
        packed = PackedGrids(
            z_mm=record["packed_z_mm"].tobytes(), sigma_w_mm=record["packed_sigma_w_mm"].tobytes(),
            z_finite=finite.view(bool),
        )  # fmt: skip
        yield measurement, peak, packed


def topography_write(context: JobContext[TopographySpec], turns: Iterator[InOrder]) -> dict[str, Any]:
    """Merge of phase 0, in frame order: the result file, as `topography_recording` writes it, a chunk at a time
    as each one's turn comes (the progress is the chunks')."""
    from fringelab.formats.recordings import recording_log
    from fringelab.formats.topography import write_xdmf
    from fringelab.science.fields import Grid

    inputs = _topography_inputs(context)
    source, wanted, projector = inputs.source, inputs.wanted, inputs.projector
    log = recording_log(source)  # frames.csv, else the container's own times (a .cine's stamps)
    n_frames, where = len(source), str(source.path)
    inputs.close()
    _, track = _reference(context)
    z_flat, clamp = float(track["z_flat_mm"]), [float(v) for v in track["clamp"]]
    tally = SummaryTally()
    cross_check = TemporalCrossCheck(projector)  # over the chunks' frames in order, so whatever the chunking
    with context.output("topography.h5", media_type="application/x-hdf5") as temporary:
        writer = result_writer(
            temporary, grid=Grid(x_mm=track["x_mm"], y_mm=track["y_mm"]), max_edge_mm=float(track["max_edge_mm"]),
            z_flat_mm=z_flat, camera_model=inputs.camera_model, projector=projector, settings=inputs.settings,
            where=where, n_frames=n_frames, wanted=wanted, time_source=log.time_source,
            centre_xy_mm=(clamp[0], clamp[1]), plate_nodes=track["plate_nodes"],
        )  # fmt: skip
        with writer:
            grid_shape = (len(track["y_mm"]), len(track["x_mm"]))
            for turn in turns:
                for measured, peak, packed in _frames_of(context, turn, grid_shape):
                    measurement = cross_check.checked(measured)
                    writer.append(measurement, None, peak, log=log.row(measurement.frame),
                                  camera_frame=int(log.camera_frame[measurement.frame]), packed=packed)  # fmt: skip
                    tally.add(peak, n_out_of_range=measurement.n_out_of_range, measurement=measurement)
            tally.require_ordered(where)
            writer.close(tally.attrs(flat_rms_mm=float(track["flat_rms_mm"]),
                                     n_tracks_first_frame=int(track["n_tracks_first_frame"]), clamp=clamp))  # fmt: skip
    with context.output("topography.xdmf", media_type="application/xml") as temporary:
        write_xdmf(context.directory / "topography.h5", temporary)  # ParaView opens it beside topography.h5
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
