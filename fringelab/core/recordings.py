"""Experiments, cameras and recordings as the API changes them.

What belongs here: who may see or change a camera or recording (it follows its experiment, `fringelab.core.accounts`),
when a delete is refused (a job still uses the files) and what it removes, how a finished upload is checked and
becomes a recording with its ingest job, and the outward shape of a recording. Routes call these and stay thin;
everything a client must act on is an `DomainError` (`backend.errors`).
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Any

from sqlalchemy import select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from fringelab.core import upload_checks
from fringelab.core.accounts import Principal, access_level, audit, readable_experiments, require_access
from fringelab.core.app_state import AppState
from fringelab.core.errors import (
    Conflict,
    DomainError,
    Forbidden,
    Invalid,
    NotFound,
    TooLarge,
    Unavailable,
    UnsupportedFormat,
)
from fringelab.core.job_kinds import named_by
from fringelab.core.jobs import ACTIVE_STATES
from fringelab.core.models import Camera, Experiment, Group, Job, Recording
from fringelab.core.quota import check_quota
from fringelab.core.settings import Settings
from fringelab.core.storage import (
    InsufficientStorage,
    check_room,
    free_disk_bytes,
    place_file,
    recording_dir,
    recording_file_name,
    remove_tree,
    replace_with_link,
    sync_file,
)
from fringelab.core.text import check_file_name
from fringelab.core.upload_checks import RECORDING_INGEST
from fringelab.formats.container_common import CorruptRecording, OverBudget, UnsafeArchive, UnsupportedRecording
from fringelab.formats.container_zip import ZipLimits
from fringelab.formats.containers import (
    ACCEPTED_UPLOADS,
    UPLOAD_SUFFIXES,
    RecordingLayout,
    check_ingest_budget,
    recording_layout,
)
from fringelab.formats.previews import THUMBNAIL_PX

KINDS = ("camera_calibration", "projector_calibration", "test")


def camera_for(session: Session, principal: Principal, camera_id: int, *, write: bool = False) -> Camera:
    """The camera if `principal` may read (or write) its experiment; otherwise a 404, as if it did not exist
    (a 403 for a read-only group member asking to write, `fringelab.core.accounts.require_access`)."""
    camera = session.get(Camera, camera_id)
    if camera is None:
        raise NotFound(f"camera {camera_id} not found")
    require_access(session, principal, camera.experiment, write=write, what=f"camera {camera_id}")
    return camera


def recording_for(session: Session, principal: Principal, recording_id: int, *, write: bool = False) -> Recording:
    """The recording if `principal` may read (or write) its experiment; otherwise a 404 (403: read-only)."""
    recording = session.get(Recording, recording_id)
    if recording is None:
        raise NotFound(f"recording {recording_id} not found")
    require_access(session, principal, recording.camera.experiment, write=write, what=f"recording {recording_id}")
    return recording


SHARING_FIELDS = ("group_id", "group_access")


def update_experiment(session: Session, principal: Principal, experiment: Experiment, changes: dict[str, Any]) -> None:
    """Apply the fields of an ExperimentCreate/ExperimentUpdate (not committed). Sharing (group_id, group_access)
    is the owner's or an admin's decision: a group member with write access may edit the rest, not re-share it."""
    new = experiment.id is None
    resharing = {
        name: changes[name] for name in SHARING_FIELDS if name in changes and getattr(experiment, name) != changes[name]
    }
    if resharing and not new and access_level(session, principal, experiment) not in ("owner", "admin"):
        raise Forbidden(
            f"only the owner of experiment {experiment.id} or an admin may change whom it is shared with",
            code="not_owner",
        )
    group_id = resharing.get("group_id")
    if group_id is not None and session.get(Group, group_id) is None:
        raise Invalid(f"group_id: there is no group {group_id}; see GET /api/v1/groups", code="unknown_group")
    for name, value in changes.items():
        setattr(experiment, name, value)
    if resharing and not new:
        audit(session, principal, "share", "experiment", experiment.id,
              group_id=experiment.group_id, group_access=experiment.group_access)  # fmt: skip


# ---------------------------------------------------------------------------------------------- jobs in use


def active_jobs_using(
    session: Session,
    *,
    recording_ids: Iterable[int] = (),
    camera_ids: Iterable[int] = (),
    experiment_id: int | None = None,
) -> list[Job]:
    """Queued or running jobs whose spec names one of the recordings or cameras, or that belong to the experiment.

    What a job names is its kind's inputs (`fringelab.core.job_kinds`).
    """
    recordings, cameras = set(recording_ids), set(camera_ids)
    using = []
    for job in session.scalars(select(Job).where(Job.state.in_(ACTIVE_STATES))):
        if (
            named_by(job.kind, job.spec, "recording") & recordings
            or named_by(job.kind, job.spec, "camera") & cameras
            or (experiment_id is not None and job.experiment_id == experiment_id)
        ):
            using.append(job)
    return using


def refuse_if_in_use(session: Session, what: str, **inputs: Any) -> None:
    jobs = active_jobs_using(session, **inputs)
    if jobs:
        listed = ", ".join(f"{job.kind} job {job.id} ({job.state})" for job in jobs[:5])
        raise Conflict(f"{what} is in use by {listed}; cancel the job or wait until it ends", code="in_use")


# ---------------------------------------------------------------------------------------------- deletes


def delete_experiment(session: Session, settings: Settings, principal: Principal, experiment: Experiment) -> None:
    """The experiment with its cameras, recordings and their jobs' results (`fringelab.core.deletion`)."""
    from fringelab.core.deletion import execute, plan_experiment

    execute(
        session,
        settings,
        principal,
        plan_experiment(session, settings, experiment),
        kind="experiment",
        id=experiment.id,
    )


def delete_camera(session: Session, settings: Settings, principal: Principal, camera: Camera) -> None:
    from fringelab.core.deletion import execute, plan_camera

    execute(session, settings, principal, plan_camera(session, settings, camera), kind="camera", id=camera.id)


def delete_recording(session: Session, settings: Settings, principal: Principal, recording: Recording) -> None:
    from fringelab.core.deletion import execute, plan_recording

    execute(
        session, settings, principal, plan_recording(session, settings, recording), kind="recording", id=recording.id
    )


# ---------------------------------------------------------------------------------------------- ingest


def submit_ingest(session: Session, state: AppState, recording: Recording) -> Recording:
    """Queue the ingest job of a recording (state `ingesting`); without a queue the recording turns `invalid`."""
    upload_checks.submit_check(session, state.celery, RECORDING_INGEST, recording,
                               experiment_id=recording.camera.experiment_id)  # fmt: skip
    return recording


def start_ingest(session: Session, state: AppState, recording: Recording) -> Recording:
    """Run the ingest again (after a sidecar was added, a kind changed, or a failure was mended)."""
    refuse_if_in_use(session, f"recording {recording.id}", recording_ids=[recording.id])
    submit_ingest(session, state, recording)
    if recording.state == "invalid" and recording.error.startswith("the ingest could not be queued"):
        raise Unavailable(recording.error, code="queue_unavailable")
    return recording


# ---------------------------------------------------------------------------------------------- uploads


def check_upload_request(
    state: AppState,
    principal: Principal,
    *,
    camera_id: int,
    kind: str,
    filename: str,
    length: int | None,
    reserved_bytes: int = 0,
) -> None:
    """Refuse an upload before any byte is sent: unknown camera or kind, unsupported name, size or disk space."""
    if kind not in KINDS:
        raise Invalid(f"kind must be one of {', '.join(KINDS)}, got {kind!r}", code="invalid_kind")
    check_file_name(filename)
    suffix = Path(filename).suffix.lower()
    if suffix not in UPLOAD_SUFFIXES:
        raise UnsupportedFormat(
            f"{filename}: {suffix or 'no extension'} is not a recording format fringelab reads; it reads "
            f"{ACCEPTED_UPLOADS} (zip a folder of frames)",
            code="unsupported_format",
        )
    with state.sessions() as session:
        camera_for(session, principal, camera_id, write=True)
        if length is not None:
            check_quota(session, state.settings, principal, incoming_bytes=length + reserved_bytes)
    if length is not None:
        check_upload_size(state.settings, length, reserved_bytes=reserved_bytes)


def check_upload_size(settings: Settings, length: int, *, reserved_bytes: int = 0) -> None:
    if length < 0:
        raise DomainError(f"an upload cannot have {length} bytes", code="invalid_length")
    if length == 0:
        raise DomainError("the upload is empty (0 bytes)", code="empty_upload")
    if length > settings.max_upload_bytes:
        raise TooLarge(
            f"{length} bytes is more than the {settings.max_upload_bytes}-byte limit (FRINGELAB_MAX_UPLOAD_BYTES)",
            code="upload_too_large",
        )
    try:
        check_room(settings.data_path, length + reserved_bytes, reserve_bytes=settings.min_free_disk_bytes)
    except InsufficientStorage as error:
        raise TooLarge(str(error), code="insufficient_storage") from None


def inspect_upload(path: Path, *, filename: str, settings: Settings) -> str:
    """The format of a received file after checking its container; DomainError 415/422 when it is no recording."""
    try:
        layout = recording_layout(path, zip_limits=zip_limits(settings))
        if layout.format == "folder":
            raise UnsupportedRecording(f"{filename}: a folder cannot be uploaded; zip it")
        check_budget(layout, settings, name=filename)
        format = layout.format
    except OverBudget as error:
        raise TooLarge(_named(error, path, filename), code="over_budget") from None
    except UnsupportedRecording as error:
        raise UnsupportedFormat(_named(error, path, filename), code="unsupported_format") from None
    except UnsafeArchive as error:
        raise Invalid(_named(error, path, filename), code="unsafe_archive") from None
    except CorruptRecording as error:
        raise Invalid(_named(error, path, filename), code="corrupt_recording") from None
    except ValueError as error:  # any other refusal of the format readers: the file's fault, never a 500
        raise Invalid(_named(error, path, filename), code="invalid_recording") from None
    return format


def zip_limits(settings: Settings) -> ZipLimits:
    return ZipLimits(max_total_bytes=settings.zip_max_uncompressed_bytes, max_ratio=settings.zip_max_ratio)


def check_budget(layout: RecordingLayout, settings: Settings, *, name: str) -> None:
    """The ingest budget of a recording (its first frame's size against FRINGELAB_MAX_FRAME_BYTES, frames × frame
    size against FRINGELAB_MAX_FRAMES_BYTES, its previews
    against the free disk less FRINGELAB_MIN_FREE_DISK_BYTES), checked at upload and again by the ingest before
    it writes anything. Raises OverBudget."""
    check_ingest_budget(
        layout,
        name=name,
        max_frames_bytes=settings.max_frames_bytes,
        free_bytes=free_disk_bytes(settings.data_path),
        reserve_bytes=settings.min_free_disk_bytes,
        preview_size_px=settings.preview_size_px,
        thumbnail_px=THUMBNAIL_PX,
        max_frame_bytes=settings.max_frame_bytes,
    )


def _named(error: Exception, path: Path, filename: str) -> str:
    """Messages name the stored file; a person knows it by the name they uploaded."""
    return str(error).replace(path.name, filename)


def register_upload(
    state: AppState,
    principal: Principal,
    *,
    staged: Path,
    camera_id: int,
    kind: str,
    filename: str,
    sha256: str,
    size_bytes: int,
    upload_id: str | None,
) -> int:
    """Turn a fully received file into a recording and queue its ingest; returns the recording's id.

    The file is checked (format, container), moved into `recordings/<id>/` (a rename) and, when a recording
    the user may read has the same bytes, replaced by a hard link to it. On any refusal the staged file stays where it
    is for the caller to remove. Idempotent per upload id.
    """
    settings = state.settings
    if upload_id is not None:
        known = recording_of_upload(state, upload_id)
        if known is not None:
            return known
    format = inspect_upload(staged, filename=filename, settings=settings)
    sync_file(staged)
    with state.sessions() as session:
        camera = camera_for(session, principal, camera_id, write=True)
        # Among the recordings this user may read: another user's file is neither named nor linked to.
        duplicate = session.scalars(
            select(Recording)
            .join(Camera)
            .join(Experiment)
            .where(Recording.sha256 == sha256, Recording.size_bytes == size_bytes, Recording.path != "")
            .where(readable_experiments(session, principal))
            .order_by(Recording.id)
            .limit(1)
        ).first()
        recording = Recording(
            camera_id=camera.id,
            kind=kind,
            state="ingesting",
            filename=filename,
            format=format,
            size_bytes=size_bytes,
            sha256=sha256,
            upload_id=upload_id,
            duplicate_of=duplicate.id if duplicate else None,
        )
        session.add(recording)
        try:
            session.flush()
        except IntegrityError:  # the same upload completed twice at once: the other request registered it
            session.rollback()
            known = recording_of_upload(state, upload_id or "")
            if known is None:
                raise
            return known
        target = recording_dir(settings.data_path, recording.id) / recording_file_name(format)
        place_file(staged, target)
        try:
            recording.path = str(target.relative_to(settings.data_path))
            audit(session, principal, "upload", "recording", recording.id, filename=filename, size_bytes=size_bytes,
                  sha256=sha256, camera_id=camera.id)  # fmt: skip
            session.commit()
        except BaseException:
            session.rollback()
            place_file(target, staged)
            remove_tree(settings.data_path, target.parent)
            raise
        if duplicate is not None:
            replace_with_link(settings.data_path / duplicate.path, target)
        submit_ingest(session, state, recording)
        return recording.id


def recording_of_upload(state: AppState, upload_id: str) -> int | None:
    with state.sessions() as session:
        recording = session.scalars(select(Recording).where(Recording.upload_id == upload_id)).first()
        return recording.id if recording else None
