"""Topography of a whole test recording into its result file (docs/method.md §5–6).

What the command line calls, and the sequential reference the worker's frame-parallel topography job must equal
bit for bit. The stages (edges, identity, Z, X and Y, gridding) live in `fringelab.science.topography`; the
result file is written by `fringelab.formats.topography`.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from fringelab.formats.camera import calibration_as_dict
from fringelab.formats.hdf5 import json_text
from fringelab.formats.recordings import recording_log
from fringelab.formats.topography import PEAK_REGION_RADIUS_MM, WRITER_THREADS, TopographyWriter, write_xdmf
from fringelab.pipelines.provenance import code_versions
from fringelab.science import Cancelled
from fringelab.science.calibration import CameraCalibration, ProgressCallback
from fringelab.science.fields import Grid, field_peak
from fringelab.science.fringes import FrameEdges
from fringelab.science.projector import CameraModel, ProjectorCalibration, camera_fingerprint
from fringelab.science.topography import (
    FrameMeasurement,
    SummaryTally,
    TemporalCrossCheck,
    TopographyError,
    TopographySettings,
    check_recording_against,
    check_stripes_against,
    clamp_circle,
    frame_range,
    grid_for_first_frame,
    grid_measurement,
    grid_measurement_with_sigma,
    locate_test_edges,
    measure_frame,
    reference_for,
    track_and_measure,
)


@dataclass(frozen=True)
class TopographySummary:
    """What a topography run produced: the result file and its headline numbers (also in /summary)."""

    path: Path
    frames: range
    flat_rms_mm: float
    max_peak_w_mm: float
    n_out_of_range_total: int
    clamp_centre_xy_mm: tuple[float, float]
    clamp_radius_mm: float
    punch_axis_xy_mm: tuple[float, float]


def topography_recording(
    source: Any,
    camera_model: CameraModel,
    projector: ProjectorCalibration,
    *,
    out_path: str | Path,
    frames: range | Sequence[int] | None = None,
    settings: TopographySettings | None = None,
    edges: Iterable[FrameEdges] | None = None,
    progress: ProgressCallback | None = None,
    should_cancel: Callable[[], bool] | None = None,
    writer_threads: int = WRITER_THREADS,
) -> TopographySummary:
    """Topography of a test recording into an HDF5 result file (layout in `topography_files`): what the CLI and
    the tasks call.

    source: a frame source from `readers.open_recording` (frames.csv beside the frames, if any, is stored with
    the result). frames: the frames to write (a contiguous range); the fringe order is anchored on frame 0 (the
    flat reference) and found in every frame on its own, so only frame 0 and the frames written (plus the
    temporal smoothing half-width either way) are read, and the frames written are identical to those of a run
    over the whole recording. edges: already located edges
    of frames 0, 1, ... (e.g. from chunks run in parallel, see `topography_files.read_edges`); None locates
    them here. progress(done, total, stage) after every frame ("frames"), should_cancel() polled between frames
    (Cancelled; the partial file is removed). writer_threads: threads that compress the file's chunks beside the
    measurement (0: all in the calling thread).

    Memory does not grow with the number of frames: frames are read, located, tracked, gridded and written one
    at a time.
    """

    settings = TopographySettings() if settings is None else settings
    n_frames = len(source)
    wanted = frame_range(frames, n_frames)
    # Every frame is measured on its own against the reference (frame 0); only temporal smoothing looks h frames
    # either way, so frames lo..stop − 1 are read besides frame 0.
    h = settings.temporal_smoothing_frames
    lo, stop = max(0, wanted.start - h), min(wanted.stop + h, n_frames)
    first_image = source[0]
    check_recording_against(np.shape(first_image)[:2], projector, camera_model)
    if edges is None:
        check_stripes_against(first_image, projector)
    # Frames the log does not list (or no log at all) get NaN; the time axis falls back on the container's.
    log = recording_log(source)
    indices = ([0] if lo > 0 else []) + list(range(lo, stop))

    def located() -> Iterator[FrameEdges]:
        supplied = iter(edges) if edges is not None else None
        position = 0  # of the supplied edges (frames 0, 1, ...)
        for done, index in enumerate(indices):
            if should_cancel is not None and should_cancel():
                raise Cancelled(f"cancelled after {done} of {len(indices)} frames")
            if supplied is not None:
                try:
                    while position <= index:
                        frame_edges = next(supplied)
                        position += 1
                except StopIteration:
                    raise ValueError(f"edges: {position} located frames given, {stop} needed") from None
            else:
                image = first_image if index == 0 else source[index]
                frame_edges = next(locate_test_edges([image], projector))
            yield frame_edges
            if progress is not None:
                progress(done + 1, len(indices), "frames")

    where = str(getattr(source, "path", "recording"))
    writer: TopographyWriter | None = None
    tally = SummaryTally()
    stream = located()
    try:
        reference_edges = next(stream)
        reference = reference_for(reference_edges, projector, camera_model, settings)
        # Frame 0 is never smoothed (no frame before it), so measured alone it is what the stream gives.
        first = measure_frame(reference_edges, reference, projector, camera_model, frame=0, settings=settings)
        grid, max_edge_mm = grid_for_first_frame(first, projector, settings)
        z = first.points_obj_mm[:, 2]
        z_flat = float(np.median(z))
        flat_rms = float(np.sqrt(np.mean((z - z_flat) ** 2)))
        clamp = clamp_circle(first.points_obj_mm[:, :2])
        n_first_tracks = first.n_tracks
        writer = result_writer(
            out_path, grid=grid, max_edge_mm=max_edge_mm, z_flat_mm=z_flat, camera_model=camera_model,
            projector=projector, settings=settings, where=where, n_frames=n_frames, wanted=wanted,
            centre_xy_mm=(clamp[0], clamp[1]), time_source=log.time_source, threads=writer_threads,
            plate_nodes=plate_nodes(first, projector, grid, max_edge_mm=max_edge_mm),
        )  # fmt: skip
        rest = itertools.chain([reference_edges], stream) if lo == 0 else stream
        cross_check = TemporalCrossCheck(projector)
        for measurement in track_and_measure(
            rest, projector, camera_model, settings=settings, first_frame=lo, reference=reference
        ):
            if measurement.frame not in wanted:
                continue
            measurement = cross_check.checked(measurement)
            z_grid, sigma_grid = grid_measurement_with_sigma(measurement, projector, grid, max_edge_mm=max_edge_mm)
            peak = field_peak(z_grid - z_flat, grid)
            writer.append(
                measurement, z_grid, peak, log=log.row(measurement.frame), sigma_grid_mm=sigma_grid,
                camera_frame=int(log.camera_frame[measurement.frame]),
            )  # fmt: skip
            tally.add(peak, n_out_of_range=measurement.n_out_of_range, measurement=measurement)
        if writer is None:
            raise TopographyError(f"{where}: the recording has no frames")
        tally.require_ordered(where)
        path = writer.close(tally.attrs(flat_rms_mm=flat_rms, n_tracks_first_frame=n_first_tracks, clamp=clamp))
        write_xdmf(path)  # the ParaView sidecar beside the result
    except BaseException:
        if writer is not None:
            writer.abort()
        raise
    return TopographySummary(
        path=path,
        frames=wanted,
        flat_rms_mm=flat_rms,
        max_peak_w_mm=tally.max_peak_w_mm,
        n_out_of_range_total=tally.n_out_of_range,
        clamp_centre_xy_mm=(clamp[0], clamp[1]),
        clamp_radius_mm=clamp[2],
        punch_axis_xy_mm=tally.punch_axis_xy_mm,
    )


def result_writer(
    path: str | Path,
    *,
    grid: Grid,
    max_edge_mm: float,
    z_flat_mm: float,
    camera_model: CameraModel,
    projector: ProjectorCalibration,
    settings: TopographySettings,
    where: str,
    n_frames: int,
    wanted: range,
    time_source: str = "",
    centre_xy_mm: tuple[float, float] = (float("nan"), float("nan")),
    threads: int = WRITER_THREADS,
    plate_nodes: np.ndarray | None = None,
) -> TopographyWriter:
    """The result file's writer with everything a result records of how it was made (settings, provenance,
    the calibrations it used). plate_nodes: the grid nodes the reference frame measured (`plate_nodes`)."""

    provenance = {"input": where, "n_frames_in_recording": n_frames, "frames_written": [wanted.start, wanted.stop]}
    return TopographyWriter(
        path,
        grid=grid,
        max_edge_mm=max_edge_mm,
        z_flat_mm=z_flat_mm,
        axis=projector.axis,
        attrs={
            "time_source": time_source,
            "settings_json": json_text(asdict(settings)),
            "edge_settings_json": json_text(asdict(projector.edges)),
            "provenance_json": json_text({**provenance, **code_versions()}),
        },
        calibration_attrs=_calibration_attrs(camera_model, projector),
        peak_region_mm=(centre_xy_mm[0], centre_xy_mm[1], PEAK_REGION_RADIUS_MM),
        plate_nodes=plate_nodes,
        punch_radius_mm=settings.punch_radius_mm,
        threads=threads,
    )


def plate_nodes(first: FrameMeasurement, projector: ProjectorCalibration, grid: Grid, *, max_edge_mm: float) -> Any:
    """The grid nodes (ny, nx) bool that the reference (first) frame measured: the plate, for the rule of a
    measured peak (`science.peaks`)."""
    return np.isfinite(grid_measurement(first, projector, grid, max_edge_mm=max_edge_mm))


def _calibration_attrs(camera_model: CameraModel, projector: ProjectorCalibration) -> dict[str, Any]:
    """What the result records of the calibrations it used (provenance)."""

    if isinstance(camera_model, CameraCalibration):
        camera_json = json_text(calibration_as_dict(camera_model))
    else:
        camera_json = json_text(asdict(camera_model.camera))
    projector_doc = {
        "image_shape": list(projector.image_shape_hw_px), "axis": projector.axis, "period_px": projector.period_px,
        "reference_z_mm": projector.reference_z_mm, "z_mm": projector.z_mm, "n_edges": projector.n_edges,
        "edges": asdict(projector.edges), "qa": asdict(projector.qa), "provenance": projector.provenance,
    }  # fmt: skip
    return {
        "camera_json": camera_json,
        "camera_fingerprint": camera_fingerprint(camera_model.camera),
        "projector_json": json_text(projector_doc),
        "projector_camera_fingerprint": projector.camera_fingerprint,
    }
