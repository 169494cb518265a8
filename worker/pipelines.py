"""Celery tasks of the measurement jobs, and the generic chunk and merge tasks of chunked jobs.

Each task only says how to run a job as a task: it takes a job id, and `worker.jobrunner` loads the job, calls
the body below, and stores the outcome. Bodies load their inputs from storage, call `worker.measurement`, and
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
    from worker.measurement.calibration import CalibrationCancelled, calibrate_camera_recording
    from worker.measurement.camera_files import write_camera_json
    from worker.measurement.chessboard import Board
    from worker.measurement.readers import open_recording

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
    from worker.measurement.camera_files import read_camera_json
    from worker.measurement.fringes import EdgeSettings
    from worker.measurement.projector import CalibrationCancelled, ProjectorSettings, calibrate_projector_recording
    from worker.measurement.readers import open_recording
    from worker.measurement.topography_files import write_projector_calibration

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
# The split: locating the edges of a frame is the expensive part and depends on that frame alone, so chunks of
# frames run it in parallel on every worker and store the edges (`chunks/edges-<first>.h5`). Identity is fixed
# on frame 0 and carried frame to frame, so the merge runs the cheap tracking, Z, X-Y and gridding pass over the
# stored edges in frame order: the same computation as one sequential run, whatever the chunking.


def _topography_inputs(context: JobContext) -> tuple[Any, Any, Any, range, Any]:
    """(frame source, camera model, projector table, frames to write, settings) of a topography job."""
    from worker.measurement.camera_files import read_camera_json
    from worker.measurement.readers import open_recording
    from worker.measurement.topography import TopographySettings, frame_range
    from worker.measurement.topography_files import read_projector_calibration

    spec = context.spec
    _recording, _camera, path = _recording_input(context)
    source = open_recording(path)
    camera_model = read_camera_json(_calibration_file(context, spec["camera_calibration_id"]))
    projector = read_projector_calibration(_calibration_file(context, spec["projector_calibration_id"]))
    frames = spec.get("frames") or {}
    last = frames.get("last")
    wanted = frame_range(range(frames.get("first", 0), len(source) if last is None else last + 1), len(source))
    settings = TopographySettings(
        grid_step_mm=spec["grid_step_mm"], temporal_smoothing_frames=spec["temporal_smoothing_frames"]
    )
    return source, camera_model, projector, wanted, settings


def _edges_name(first: int) -> str:
    return f"chunks/edges-{first:07d}.h5"


def topography_entry(context: JobContext) -> Chunked:
    from worker.measurement.topography import check_recording_against, check_stripes_against

    source, camera_model, projector, wanted, settings = _topography_inputs(context)
    first_frame = source[0]
    check_recording_against(first_frame.shape[:2], projector, camera_model)
    check_stripes_against(first_frame, projector)
    # identity is fixed on frame 0: edges are needed from there to the last frame written (+ the smoothing window)
    stop = min(wanted.stop + settings.temporal_smoothing_frames, len(source))
    context.log(f"topography of frames {wanted.start}..{wanted.stop - 1} (edges of frames 0..{stop - 1})")
    return Chunked(frame_ranges(stop, _chunk_frames(context.spec, context.settings)), stage="locating edges")


def topography_chunk(context: JobContext, first: int, stop: int) -> None:
    from worker.measurement.topography import locate_test_edges
    from worker.measurement.topography_files import write_edges

    source, _camera, projector, _wanted, _settings = _topography_inputs(context)
    edges = []
    for done, frame_edges in enumerate(locate_test_edges((source[i] for i in range(first, stop)), projector)):
        edges.append(frame_edges)
        context.progress(done + 1, stop - first, "locating edges")
    with context.output(_edges_name(first), publish=False) as temporary:
        write_edges(temporary, list(range(first, stop)), edges)


def topography_merge(context: JobContext, ranges: list[tuple[int, int]]) -> dict[str, Any]:
    from worker.measurement.topography import TopographyCancelled, topography_recording
    from worker.measurement.topography_files import read_edges

    source, camera_model, projector, wanted, settings = _topography_inputs(context)

    def stored_edges() -> Any:
        for first, stop in ranges:
            path = context.directory / _edges_name(first)
            if not path.is_file():
                raise RuntimeError(f"the located edges of frames {first}..{stop - 1} are missing")
            frames, edges = read_edges(path)
            if list(frames) != list(range(first, stop)):
                raise RuntimeError(f"{path.name} holds frames {frames[0]}..{frames[-1]}, not {first}..{stop - 1}")
            yield from edges

    try:
        with context.output("topography.h5", media_type="application/x-hdf5") as temporary:
            summary = topography_recording(
                source, camera_model, projector, out_path=temporary, frames=wanted, settings=settings,
                edges=stored_edges(), progress=lambda done, total, _stage: context.progress(done, total, "measuring"),
                should_cancel=context.should_cancel,
            )  # fmt: skip
    except TopographyCancelled as error:
        raise JobCancelled(str(error)) from None
    _remove_chunk_files(context.directory)
    result = {
        "frames": [summary.frames.start, summary.frames.stop - 1],
        "flat_rms_mm": summary.flat_rms_mm,
        "max_peak_w_mm": summary.max_peak_w_mm,
        "n_out_of_range_total": summary.n_out_of_range_total,
        "punch_axis_xy_mm": list(summary.punch_axis_xy_mm),
        "clamp_centre_xy_mm": list(summary.clamp_centre_xy_mm),
        "clamp_radius_mm": summary.clamp_radius_mm,
    }
    context.log(
        f"topography of {len(summary.frames)} frames: flat first frame RMS {summary.flat_rms_mm:.3f} mm, "
        f"peak deflection {summary.max_peak_w_mm:.2f} mm"
    )
    return {key: (None if isinstance(v, float) and not np.isfinite(v) else v) for key, v in result.items()}


def export_body(context: JobContext) -> dict[str, Any]:
    from worker.measurement.topography_files import export_result

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
    "topography": [(topography_chunk, topography_merge)],
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
