"""The topography job: a test recording, a camera and a projector calibration in; the topography result out.

One fan-out over the frames and a merge in frame order, calling the stages that
`fringelab.pipelines.topography.topography_recording` calls in one sequential pass, so the file is the same
whatever the chunking (a test holds them equal):

    entry:             the reference stage (`reference_stage`: frame 0's edges matched to the table, the rim that
                       anchors the fringe order, frame 0 measured, the grid from it)   -> chunks/reference.arrays
    phase 0, chunks:   the frame stage (`frame_stage`: each frame on its own: edges, fringe order, Z, X, Y, what
                       is missing, the grids of Z and of its σ and the peak; with temporal smoothing, h frames
                       either side are read too), packed as the file stores them (`PackedFrame`)
                                                                                    -> chunks/frames-<first>.arrays
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

from fringelab.core.specs import TopographySpec
from fringelab.pipelines.topography import (
    PackedFrame,
    TopographyReference,
    frame_stage,
    frames_read,
    reference_stage,
    result_writer,
)
from fringelab.science.topography import SummaryTally, TemporalCrossCheck
from worker.chunks import InOrder, planned_frame_ranges
from worker.context import Chunked, JobContext, finite_or_none
from worker.handover import array_records, has_hand_over, load_arrays, read_array_records, save_arrays
from worker.jobs.inputs import calibration_file, recording_file, recording_input
from worker.reserve import require_reserve


@dataclass
class _TopographyInputs:
    source: Any
    camera_model: Any
    projector: Any
    wanted: range
    settings: Any

    def __enter__(self) -> _TopographyInputs:
        return self

    def __exit__(self, *_exc: object) -> None:
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
    """The recording, calibrations, frames to write and settings of a topography job; the recording is open: use
    the inputs in a `with` block, which closes it."""
    from fringelab.formats.recordings import open_recording
    from fringelab.science.order import OrderSettings
    from fringelab.science.topography import TopographySettings, frame_range

    spec = context.spec
    _recording, _camera, path = recording_input(context)
    camera_model = _cached_calibration("camera", calibration_file(context, spec.camera_calibration_id))
    projector = _cached_calibration("projector", calibration_file(context, spec.projector_calibration_id))
    settings = TopographySettings(
        grid_step_mm=spec.grid_step_mm, temporal_smoothing_frames=spec.temporal_smoothing_frames,
        order=OrderSettings(rim_circle_mm=spec.rim_circle_mm),
    )  # fmt: skip
    source = open_recording(path)
    try:
        last = spec.frames.last
        wanted = frame_range(range(spec.frames.first, len(source) if last is None else last + 1), len(source))
    except BaseException:
        source.close()
        raise
    return _TopographyInputs(source, camera_model, projector, wanted, settings)


def topography_entry(context: JobContext[TopographySpec]) -> Chunked:
    """The reference (frame 0, its order from the Gray code at rest when the spec names one), then the frames to
    write in chunks on any worker."""
    from fringelab.pipelines.topography import decode_reference_code
    from fringelab.science.topography import check_recording_against, check_stripes_against, locate_test_edges

    with _topography_inputs(context) as inputs:
        first_frame = inputs.source[0]
        check_recording_against(first_frame.shape[:2], inputs.projector, inputs.camera_model)
        check_stripes_against(first_frame, inputs.projector)
        edges = next(iter(locate_test_edges([first_frame], inputs.projector)))
    code = None
    if context.spec.reference_code_recording_id is not None:
        path = recording_file(context, context.spec.reference_code_recording_id)
        code = decode_reference_code(path, image_shape_hw_px=(first_frame.shape[0], first_frame.shape[1]))
        context.log(f"reference order from the Gray code at rest ({code.valid_share:.0%} of its pixels decoded)")
    reference = reference_stage(edges, inputs.projector, inputs.camera_model, inputs.settings, code=code)
    if code is not None:
        order = reference.order
        checked = (f"the table's match agrees on {order.code_agreement:.1%} of {order.code_compared}"
                   if order.code_compared else "no table match to check it against (the plate rests off its "
                   "reference Z)")  # fmt: skip
        context.log(f"the code names {order.code_points} edge points of frame 0; {checked}")
    save_arrays(context, _REFERENCE, **reference.as_record())
    wanted = inputs.wanted
    context.log(f"topography of frames {wanted.start}..{wanted.stop - 1}, each ordered on its own")
    ranges = [(wanted.start + a, wanted.start + b)
              for a, b in planned_frame_ranges(len(wanted), context.spec.chunk_frames, context.settings)]  # fmt: skip
    return Chunked(ranges, stage="measuring")


_REFERENCE = "chunks/reference.arrays"


def _reference(context: JobContext[TopographySpec]) -> TopographyReference:
    return TopographyReference.from_record(load_arrays(context, _REFERENCE))


def topography_measure(context: JobContext[TopographySpec], first: int, stop: int) -> None:
    """Phase 0, any worker: frames [first, stop) measured (`_measured`) and handed over one record per frame."""
    require_reserve(context.settings, what=f"writing frames {first} to {stop - 1}")
    with array_records(context, _hand_over_name(first)) as write:
        for frame in _measured(context, first, stop):
            write(**frame.as_record())


def _hand_over_name(first: int) -> str:
    return f"chunks/frames-{first:07d}.arrays"


def _measured(
    context: JobContext[TopographySpec], first: int, stop: int, *, report: bool = True
) -> Iterator[PackedFrame]:
    """Frames [first, stop), each on its own (the frame stage), packed as the result file stores them: the merge
    only writes. report: the progress is the context's chunk's."""
    from fringelab.science.topography import locate_test_edges

    with _topography_inputs(context) as inputs:
        read = frames_read(range(first, stop), len(inputs.source), inputs.settings)
        located = locate_test_edges((inputs.source[i] for i in read), inputs.projector)
        for frame in frame_stage(located, _reference(context), inputs.projector, inputs.camera_model,
                                 inputs.settings, first_frame=read.start, wanted=range(first, stop)):  # fmt: skip
            yield PackedFrame.of(frame)
            if report:  # (the chunk's end is recorded when it is marked done: the last frame need not be)
                context.progress(frame.measurement.frame - first, stop - first, "measuring")


def _frames_of(
    context: JobContext[TopographySpec], turn: InOrder, grid_shape: tuple[int, int]
) -> Iterator[PackedFrame]:
    """The frames of a chunk's turn one at a time: measured here when the turn says so, or when its hand-over is
    missing (a merge that ran before, and died, measured it straight into its own file or kept it in its process),
    else read from the hand-over. Either way through the same records (`PackedFrame.as_record`), so the file is
    the same."""
    records: Iterator[dict[str, Any]]
    if turn.measure_here is not None:
        records = (frame.as_record() for frame in _measured(turn.measure_here, turn.first, turn.stop))
    elif not has_hand_over(context, _hand_over_name(turn.first)):
        records = (frame.as_record() for frame in _measured(context, turn.first, turn.stop, report=False))
    else:
        records = read_array_records(context, _hand_over_name(turn.first))
    for record in records:
        yield PackedFrame.from_record(record, grid_shape)


def topography_write(context: JobContext[TopographySpec], turns: Iterator[InOrder]) -> dict[str, Any]:
    """Merge of phase 0, in frame order: the result file, as `topography_recording` writes it, a chunk at a time
    as each one's turn comes (the progress is the chunks')."""
    from fringelab.formats.recordings import recording_log
    from fringelab.formats.topography import write_xdmf

    with _topography_inputs(context) as inputs:
        source, wanted, projector = inputs.source, inputs.wanted, inputs.projector
        log = recording_log(source)  # frames.csv, else the container's own times (a .cine's stamps)
        n_frames, where = len(source), str(source.path)
    reference = _reference(context)
    tally = SummaryTally()
    cross_check = TemporalCrossCheck(projector)  # over the chunks' frames in order, so whatever the chunking
    with context.output("topography.h5", media_type="application/x-hdf5") as temporary:
        writer = result_writer(
            temporary, reference=reference, camera_model=inputs.camera_model, projector=projector,
            settings=inputs.settings, where=where, n_frames=n_frames, wanted=wanted, time_source=log.time_source,
        )  # fmt: skip
        with writer:
            for turn in turns:
                require_reserve(context.settings, what="writing the next frames of the result")
                for frame in _frames_of(context, turn, reference.grid.shape):
                    measurement = cross_check.checked(frame.measurement)
                    row, camera_frame = log.row(measurement.frame), int(log.camera_frame[measurement.frame])
                    writer.append(
                        measurement, None, frame.peak, log=row, camera_frame=camera_frame, packed=frame.packed
                    )
                    tally.add(frame.peak, n_out_of_range=measurement.n_out_of_range, measurement=measurement)
            tally.require_ordered(where)
            writer.close(reference.summary_attrs(tally))
    with context.output("topography.xdmf", media_type="application/xml") as temporary:
        write_xdmf(context.directory / "topography.h5", temporary)  # ParaView opens it beside topography.h5
    clamp = reference.clamp
    result = {
        "frames": [wanted.start, wanted.stop - 1],
        "flat_rms_mm": reference.flat_rms_mm,
        "max_peak_w_mm": writer.max_measured_peak_w_mm,  # of the frames whose peak was measured
        "n_out_of_range_total": tally.n_out_of_range,
        "punch_axis_xy_mm": list(tally.punch_axis_xy_mm),
        "clamp_centre_xy_mm": list(clamp[:2]),
        "clamp_radius_mm": clamp[2],
    }
    context.log(
        f"topography of {len(wanted)} frames: flat first frame RMS {result['flat_rms_mm']:.3f} mm, "
        f"peak deflection {result['max_peak_w_mm'] or float('nan'):.2f} mm"
    )
    return {key: finite_or_none(value) for key, value in result.items()}
