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

No frame depends on the frames before it (the order is found per frame, anchored on the reference), so there is
no long in-order phase: the merge only writes. Each worker process reads a calibration file once (`_calibration`).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from fringelab.pipelines.topography import result_writer
from fringelab.science.topography import SummaryTally, TemporalCrossCheck
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


def _topography_inputs(context: JobContext) -> _TopographyInputs:
    """The recording (open: close it), calibrations, frames to write and settings of a topography job."""
    from fringelab.formats.recordings import open_recording
    from fringelab.science.topography import TopographySettings, frame_range

    spec = context.spec
    _recording, _camera, path = recording_input(context)
    camera_model = _cached_calibration("camera", calibration_file(context, spec["camera_calibration_id"]))
    projector = _cached_calibration("projector", calibration_file(context, spec["projector_calibration_id"]))
    source = open_recording(path)
    frames = spec.get("frames") or {}
    last = frames.get("last")
    wanted = frame_range(range(frames.get("first", 0), len(source) if last is None else last + 1), len(source))
    settings = TopographySettings(
        grid_step_mm=spec["grid_step_mm"], temporal_smoothing_frames=spec["temporal_smoothing_frames"]
    )
    return _TopographyInputs(source, camera_model, projector, wanted, settings)


def topography_entry(context: JobContext) -> Chunked:
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
    )  # fmt: skip
    wanted = inputs.wanted
    context.log(f"topography of frames {wanted.start}..{wanted.stop - 1}, each ordered on its own")
    ranges = [(wanted.start + a, wanted.start + b) for a, b in frame_ranges(len(wanted), chunk_frames_of(
        context.spec, context.settings, len(wanted)))]  # fmt: skip
    return Chunked(ranges, stage="measuring")


def _reference(context: JobContext) -> Any:
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


def _sigma(measurement: Any) -> np.ndarray:
    sigma = measurement.sigma_z_mm
    return np.full(len(measurement.k), np.nan, np.float32) if sigma is None else np.asarray(sigma, np.float32)


def topography_measure(context: JobContext, first: int, stop: int) -> None:
    """Phase 0, any worker: frames [first, stop) measured, gridded (Z and σ) and packed as the result file stores
    them, each on its own; the merge only writes."""
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
    measurements, finite, packed, peaks = [], [], [], []
    try:
        frames = (inputs.source[i] for i in range(lo, hi))
        located = locate_test_edges(frames, projector)
        for measurement in track_and_measure(
            located, projector, inputs.camera_model, settings=settings, first_frame=lo, reference=reference
        ):
            if not first <= measurement.frame < stop:
                continue
            z_grid, sigma_grid = grid_measurement_with_sigma(
                measurement, projector, grid, max_edge_mm=float(data["max_edge_mm"])
            )
            measurements.append(measurement)
            chunks = pack_grids(z_grid, sigma_grid)
            packed.extend([chunks.z_mm, chunks.sigma_w_mm])
            finite.append(np.packbits(chunks.z_finite))
            peaks.append(list(vars(field_peak(z_grid - z_flat, grid)).values()))
            # (the chunk's end is recorded when it is marked done: the last frame need not be)
            context.progress(measurement.frame - first, stop - first, "measuring")
    finally:
        inputs.close()
    sizes = [len(m.k) for m in measurements]
    covered = [m.coverage for m in measurements if m.coverage is not None]
    if len(covered) != len(measurements):
        raise RuntimeError("a measurement came without its coverage")
    coverage = {
        "visible_area_mm2": [c.visible_area_mm2 for c in covered],
        "measured_area_mm2": [c.measured_area_mm2 for c in covered],
        **{f"missing_{name}_mm2": [c.missing_mm2[name] for c in covered] for name in MISSING_REASONS},
    }
    points = np.concatenate([m.points_obj_mm for m in measurements]).reshape(-1, 3)
    save_arrays(
        context, f"chunks/frames-{first:07d}.arrays",
        frame=np.array([m.frame for m in measurements], np.int64),
        offsets=np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64),
        k=np.concatenate([m.k for m in measurements]), line=np.concatenate([m.line for m in measurements]),
        # X and Y as the file stores them; Z in full, for the temporal cross-check of the merge
        xy_mm=points[:, :2].astype(np.float32), z_mm=points[:, 2],
        edge_noise_px=np.array([m.edge_noise_px for m in measurements], np.float64),
        z_finite=np.array(finite, np.uint8), peak=np.array(peaks, np.float64),
        packed=np.frombuffer(b"".join(packed), np.uint8),
        packed_offsets=np.concatenate([[0], np.cumsum([len(c) for c in packed])]).astype(np.int64),
        sigma_z_mm=np.concatenate([_sigma(m) for m in measurements]),
        **{name: np.array([getattr(m, name) for m in measurements], np.int64) for name in _MEASURE_COUNTS},
        **{name: np.array(values, np.float64) for name, values in coverage.items()},
    )  # fmt: skip


def _load_frames(context: JobContext, first: int) -> tuple[list[Any], Any]:
    from fringelab.science.coverage import MISSING_REASONS, FrameCoverage
    from fringelab.science.topography import FrameMeasurement

    data = load_arrays(context, f"chunks/frames-{first:07d}.arrays")
    offsets = data["offsets"]
    # float64 as measured: X, Y were stored as the file stores them (float32), which loses nothing written
    points = np.column_stack([data["xy_mm"].astype(np.float64), data["z_mm"]])
    measurements = [
        FrameMeasurement(
            frame=int(frame),
            k=data["k"][lo:hi],
            line=data["line"][lo:hi],
            points_obj_mm=points[lo:hi],
            edge_noise_px=float(data["edge_noise_px"][i]),
            coverage=FrameCoverage(
                visible_area_mm2=float(data["visible_area_mm2"][i]),
                measured_area_mm2=float(data["measured_area_mm2"][i]),
                missing_mm2={name: float(data[f"missing_{name}_mm2"][i]) for name in MISSING_REASONS},
                n_order_conflicts=int(data["n_order_conflicts"][i]),
            ),
            sigma_z_mm=data["sigma_z_mm"][lo:hi],
            **{name: int(data[name][i]) for name in _MEASURE_COUNTS},
        )  # fmt: skip
        for i, (frame, lo, hi) in enumerate(zip(data["frame"], offsets[:-1], offsets[1:], strict=True))
    ]
    return measurements, data


def _packed(data: Any, i: int, track: Any) -> Any:
    """The packed grids of the chunk's frame i (`topography_measure`)."""
    from fringelab.formats.topography import PackedGrids

    packed, at = data["packed"], data["packed_offsets"]
    shape = (len(track["y_mm"]), len(track["x_mm"]))
    return PackedGrids(
        z_mm=packed[at[2 * i] : at[2 * i + 1]].tobytes(), sigma_w_mm=packed[at[2 * i + 1] : at[2 * i + 2]].tobytes(),
        z_finite=np.unpackbits(data["z_finite"][i], count=shape[0] * shape[1]).reshape(shape).view(bool),
    )  # fmt: skip


def topography_write(context: JobContext, ranges: list[tuple[int, int]]) -> dict[str, Any]:
    """Merge of phase 0, in frame order: the result file, as `topography_recording` writes it."""
    from dataclasses import fields

    from fringelab.formats.recordings import recording_log
    from fringelab.formats.topography import write_xdmf
    from fringelab.science.fields import Grid, Peak

    inputs = _topography_inputs(context)
    source, wanted, projector = inputs.source, inputs.wanted, inputs.projector
    log = recording_log(source)  # frames.csv, else the container's own times (a .cine's stamps)
    n_frames, where = len(source), str(source.path)
    inputs.close()
    _, track = _reference(context)
    z_flat, clamp = float(track["z_flat_mm"]), [float(v) for v in track["clamp"]]
    peak_names = [f.name for f in fields(Peak)]
    tally = SummaryTally()
    cross_check = TemporalCrossCheck(projector)  # over the chunks' frames in order, so whatever the chunking
    with context.output("topography.h5", media_type="application/x-hdf5") as temporary:
        writer = result_writer(
            temporary, grid=Grid(x_mm=track["x_mm"], y_mm=track["y_mm"]), max_edge_mm=float(track["max_edge_mm"]),
            z_flat_mm=z_flat, camera_model=inputs.camera_model, projector=projector, settings=inputs.settings,
            where=where, n_frames=n_frames, wanted=wanted, time_source=log.time_source,
            centre_xy_mm=(clamp[0], clamp[1]),
        )  # fmt: skip
        with writer:
            for first, _stop in ranges:
                measurements, gridded = _load_frames(context, first)
                for i, measurement in enumerate(map(cross_check.checked, measurements)):
                    peak = Peak(**dict(zip(peak_names, map(float, gridded["peak"][i]), strict=True)))
                    writer.append(measurement, None, peak, log=log.row(measurement.frame),
                                  camera_frame=int(log.camera_frame[measurement.frame]),
                                  packed=_packed(gridded, i, track))  # fmt: skip
                    tally.add(peak, n_out_of_range=measurement.n_out_of_range, measurement=measurement)
                    context.progress(measurement.frame - wanted.start + 1, len(wanted), "writing")
            tally.require_ordered(where)
            writer.close(tally.attrs(flat_rms_mm=float(track["flat_rms_mm"]),
                                     n_tracks_first_frame=int(track["n_tracks_first_frame"]), clamp=clamp))  # fmt: skip
    with context.output("topography.xdmf", media_type="application/xml") as temporary:
        write_xdmf(context.directory / "topography.h5", temporary)  # ParaView opens it beside topography.h5
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
