"""Topography of a whole test recording into its result file (docs/method.md §5–6).

What the command line calls. Its two stages, the reference (`reference_stage`, frame 0) and the frames
(`frame_stage`, each frame on its own against the reference), are also what the worker's frame-parallel
topography job calls (its entry task and its chunks), so the two write the same file; `TopographyReference` and
`PackedFrame` are what the job hands from one task to the next (`as_record` / `from_record`). The science of each
step (edges, identity, Z, X and Y, gridding) lives in `fringelab.science.topography`; the result file is written
by `fringelab.formats.topography`.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np

from fringelab.formats.camera import calibration_as_dict
from fringelab.formats.hdf5 import json_text
from fringelab.formats.recordings import recording_log
from fringelab.formats.topography import (
    PEAK_REGION_RADIUS_MM,
    WRITER_THREADS,
    PackedGrids,
    TopographyWriter,
    pack_grids,
    write_xdmf,
)
from fringelab.pipelines.provenance import code_versions
from fringelab.science import Cancelled, MeasurementError
from fringelab.science.calibration import CameraCalibration, ProgressCallback
from fringelab.science.coverage import MISSING_REASONS, FrameCoverage
from fringelab.science.fields import Grid, Peak, field_peak
from fringelab.science.fringes import FrameEdges
from fringelab.science.graycode import Decoding, decode
from fringelab.science.order import OrderReference
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
    code: Decoding | None = None,
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
    measurement (0: all in the calling thread). code: a Gray code recorded with the plate at rest
    (`decode_reference_code`), which gives frame 0's order (`reference_stage`).

    Memory does not grow with the number of frames: frames are read, located, tracked, gridded and written one
    at a time.
    """

    settings = TopographySettings() if settings is None else settings
    n_frames = len(source)
    wanted = frame_range(frames, n_frames)
    read = frames_read(wanted, n_frames, settings)  # besides frame 0
    lo, stop = read.start, read.stop
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
        reference = reference_stage(reference_edges, projector, camera_model, settings, code=code)
        writer = result_writer(
            out_path, reference=reference, camera_model=camera_model, projector=projector, settings=settings,
            where=where, n_frames=n_frames, wanted=wanted, time_source=log.time_source, threads=writer_threads,
        )  # fmt: skip
        rest = itertools.chain([reference_edges], stream) if lo == 0 else stream
        cross_check = TemporalCrossCheck(projector)
        for frame in frame_stage(rest, reference, projector, camera_model, settings, first_frame=lo, wanted=wanted):
            measurement = cross_check.checked(frame.measurement)
            writer.append(
                measurement, frame.z_grid_mm, frame.peak, log=log.row(measurement.frame),
                sigma_grid_mm=frame.sigma_grid_mm, camera_frame=int(log.camera_frame[measurement.frame]),
            )  # fmt: skip
            tally.add(frame.peak, n_out_of_range=measurement.n_out_of_range, measurement=measurement)
        if writer is None:
            raise TopographyError(f"{where}: the recording has no frames")
        tally.require_ordered(where)
        path = writer.close(reference.summary_attrs(tally))
        write_xdmf(path)  # the ParaView sidecar beside the result
    except BaseException:
        if writer is not None:
            writer.abort()
        raise
    clamp = reference.clamp
    return TopographySummary(
        path=path,
        frames=wanted,
        flat_rms_mm=reference.flat_rms_mm,
        max_peak_w_mm=writer.max_measured_peak_w_mm,  # of the frames whose peak was measured
        n_out_of_range_total=tally.n_out_of_range,
        clamp_centre_xy_mm=(clamp[0], clamp[1]),
        clamp_radius_mm=clamp[2],
        punch_axis_xy_mm=tally.punch_axis_xy_mm,
    )


def result_writer(
    path: str | Path,
    *,
    reference: TopographyReference,
    camera_model: CameraModel,
    projector: ProjectorCalibration,
    settings: TopographySettings,
    where: str,
    n_frames: int,
    wanted: range,
    time_source: str = "",
    threads: int = WRITER_THREADS,
) -> TopographyWriter:
    """The result file's writer with everything a result records of how it was made (settings, provenance,
    the calibrations it used), on the reference's grid."""

    provenance = {"input": where, "n_frames_in_recording": n_frames, "frames_written": [wanted.start, wanted.stop]}
    return TopographyWriter(
        path,
        grid=reference.grid,
        max_edge_mm=reference.max_edge_mm,
        z_flat_mm=reference.z_flat_mm,
        axis=projector.axis,
        attrs={
            "time_source": time_source,
            "settings_json": json_text(asdict(settings)),
            "edge_settings_json": json_text(asdict(projector.edges)),
            "provenance_json": json_text({**provenance, **code_versions()}),
        },
        calibration_attrs=_calibration_attrs(camera_model, projector),
        peak_region_mm=(reference.clamp[0], reference.clamp[1], PEAK_REGION_RADIUS_MM),
        plate_nodes=reference.plate_nodes,
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


# ------------------------------------------------------------------------------------------------------ stages
# The two stages of a topography, called by `topography_recording` (one sequential pass) and by the worker's
# topography job (the reference in its entry task, the frames in chunks on any worker, written in frame order by
# its merge): one orchestration, so the two give the same file.


@dataclass(frozen=True)
class TopographyReference:
    """The reference stage's answer (frame 0, the flat plate): what anchors the fringe order in every frame, the
    grid, and what the result records of the flat plate. clamp: (X, Y, radius) of the clamp circle, mm;
    plate_nodes: (ny, nx) bool, the grid nodes frame 0 measured (`plate_nodes`)."""

    order: OrderReference
    grid: Grid
    max_edge_mm: float
    z_flat_mm: float
    flat_rms_mm: float
    clamp: tuple[float, float, float]
    n_tracks_first_frame: int
    plate_nodes: np.ndarray

    def summary_attrs(self, tally: SummaryTally) -> dict[str, Any]:
        """The result file's /summary attributes, of the frames `tally` counted, and where frame 0's order came
        from (a Gray code at rest, checked against the table's match, or the table's match alone)."""
        order = self.order
        return {
            **tally.attrs(flat_rms_mm=self.flat_rms_mm, n_tracks_first_frame=self.n_tracks_first_frame,
                          clamp=self.clamp),
            "reference_order_from": "gray code at rest" if order.code_points else "projector table",
            "reference_code_points": order.code_points, "reference_code_compared": order.code_compared,
            "reference_code_agreement": order.code_agreement,
        }  # fmt: skip

    def as_record(self) -> dict[str, np.ndarray]:
        """Arrays by name (a hand-over record; `from_record` reads it back exactly)."""
        order = self.order
        return {
            "reference_t_px": order.reference_t_px, "rim": order.rim, "rim_circle_mm": np.array(order.rim_circle_mm),
            "cell_area_mm2": order.cell_area_mm2, "x_mm": self.grid.x_mm, "y_mm": self.grid.y_mm,
            "max_edge_mm": np.array(self.max_edge_mm), "z_flat_mm": np.array(self.z_flat_mm),
            "flat_rms_mm": np.array(self.flat_rms_mm), "clamp": np.array(self.clamp),
            "n_tracks_first_frame": np.array(self.n_tracks_first_frame), "plate_nodes": self.plate_nodes,
            "code_check": np.array([order.code_points, order.code_compared, order.code_agreement]),
        }  # fmt: skip

    @classmethod
    def from_record(cls, record: dict[str, np.ndarray]) -> TopographyReference:
        rim_x, rim_y, rim_r = (float(v) for v in record["rim_circle_mm"])
        clamp_x, clamp_y, clamp_r = (float(v) for v in record["clamp"])
        code_points, code_compared, code_agreement = record["code_check"]
        order = OrderReference(reference_t_px=record["reference_t_px"], rim=record["rim"],
                               rim_circle_mm=(rim_x, rim_y, rim_r), cell_area_mm2=record["cell_area_mm2"],
                               code_points=int(code_points), code_compared=int(code_compared),
                               code_agreement=float(code_agreement))  # fmt: skip
        return cls(
            order=order, grid=Grid(x_mm=record["x_mm"], y_mm=record["y_mm"]),
            max_edge_mm=float(record["max_edge_mm"]), z_flat_mm=float(record["z_flat_mm"]),
            flat_rms_mm=float(record["flat_rms_mm"]), clamp=(clamp_x, clamp_y, clamp_r),
            n_tracks_first_frame=int(record["n_tracks_first_frame"]), plate_nodes=record["plate_nodes"],
        )  # fmt: skip


def reference_stage(
    edges: FrameEdges,
    projector: ProjectorCalibration,
    camera_model: CameraModel,
    settings: TopographySettings,
    *,
    code: Decoding | None = None,
) -> TopographyReference:
    """The reference stage: frame 0's located edges matched to the table (or named by a Gray code recorded at
    rest, `code`), the rim that anchors the order, frame 0 measured, and the grid from it."""
    order = reference_for(edges, projector, camera_model, settings, code=code)
    # Frame 0 is never smoothed (no frame before it), so measured alone it is what a pass over the frames gives.
    first = measure_frame(edges, order, projector, camera_model, frame=0, settings=settings)
    grid, max_edge_mm = grid_for_first_frame(first, projector, settings)
    z = first.points_obj_mm[:, 2]
    z_flat = float(np.median(z))
    return TopographyReference(
        order=order, grid=grid, max_edge_mm=max_edge_mm, z_flat_mm=z_flat,
        flat_rms_mm=float(np.sqrt(np.mean((z - z_flat) ** 2))), clamp=clamp_circle(first.points_obj_mm[:, :2]),
        n_tracks_first_frame=first.n_tracks, plate_nodes=plate_nodes(first, projector, grid, max_edge_mm=max_edge_mm),
    )  # fmt: skip


def frames_read(wanted: range, n_frames: int, settings: TopographySettings) -> range:
    """The frames the frame stage reads to measure `wanted` (besides frame 0): every frame is measured on its own
    against the reference; only temporal smoothing looks h frames either way."""
    h = settings.temporal_smoothing_frames
    return range(max(0, wanted.start - h), min(wanted.stop + h, n_frames))


def decode_reference_code(
    recording: str | Path, *, patterns: str | Path | None = None, image_shape_hw_px: tuple[int, int] | None = None
) -> Decoding:
    """The Gray code recorded with the plate at rest (a folder or ZIP of frames with its patterns.json, or the
    `patterns` file given), decoded (docs/procam.md §5). image_shape_hw_px: the test frames' size, which the
    code's must equal. ValueError or graycode.DecodingError naming the recording (and the file and key)."""
    from fringelab.formats.recordings import open_recording
    from fringelab.pipelines.scan import sequence_of

    name = Path(recording).name
    try:
        with open_recording(recording) as source:
            sequence, _text = sequence_of(source, name, patterns)
            first = np.asarray(source[0])
            if image_shape_hw_px is not None and tuple(first.shape[:2]) != tuple(image_shape_hw_px):
                raise ValueError(
                    f"the Gray code at rest is {first.shape[1]} × {first.shape[0]} px but the test frames are "
                    f"{image_shape_hw_px[1]} × {image_shape_hw_px[0]} px: record it with the test's camera"
                )
            frames: list[np.ndarray] = [first] * len(source)
            for index in sorted(set(sequence.frames_used())):
                frames[index] = np.asarray(source[index])
        return decode(frames, sequence)
    except (ValueError, MeasurementError) as error:
        text = str(error)
        raise type(error)(text if text.startswith(f"{name}: ") else f"{name}: {text}") from None


@dataclass(frozen=True)
class MeasuredFrame:
    """The frame stage's answer for one frame: its measurement, its gridded Z and σ (ny, nx), and its peak."""

    measurement: FrameMeasurement
    z_grid_mm: np.ndarray
    sigma_grid_mm: np.ndarray
    peak: Peak


def frame_stage(
    located: Iterable[FrameEdges],
    reference: TopographyReference,
    projector: ProjectorCalibration,
    camera_model: CameraModel,
    settings: TopographySettings,
    *,
    first_frame: int,
    wanted: range,
) -> Iterator[MeasuredFrame]:
    """The frame stage: the located edges of frames first_frame, first_frame + 1, ... (`frames_read`) ordered,
    measured and gridded, each on its own against the reference; the frames in `wanted`, one at a time."""
    for measurement in track_and_measure(
        located, projector, camera_model, settings=settings, first_frame=first_frame, reference=reference.order
    ):
        if measurement.frame not in wanted:
            continue
        z_grid, sigma_grid = grid_measurement_with_sigma(
            measurement, projector, reference.grid, max_edge_mm=reference.max_edge_mm
        )
        yield MeasuredFrame(measurement, z_grid, sigma_grid, field_peak(z_grid - reference.z_flat_mm, reference.grid))


_COUNTS = ("n_tracks", "n_ended", "n_out_of_range", "n_unmatched", "n_order_unresolved", "n_order_conflict_points",
           "n_order_conflicts")  # fmt: skip
# A frame's scalars in one structured record (one header per frame, not one per number), by name; counts exact.
FRAME_SCALARS = np.dtype(
    [("frame", np.int64), ("edge_noise_px", np.float64), ("visible_area_mm2", np.float64),
     ("measured_area_mm2", np.float64)]
    + [(f"missing_{reason}_mm2", np.float64) for reason in MISSING_REASONS]
    + [(f"peak_{f.name}", np.float64) for f in fields(Peak)]
    + [(name, np.int64) for name in _COUNTS]
)  # fmt: skip


@dataclass(frozen=True)
class PackedFrame:
    """A measured frame as the result file takes it: its measurement, peak and grids packed (`pack_grids`). What
    the worker's chunks hand over to its merge (`as_record` / `from_record`): X, Y and σ of the points as the file
    stores them (float32), Z in full (the merge's temporal cross-check reads it)."""

    measurement: FrameMeasurement
    peak: Peak
    packed: PackedGrids

    @classmethod
    def of(cls, frame: MeasuredFrame) -> PackedFrame:
        return cls(frame.measurement, frame.peak, pack_grids(frame.z_grid_mm, frame.sigma_grid_mm))

    def as_record(self) -> dict[str, np.ndarray]:
        m, coverage = self.measurement, self.measurement.coverage
        if coverage is None:
            raise RuntimeError(f"frame {m.frame}: a measurement came without its coverage")
        scalars = np.zeros(1, FRAME_SCALARS)
        scalars["frame"], scalars["edge_noise_px"] = m.frame, m.edge_noise_px
        scalars["visible_area_mm2"], scalars["measured_area_mm2"] = (
            coverage.visible_area_mm2,
            coverage.measured_area_mm2,
        )
        for reason in MISSING_REASONS:
            scalars[f"missing_{reason}_mm2"] = coverage.missing_mm2[reason]
        for f in fields(Peak):
            scalars[f"peak_{f.name}"] = getattr(self.peak, f.name)
        for name in _COUNTS:
            scalars[name] = getattr(m, name)
        sigma = np.full(len(m.k), np.nan) if m.sigma_z_mm is None else m.sigma_z_mm
        return {
            "k": m.k, "line": m.line, "xy_mm": m.points_obj_mm[:, :2].astype(np.float32), "z_mm": m.points_obj_mm[:, 2],
            "sigma_z_mm": np.asarray(sigma, np.float32), "packed_z_mm": np.frombuffer(self.packed.z_mm, np.uint8),
            "packed_sigma_w_mm": np.frombuffer(self.packed.sigma_w_mm, np.uint8),
            "z_finite": np.packbits(self.packed.z_finite), "scalars": scalars,
        }  # fmt: skip

    @classmethod
    def from_record(cls, record: dict[str, np.ndarray], grid_shape: tuple[int, int]) -> PackedFrame:
        """The frame `as_record` wrote; grid_shape: (ny, nx) of the reference's grid."""
        scalars = record["scalars"][0]
        counts = {name: int(scalars[name]) for name in _COUNTS}
        points = np.empty((len(record["k"]), 3))  # float64 as measured: X, Y in float32 lose nothing written
        points[:, :2], points[:, 2] = record["xy_mm"], record["z_mm"]
        coverage = FrameCoverage(
            visible_area_mm2=float(scalars["visible_area_mm2"]), measured_area_mm2=float(scalars["measured_area_mm2"]),
            missing_mm2={reason: float(scalars[f"missing_{reason}_mm2"]) for reason in MISSING_REASONS},
            n_order_conflicts=counts["n_order_conflicts"],
        )  # fmt: skip
        measurement = FrameMeasurement(
            frame=int(scalars["frame"]), k=record["k"], line=record["line"], points_obj_mm=points,
            n_tracks=counts["n_tracks"], n_ended=counts["n_ended"], n_out_of_range=counts["n_out_of_range"],
            n_unmatched=counts["n_unmatched"], edge_noise_px=float(scalars["edge_noise_px"]),
            n_order_unresolved=counts["n_order_unresolved"], n_order_conflict_points=counts["n_order_conflict_points"],
            n_order_conflicts=counts["n_order_conflicts"], coverage=coverage, sigma_z_mm=record["sigma_z_mm"],
        )  # fmt: skip
        peak = Peak(**{f.name: float(scalars[f"peak_{f.name}"]) for f in fields(Peak)})
        finite = np.unpackbits(record["z_finite"], count=grid_shape[0] * grid_shape[1]).reshape(grid_shape)
        packed = PackedGrids(z_mm=record["packed_z_mm"].tobytes(), sigma_w_mm=record["packed_sigma_w_mm"].tobytes(),
                             z_finite=finite.view(bool))  # fmt: skip
        return cls(measurement, peak, packed)
