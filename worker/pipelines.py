"""Celery tasks of the measurement jobs, and the generic chunk and merge tasks of chunked jobs.

Each task only says how to run a job as a task: it takes a job id, and `worker.jobrunner` loads the job, calls
the body below, and stores the outcome. Bodies load their inputs from storage, call `fringelab.science`, and
write their files through `JobContext.output` (temporary file + rename), so a task that runs twice writes the
same complete files. A chunked kind has three bodies: the entry (check inputs, plan the chunks), the chunk
(frames `[first, stop)` in any order on any worker) and the merge (everything that must run in frame order).
"""

from __future__ import annotations

import hashlib
import os
import shutil
import socket
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py
import numpy as np
from celery import Task, shared_task
from sqlalchemy import func, select
from sqlalchemy.exc import IntegrityError

from backend.jobs import as_utc
from backend.models import Calibration, Camera, Job, Recording, utcnow
from backend.settings import Settings
from worker.jobrunner import ChunkBody, Chunked, JobCancelled, JobContext, MergeBody, run_chunk, run_job, run_merge
from worker.runtime import sessions_of


def frame_ranges(count: int, chunk_frames: int) -> list[tuple[int, int]]:
    """Split positions `0..count-1` into consecutive `[first, stop)` ranges of at most `chunk_frames`."""
    if count < 1 or chunk_frames < 1:
        raise ValueError(f"need at least one frame and one frame per chunk, got {count} and {chunk_frames}")
    return [(first, min(first + chunk_frames, count)) for first in range(0, count, chunk_frames)]


def _chunk_frames(spec: dict[str, Any], settings: Settings) -> int:
    return int(spec.get("chunk_frames") or settings.chunk_frames)


def _this_worker() -> str:
    return f"{socket.gethostname()}:{os.getpid()}"


# ------------------------------------------------------------------------------------------------ selftest


def selftest_frame(frame: int, *, size_px: int) -> tuple[float, str]:
    """The work of one selftest frame: a seeded random image and its spectrum. Returns (mean spectral amplitude,
    SHA-256 of the image), the same on every machine for the same frame, so the merge can check each one."""
    image = np.random.default_rng(frame).random((size_px, size_px), dtype=np.float32)
    spectrum = np.abs(np.fft.rfft2(image))
    return float(spectrum[1:, 1:].mean()), hashlib.sha256(image.tobytes()).hexdigest()


def selftest_entry(context: JobContext) -> Chunked:
    frames = int(context.spec["frames"])
    context.log(f"selftest of {frames} frames of {context.spec['frame_size_px']} px")
    return Chunked(frame_ranges(frames, _chunk_frames(context.spec, context.settings)), stage="computing frames")


def _save(context: JobContext, name: str, **arrays: np.ndarray) -> None:
    with context.output(name, publish=False) as path, path.open("wb") as handle:
        np.savez(handle, **arrays)


def _load(context: JobContext, name: str) -> dict[str, np.ndarray]:
    path = context.directory / name
    if not path.is_file():
        raise RuntimeError(f"the intermediate file {name} is missing")
    with np.load(path) as data:
        return {key: data[key] for key in data.files}


def selftest_compute(context: JobContext, first: int, stop: int) -> None:
    """Phase 0, any worker: compute frames [first, stop)."""
    size_px = int(context.spec["frame_size_px"])
    values, digests = [], []
    for done, frame in enumerate(range(first, stop)):
        value, digest = selftest_frame(frame, size_px=size_px)
        values.append(value)
        digests.append(digest)
        context.progress(done + 1, stop - first, "computing frames")
    _save(context, f"chunks/p0-{first:07d}.npz", frame=np.arange(first, stop), value=np.asarray(values),
          digest=np.asarray(digests, dtype="S64"), worker=np.asarray([_this_worker()], dtype="S200"))  # fmt: skip


def selftest_chain(context: JobContext, ranges: list[tuple[int, int]]) -> Chunked:
    """Merge of phase 0, in frame order: check that every frame came back once, and chain the digests (each link
    depends on all frames before it, as edge identity does in a topography), then verify in parallel."""
    chunks = [_load(context, f"chunks/p0-{first:07d}.npz") for first, _stop in ranges]
    frame = np.concatenate([c["frame"] for c in chunks])
    expected = int(context.spec["frames"])
    if not np.array_equal(frame, np.arange(expected)):
        raise RuntimeError(f"the chunks hold {frame.size} frames, not each of 0..{expected - 1} once")
    digest = np.concatenate([c["digest"] for c in chunks])
    chain, link = [], hashlib.sha256()
    for done, value in enumerate(digest.tolist()):
        link.update(value)
        chain.append(link.hexdigest())
        context.progress(done + 1, expected, "chaining")
    computed_by = np.concatenate([np.repeat(c["worker"], c["frame"].size) for c in chunks])
    _save(context, "chunks/sequence.npz", frame=frame, value=np.concatenate([c["value"] for c in chunks]),
          digest=digest, chain=np.asarray(chain, dtype="S64"), computed_by=computed_by)  # fmt: skip
    return Chunked(ranges, stage="verifying frames")


def selftest_verify(context: JobContext, first: int, stop: int) -> None:
    """Phase 1, any worker: compute frames [first, stop) again and compare with what phase 0 stored."""
    size_px = int(context.spec["frame_size_px"])
    stored = _load(context, "chunks/sequence.npz")["digest"][first:stop]
    matches = []
    for done, frame in enumerate(range(first, stop)):
        matches.append(selftest_frame(frame, size_px=size_px)[1].encode() == stored[done])
        context.progress(done + 1, stop - first, "verifying frames")
    _save(context, f"chunks/p1-{first:07d}.npz", matches=np.asarray(matches),
          worker=np.asarray([_this_worker()], dtype="S200"))  # fmt: skip


def selftest_write(context: JobContext, ranges: list[tuple[int, int]]) -> dict[str, Any]:
    """Merge of phase 1: the result file, and a failure naming the workers if any frame came out differently."""
    context.progress(0, 1, "writing")
    sequence = _load(context, "chunks/sequence.npz")
    checks = [_load(context, f"chunks/p1-{first:07d}.npz") for first, _stop in ranges]
    matches = np.concatenate([c["matches"] for c in checks])
    verified_by = np.concatenate([np.repeat(c["worker"], c["matches"].size) for c in checks])
    differing = np.flatnonzero(~matches)
    if differing.size:
        pairs = sorted({(sequence["computed_by"][i].decode(), verified_by[i].decode()) for i in differing})
        raise ValueError(
            f"{differing.size} frames (first: {int(differing[0])}) came out differently on "
            + "; ".join(f"{a} and {b}" for a, b in pairs)
            + ": the workers do not compute alike; give every machine the same fringelab and numpy versions"
        )
    with context.output("selftest.h5", media_type="application/x-hdf5") as path, h5py.File(path, "w") as out:
        for name in ("frame", "value", "digest", "chain", "computed_by"):
            out[name] = sequence[name]
        out["verified_by"] = verified_by
        out.attrs["frame_size_px"] = int(context.spec["frame_size_px"])
    with context.sessions() as session:
        started = session.scalar(select(Job.started_at).where(Job.id == context.job_id))
    elapsed_s = (utcnow() - as_utc(started)).total_seconds() if started is not None else None  # type: ignore[operator]
    _remove_chunk_files(context.directory)
    frames = int(sequence["frame"].size)
    return {
        "frames": frames,
        "chunks": len(ranges),
        "workers": {"computing": _tally(sequence["computed_by"]), "verifying": _tally(verified_by)},
        "digest": sequence["chain"][-1].decode(),
        "elapsed_s": elapsed_s,
        "frames_per_s": frames / elapsed_s if elapsed_s else None,
    }


def _tally(names: np.ndarray) -> dict[str, int]:
    found, counts = np.unique(names, return_counts=True)
    return {name.decode(): int(count) for name, count in zip(found, counts, strict=True)}


def _remove_chunk_files(directory: Path) -> None:
    chunk_dir = directory / "chunks"
    if chunk_dir.is_dir():
        for path in chunk_dir.iterdir():
            path.unlink(missing_ok=True)
        chunk_dir.rmdir()


# ------------------------------------------------------------------------------------------ calibrations


def _recording_input(context: JobContext) -> tuple[Recording, Camera, Path]:
    with context.sessions() as session:
        recording = session.get(Recording, context.spec["recording_id"])
        if recording is None:
            raise ValueError(f"recording {context.spec['recording_id']} was deleted; upload it again")
        camera = recording.camera
        session.expunge_all()
    return recording, camera, context.settings.data_path / recording.path


def record_calibration(
    context: JobContext,
    *,
    kind: str,
    camera_id: int,
    recording_id: int,
    name: str,
    image_size_px: tuple[int, int],
    summary: dict[str, Any],
) -> Calibration:
    """The versioned Calibration row of this job's file `name` (one per job: a second run finds the first).
    Versions count per camera and kind; two jobs finishing at once retry on the unique version."""
    path = context.directory / name
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    for _attempt in range(5):
        with context.sessions() as session:
            existing = session.scalar(select(Calibration).where(Calibration.job_id == context.job_id))
            if existing is not None:
                return existing
            latest = session.scalar(
                select(func.max(Calibration.version)).where(
                    Calibration.camera_id == camera_id, Calibration.kind == kind
                )
            )
            row = Calibration(
                kind=kind,
                camera_id=camera_id,
                recording_id=recording_id,
                job_id=context.job_id,
                version=(latest or 0) + 1,
                path=str(path.relative_to(context.settings.data_path)),
                summary=summary,
                image_width_px=image_size_px[0],
                image_height_px=image_size_px[1],
                sha256=digest,
            )
            session.add(row)
            try:
                session.commit()
            except IntegrityError:  # another job took this version a moment ago
                session.rollback()
                continue
            return row
    raise RuntimeError(f"could not number the {kind} calibration of camera {camera_id}; retry the job")


def camera_calibration_body(context: JobContext) -> dict[str, Any]:
    from fringelab.formats.camera import write_camera_json
    from fringelab.formats.recordings import open_recording
    from fringelab.pipelines.camera_calibration import calibrate_camera_recording
    from fringelab.science.calibration import CalibrationCancelled
    from fringelab.science.chessboard import Board

    spec = context.spec
    recording, camera, path = _recording_input(context)
    board = None
    if spec.get("board"):
        b = spec["board"]
        board = Board(b["cols"], b["rows"], b["square_mm"], origin=tuple(b["origin"]) if b.get("origin") else None)
    pitch_um = camera.pixel_pitch_um
    if not pitch_um > 0:
        raise ValueError(f"camera {camera.name!r} has no pixel pitch; set it on the camera, then retry")
    context.log(f"calibrating camera {camera.name!r} from recording {recording.id} ({spec['mode']})")
    try:
        calibration = calibrate_camera_recording(
            open_recording(path),
            board=board,
            mode=spec["mode"],
            du_px_per_mm=1000.0 / pitch_um,
            dv_px_per_mm=1000.0 / pitch_um,
            scale_on=spec["scale_on"],
            reject_outliers=spec["reject_outliers"],
            pixel_pitch_um=(pitch_um, pitch_um),
            detector=spec["detector"],
            subpix_half_window_px=spec.get("subpix_window_px"),
            progress=context.progress,
            should_cancel=context.should_cancel,
        )
    except CalibrationCancelled as error:
        raise JobCancelled(str(error)) from None
    with context.output("camera.json", media_type="application/json") as temporary:
        write_camera_json(calibration, temporary)
    for frame in calibration.frames:
        if frame.status != "used":
            context.log(f"frame {frame.frame} {frame.status}: {frame.reason}", level="warning")
    used = sum(f.status == "used" for f in calibration.frames)
    summary = {
        "mode": calibration.mode,
        "rms_px": calibration.rms_px,
        "verdict": calibration.verdict.level,
        "n_points": calibration.n_points,
        "frames_used": used,
        "frames_total": len(calibration.frames),
        "f_mm": calibration.camera.f_mm,
    }
    size = (calibration.camera.image_width_px, calibration.camera.image_height_px)
    row = record_calibration(
        context, kind="camera", camera_id=camera.id, recording_id=recording.id, name="camera.json",
        image_size_px=size, summary=summary,
    )  # fmt: skip
    context.provenance.update({"science": calibration.provenance})
    context.log(
        f"camera calibration version {row.version}: RMS {calibration.rms_px:.3f} px, "
        f"verdict {calibration.verdict.level}"
    )
    return {"calibration_id": row.id, "version": row.version, **summary, "reasons": list(calibration.verdict.reasons)}


def _calibration_file(context: JobContext, calibration_id: int) -> Path:
    with context.sessions() as session:
        row = session.get(Calibration, calibration_id)
        if row is None:
            raise ValueError(f"calibration {calibration_id} was deleted; choose another one and start a new job")
        path = context.settings.data_path / row.path
    if not path.is_file():
        raise ValueError(f"the file of calibration {calibration_id} is gone ({row.path}); run that calibration again")
    return path


def projector_calibration_body(context: JobContext) -> dict[str, Any]:
    from fringelab.formats.camera import read_camera_json
    from fringelab.formats.projector import write_projector_calibration
    from fringelab.formats.recordings import open_recording
    from fringelab.pipelines.projector_calibration import calibrate_projector_recording
    from fringelab.science.fringes import EdgeSettings
    from fringelab.science.projector import CalibrationCancelled, ProjectorSettings

    spec = context.spec
    recording, camera, path = _recording_input(context)
    camera_model = read_camera_json(_calibration_file(context, spec["camera_calibration_id"]))
    settings = ProjectorSettings(
        edges=EdgeSettings(axis=spec["axis"]),
        reference_z_mm=spec["reference_z_mm"],
        poly_degree=spec["poly_degree"],
        min_z_samples=max(6, spec["poly_degree"] + 2),
    )
    context.log(f"projector calibration of camera {camera.name!r} from recording {recording.id}")
    try:
        calibration = calibrate_projector_recording(
            open_recording(path),
            camera_model,
            settings=settings,
            progress=context.progress,
            should_cancel=context.should_cancel,
        )
    except CalibrationCancelled as error:
        raise JobCancelled(str(error)) from None
    with context.output("projector.h5", media_type="application/x-hdf5") as temporary:
        write_projector_calibration(calibration, temporary)
    qa = calibration.qa
    summary = {
        "axis": calibration.axis,
        "n_edges": qa.n_edges,
        "n_lines": calibration.n_lines,
        "z_range_mm": [float(v) for v in qa.z_range_mm],
        "z_steps": len(calibration.z_mm),
        "coverage": qa.coverage,
        "sensitivity_px_per_mm": float(qa.sensitivity_px_per_mm[1]),
        "fit_rms_mm": qa.fit_rms_mm,
    }
    height, width = calibration.image_shape
    row = record_calibration(
        context, kind="projector", camera_id=camera.id, recording_id=recording.id, name="projector.h5",
        image_size_px=(width, height), summary=summary,
    )  # fmt: skip
    context.provenance.update({"science": calibration.provenance})
    context.log(
        f"projector calibration version {row.version}: {qa.n_edges} edges, coverage {qa.coverage:.1%}, "
        f"fit RMS {qa.fit_rms_mm:.4f} mm"
    )
    return {"calibration_id": row.id, "version": row.version, **summary}


# ------------------------------------------------------------------------------------------------ topography
#
# Two fan-outs, each joined by a pass in frame order, computing exactly what `topography_recording` computes in
# one sequential pass (a test holds them to the bit):
#   phase 0, chunks:  edges of each frame (a pure function of the frame)        -> chunks/edges-<first>.h5
#   merge 0, in order: identity fixed on frame 0 and carried frame to frame;
#                      Z, X, Y of every point; the grid from frame 0            -> chunks/track.npz, measure-*.npz
#   phase 1, chunks:  the deflection grid and peak of each frame (pure again)   -> chunks/grid-<first>.npz
#   merge 1, in order: the result file (TopographyWriter) and its summary       -> topography.h5
# Gridding is the largest part of the per-frame work, which is why it is not left in the sequential pass.


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
    _recording, _camera, path = _recording_input(context)
    camera_model = read_camera_json(_calibration_file(context, spec["camera_calibration_id"]))
    projector = read_projector_calibration(_calibration_file(context, spec["projector_calibration_id"]))
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
    return Chunked(frame_ranges(stop, _chunk_frames(context.spec, context.settings)), stage="locating edges")


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


def _save_measurements(context: JobContext, first: int, measurements: list[Any]) -> None:
    sizes = [len(m.k) for m in measurements]
    _save(
        context, f"chunks/measure-{first:07d}.npz",
        frame=np.array([m.frame for m in measurements], np.int64),
        offsets=np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64),
        k=np.concatenate([m.k for m in measurements]), line=np.concatenate([m.line for m in measurements]),
        points_obj_mm=np.concatenate([m.points_obj_mm for m in measurements]).reshape(-1, 3),
        edge_noise_px=np.array([m.edge_noise_px for m in measurements], np.float64),
        **{name: np.array([getattr(m, name) for m in measurements], np.int64) for name in _MEASURE_COUNTS},
    )  # fmt: skip


def _load_measurements(context: JobContext, first: int) -> list[Any]:
    from fringelab.science.topography import FrameMeasurement

    data = _load(context, f"chunks/measure-{first:07d}.npz")
    offsets = data["offsets"]
    return [
        FrameMeasurement(
            frame=int(frame),
            k=data["k"][lo:hi],
            line=data["line"][lo:hi],
            points_obj_mm=data["points_obj_mm"][lo:hi],
            edge_noise_px=float(data["edge_noise_px"][i]),
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

    grid_ranges = [(wanted.start + a, wanted.start + b) for a, b in frame_ranges(len(wanted), _chunk_frames(
        context.spec, context.settings))]  # fmt: skip
    pending: list[Any] = []
    for measurement in track_and_measure(stored_edges(), projector, inputs.camera_model, settings=settings):
        if measurement.frame == 0:
            grid, max_edge_mm = grid_for_first_frame(measurement, projector, settings)
            z = measurement.points_obj_mm[:, 2]
            z_flat = float(np.median(z))
            _save(context, "chunks/track.npz", x_mm=grid.x_mm, y_mm=grid.y_mm, max_edge_mm=max_edge_mm,
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
    track = _load(context, "chunks/track.npz")
    grid, z_flat = Grid(x_mm=track["x_mm"], y_mm=track["y_mm"]), float(track["z_flat_mm"])
    grids, peaks = [], []
    for done, measurement in enumerate(_load_measurements(context, first)):
        z_grid = grid_measurement(measurement, inputs.projector, grid, max_edge_mm=float(track["max_edge_mm"]))
        grids.append(z_grid)
        peaks.append(list(vars(field_peak(z_grid - z_flat, grid)).values()))
        context.progress(done + 1, stop - first, "gridding")
    _save(context, f"chunks/grid-{first:07d}.npz", z_mm=np.array(grids), peak=np.array(peaks, np.float64))


def topography_write(context: JobContext, ranges: list[tuple[int, int]]) -> dict[str, Any]:
    """Merge of phase 1, in frame order: the result file, as `topography_recording` writes it."""
    from dataclasses import asdict, fields

    from fringelab.formats.hdf5 import json_text
    from fringelab.formats.sidecars import FrameTable, read_frames_csv
    from fringelab.formats.topography import TopographyWriter
    from fringelab.pipelines.provenance import code_versions
    from fringelab.pipelines.topography import _calibration_attrs
    from fringelab.science.fields import Grid, Peak

    inputs = _topography_inputs(context)
    source, wanted, projector = inputs.source, inputs.wanted, inputs.projector
    frames_text = source.sidecar_text("frames.csv")
    n_frames, where = len(source), str(source.path)
    inputs.close()
    log = (read_frames_csv(frames_text) if frames_text is not None else FrameTable.empty()).rows(list(range(n_frames)))
    track = _load(context, "chunks/track.npz")
    z_flat, clamp = float(track["z_flat_mm"]), [float(v) for v in track["clamp"]]
    peak_names = [f.name for f in fields(Peak)]
    centres: list[tuple[float, float]] = []
    peaks: list[float] = []
    n_out_of_range = 0
    with context.output("topography.h5", media_type="application/x-hdf5") as temporary:
        writer = TopographyWriter(
            temporary, grid=Grid(x_mm=track["x_mm"], y_mm=track["y_mm"]), max_edge_mm=float(track["max_edge_mm"]),
            z_flat_mm=z_flat, axis=projector.axis,
            attrs={"settings_json": json_text(asdict(inputs.settings)),
                   "edge_settings_json": json_text(asdict(projector.edges)),
                   "provenance_json": json_text({"input": where, "n_frames_in_recording": n_frames,
                                             "frames_written": [wanted.start, wanted.stop], **code_versions()})},
            calibration_attrs=_calibration_attrs(inputs.camera_model, projector),
        )  # fmt: skip
        with writer:
            for first, _stop in ranges:
                gridded = _load(context, f"chunks/grid-{first:07d}.npz")
                for i, measurement in enumerate(_load_measurements(context, first)):
                    peak = Peak(**dict(zip(peak_names, map(float, gridded["peak"][i]), strict=True)))
                    row = tuple(float(log[name][measurement.frame]) for name in FrameTable.COLUMNS)
                    writer.append(measurement, gridded["z_mm"][i], peak, log=row)  # type: ignore[arg-type]
                    peaks.append(peak.w_mm)
                    if np.isfinite(peak.centre_x_mm) and peak.w_mm >= 5.0:
                        centres.append((peak.centre_x_mm, peak.centre_y_mm))
                    n_out_of_range += measurement.n_out_of_range
                    context.progress(measurement.frame - wanted.start + 1, len(wanted), "writing")
            axis_xy = tuple(np.median(np.array(centres), axis=0)) if centres else (float("nan"), float("nan"))
            writer.close({
                "flat_rms_mm": float(track["flat_rms_mm"]), "n_tracks_first_frame": int(track["n_tracks_first_frame"]),
                "clamp_centre_x_mm": clamp[0], "clamp_centre_y_mm": clamp[1], "clamp_radius_mm": clamp[2],
                "punch_axis_x_mm": axis_xy[0], "punch_axis_y_mm": axis_xy[1], "n_out_of_range_total": n_out_of_range,
            })  # fmt: skip
    _remove_chunk_files(context.directory)
    finite = [p for p in peaks if np.isfinite(p)]
    result = {
        "frames": [wanted.start, wanted.stop - 1],
        "flat_rms_mm": float(track["flat_rms_mm"]),
        "max_peak_w_mm": max(finite) if finite else None,
        "n_out_of_range_total": n_out_of_range,
        "punch_axis_xy_mm": [float(v) for v in axis_xy],
        "clamp_centre_xy_mm": clamp[:2],
        "clamp_radius_mm": clamp[2],
    }
    context.log(
        f"topography of {len(wanted)} frames: flat first frame RMS {result['flat_rms_mm']:.3f} mm, "
        f"peak deflection {result['max_peak_w_mm'] or float('nan'):.2f} mm"
    )
    return {key: _finite_or_none(value) for key, value in result.items()}


def _finite_or_none(value: Any) -> Any:
    if isinstance(value, float):
        return value if np.isfinite(value) else None
    if isinstance(value, list):
        return [_finite_or_none(v) for v in value]
    return value


def export_body(context: JobContext) -> dict[str, Any]:
    from fringelab.formats.exports import export_result

    spec = context.spec
    with context.sessions() as session:
        source = session.get(Job, spec["job_id"])
        entry = next((f for f in (source.files if source else []) if f["name"] == "topography.h5"), None)
    if entry is None:
        raise ValueError(f"topography job {spec['job_id']} has no result file any more; run it again")
    result_path = context.settings.data_path / entry["path"]
    line = tuple(spec["line"]) if spec.get("line") else None
    context.progress(0, 1, "exporting")
    fmt = spec["format"]
    if fmt == "vtk":  # a .pvd time series of .vtu files: one download as a ZIP
        work = context.directory / "vtk"
        shutil.rmtree(work, ignore_errors=True)  # a previous run's leftovers
        export_result(result_path, fmt, work / "topography.pvd")
        name = "topography-vtk.zip"
        with (
            context.output(name, media_type="application/zip") as temporary,
            zipfile.ZipFile(temporary, "w", compression=zipfile.ZIP_DEFLATED) as archive,
        ):
            for path in sorted(work.rglob("*")):
                if path.is_file():
                    archive.write(path, path.relative_to(work))
        shutil.rmtree(work)
    else:
        suffix, media = {
            "points-csv": (".csv", "text/csv"),
            "profile-csv": ("-profile.csv", "text/csv"),
            "grid-npz": (".npz", "application/octet-stream"),
            "mat": (".mat", "application/x-matlab-data"),
        }[fmt]
        name = f"topography{suffix}"
        with context.output(name, media_type=media) as temporary:
            export_result(result_path, fmt, temporary, line=line)  # type: ignore[arg-type]
    context.progress(1, 1, "exporting")
    return {"format": fmt, "file": name, "source_job_id": spec["job_id"]}


# ------------------------------------------------------------------------------------------------ the tasks

# Per chunked kind, its phases in order: (chunk body, merge body). A merge that returns a `Chunked` plan starts the
# next phase; the last one returns the result.
PHASES: dict[str, list[tuple[ChunkBody, MergeBody]]] = {
    "selftest": [(selftest_compute, selftest_chain), (selftest_verify, selftest_write)],
    "topography": [(topography_locate, topography_track), (topography_grid, topography_write)],
}


def _kind(task: Task, job_id: str) -> str | None:
    with sessions_of(task.app)() as session:
        return session.scalar(select(Job.kind).where(Job.id == job_id))


@shared_task(bind=True, name="fringelab.selftest", ignore_result=True)
def selftest(self: Task, job_id: str) -> dict[str, Any]:
    return run_job(self, job_id, selftest_entry)


@shared_task(bind=True, name="fringelab.camera_calibration", ignore_result=True)
def camera_calibration(self: Task, job_id: str) -> dict[str, Any]:
    return run_job(self, job_id, camera_calibration_body)


@shared_task(bind=True, name="fringelab.projector_calibration", ignore_result=True)
def projector_calibration(self: Task, job_id: str) -> dict[str, Any]:
    return run_job(self, job_id, projector_calibration_body)


@shared_task(bind=True, name="fringelab.topography", ignore_result=True)
def topography(self: Task, job_id: str) -> dict[str, Any]:
    return run_job(self, job_id, topography_entry)


@shared_task(bind=True, name="fringelab.export", ignore_result=True)
def export(self: Task, job_id: str) -> dict[str, Any]:
    return run_job(self, job_id, export_body)


@shared_task(bind=True, name="fringelab.job_chunk", ignore_result=True)
def job_chunk(self: Task, job_id: str, phase: int, index: int) -> None:
    kind = _kind(self, job_id)
    if kind is not None:
        run_chunk(self, job_id, phase, index, PHASES[kind][phase][0])


@shared_task(bind=True, name="fringelab.job_merge", ignore_result=True)
def job_merge(self: Task, job_id: str, phase: int) -> dict[str, Any]:
    kind = _kind(self, job_id)
    return run_merge(self, job_id, phase, PHASES[kind][phase][1]) if kind is not None else {}
