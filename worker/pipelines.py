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
import socket
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


def _chunk_name(first: int) -> str:
    return f"chunks/{first:07d}.npz"


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


def selftest_chunk(context: JobContext, first: int, stop: int) -> None:
    size_px = int(context.spec["frame_size_px"])
    values, digests = [], []
    for done, frame in enumerate(range(first, stop)):
        value, digest = selftest_frame(frame, size_px=size_px)
        values.append(value)
        digests.append(digest)
        context.progress(done + 1, stop - first, "computing frames")
    with context.output(_chunk_name(first), publish=False) as path, path.open("wb") as handle:
        np.savez(
            handle,
            frame=np.arange(first, stop, dtype=np.int64),
            value=np.asarray(values),
            digest=np.asarray(digests, dtype="S64"),
            worker=np.asarray([_this_worker()], dtype="S200"),
        )


def _read_chunks(context: JobContext, ranges: list[tuple[int, int]]) -> list[dict[str, np.ndarray]]:
    chunks = []
    for first, stop in ranges:
        path = context.directory / _chunk_name(first)
        if not path.is_file():
            raise RuntimeError(f"chunk file {path.name} of frames {first}..{stop - 1} is missing")
        with np.load(path) as data:
            chunks.append({key: data[key] for key in data.files})
    return chunks


def selftest_merge(context: JobContext, ranges: list[tuple[int, int]]) -> dict[str, Any]:
    context.progress(0, 1, "merging")
    chunks = _read_chunks(context, ranges)
    frame = np.concatenate([c["frame"] for c in chunks])
    expected = int(context.spec["frames"])
    if not np.array_equal(frame, np.arange(expected)):
        raise RuntimeError(f"the chunks hold {frame.size} frames, not each of 0..{expected - 1} once")
    digest = np.concatenate([c["digest"] for c in chunks])
    workers: dict[str, int] = {}
    for chunk in chunks:
        name = chunk["worker"][0].decode()
        workers[name] = workers.get(name, 0) + int(chunk["frame"].size)
    with context.output("selftest.h5", media_type="application/x-hdf5") as path, h5py.File(path, "w") as out:
        out["frame"] = frame
        out["value"] = np.concatenate([c["value"] for c in chunks])
        out["digest"] = digest
        out.attrs["frame_size_px"] = int(context.spec["frame_size_px"])
    with context.sessions() as session:
        started = session.scalar(select(Job.started_at).where(Job.id == context.job_id))
    elapsed_s = (utcnow() - as_utc(started)).total_seconds() if started is not None else None
    _remove_chunk_files(context.directory)
    return {
        "frames": expected,
        "chunks": len(ranges),
        "workers": workers,
        "digest": hashlib.sha256(b"".join(digest.tolist())).hexdigest(),
        "elapsed_s": elapsed_s,
        "frames_per_s": expected / elapsed_s if elapsed_s else None,
    }


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


# ------------------------------------------------------------------------------------------------ the tasks

CHUNK_BODIES: dict[str, ChunkBody] = {"selftest": selftest_chunk}
MERGE_BODIES: dict[str, MergeBody] = {"selftest": selftest_merge}


def _kind(task: Task, job_id: str) -> str | None:
    with sessions_of(task.app)() as session:
        return session.scalar(select(Job.kind).where(Job.id == job_id))


@shared_task(bind=True, name="fringelab.selftest", ignore_result=True)
def selftest(self: Task, job_id: str) -> dict[str, Any]:
    return run_job(self, job_id, selftest_entry)


@shared_task(bind=True, name="fringelab.camera_calibration", ignore_result=True)
def camera_calibration(self: Task, job_id: str) -> dict[str, Any]:
    return run_job(self, job_id, camera_calibration_body)


@shared_task(bind=True, name="fringelab.job_chunk", ignore_result=True)
def job_chunk(self: Task, job_id: str, index: int) -> None:
    kind = _kind(self, job_id)
    if kind is not None:
        run_chunk(self, job_id, index, CHUNK_BODIES[kind])


@shared_task(bind=True, name="fringelab.job_merge", ignore_result=True)
def job_merge(self: Task, job_id: str) -> dict[str, Any]:
    kind = _kind(self, job_id)
    return run_merge(self, job_id, MERGE_BODIES[kind]) if kind is not None else {}
