"""The "Load demo experiment" button's work: a virtual punch test measured like an uploaded one.

Task `fringelab.demo` (sent by POST /api/v1/demo, `simulate_demo`): for each camera preset, add the camera to the demo
experiment, render its three recordings (the `virtual-test` command's science, `write_virtual_test`) and register
them as an upload would (`register_upload`, which queues their ingest). Task `fringelab.demo_advance` (`advance`) then
looks every few seconds at what is ready and starts the next job of each camera through the jobs API's own rules
(`create_job`): camera calibration → projector calibration → topography. Polling from a short task, rather than
waiting inside one, keeps every worker process free for the jobs themselves, even with a single process.

Thin: it calls existing functions and holds no science. Both tasks are idempotent (acks-late work can run
twice): a camera, a recording or a job that exists is not made again.
"""

from __future__ import annotations

import logging
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

from celery import Celery
from pydantic import TypeAdapter
from sqlalchemy import select
from sqlalchemy.orm import Session

from fringelab.core.accounts import LOCAL_ADMIN, Principal
from fringelab.core.app_state import AppState
from fringelab.core.errors import DomainError
from fringelab.core.job_kinds import JobSpec, named_by
from fringelab.core.jobs import QueueUnavailable, create_job
from fringelab.core.models import Camera, Experiment, Job, Recording, User
from fringelab.core.recordings import register_upload
from fringelab.core.storage import InsufficientStorage, check_room, put_dir, sha256_of_file
from fringelab.core.text import public_text
from fringelab.pipelines.virtual_test import write_virtual_test
from fringelab.science.virtual_test import preset
from worker.runtime import sessions_of, settings_of

log = logging.getLogger(__name__)
ADVANCE_EVERY_S = 2.0
GIVE_UP_AFTER_S = 3600.0  # a demo whose jobs have not all started after an hour is left as it is
RECORDING_KINDS = ("camera_calibration", "projector_calibration", "test")
_specs: TypeAdapter[Any] = TypeAdapter(JobSpec)


def services_of(app: Celery) -> AppState:
    """What the demo's tasks use of this worker process: settings, database sessions and the queue."""
    sessions = sessions_of(app)
    return AppState(settings=settings_of(app), engine=sessions.kw["bind"], sessions=sessions, celery=app)


def _owner(session: Session, experiment: Experiment) -> Principal:
    """Who the demo acts as: the experiment's owner (everything stays theirs), or the local admin (no accounts)."""
    user = session.get(User, experiment.owner_id) if experiment.owner_id else None
    return Principal(user_id=user.id, username=user.username, role=user.role) if user else LOCAL_ADMIN


def simulate_demo(
    state: AppState,
    experiment_id: int,
    presets: list[str],
    test_frames: int,
    *,
    scenario: str = "quasi-static",
    first_camera_ready: Callable[[], None],
) -> None:
    """Add each preset's camera to the experiment and register its simulated recordings of the virtual test
    `scenario` (`virtual_test.SCENARIOS`) (idempotent). A demo that cannot be made (a full disk, a refused
    recording) says why in its experiment's notes, where its page shows it, not only in the worker log."""
    try:
        _simulate_demo(state, experiment_id, presets, test_frames, scenario=scenario,
                       first_camera_ready=first_camera_ready)  # fmt: skip
    except (OSError, ValueError, DomainError, InsufficientStorage) as error:
        reason = public_text(error.detail if isinstance(error, DomainError) else str(error))
        log.warning("demo experiment %s could not be made: %s", experiment_id, error)
        with state.sessions() as session:
            experiment = session.get(Experiment, experiment_id)
            if experiment is not None:
                experiment.notes = f"The demo could not be made: {reason}\n\n{experiment.notes}"[:20_000]
                session.commit()


def _simulate_demo(
    state: AppState,
    experiment_id: int,
    presets: list[str],
    test_frames: int,
    *,
    scenario: str,
    first_camera_ready: Callable[[], None],
) -> None:
    settings = state.settings
    check_room(settings.data_path, 0, reserve_bytes=settings.min_free_disk_bytes)  # before writing anything
    with state.sessions() as session:
        experiment = session.get(Experiment, experiment_id)
        if experiment is None:
            log.warning("demo experiment %s is gone; nothing to make", experiment_id)
            return
        principal = _owner(session, experiment)
    for index, name in enumerate(presets):
        camera_model = preset(name).camera
        with state.sessions() as session:
            camera = session.scalar(select(Camera).where(Camera.experiment_id == experiment_id, Camera.name == name))
            if camera is None:
                camera = Camera(
                    experiment_id=experiment_id,
                    name=name,
                    image_width_px=camera_model.image_width_px,
                    image_height_px=camera_model.image_height_px,
                    pixel_pitch_um=1000.0 / camera_model.du_px_per_mm,
                )
                session.add(camera)
                session.commit()
            camera_id = camera.id
            have = set(session.scalars(select(Recording.kind).where(Recording.camera_id == camera_id)))
        if not have.issuperset(RECORDING_KINDS):
            staging = put_dir(settings.data_path)  # on the data volume: registering is a rename
            staging.mkdir(parents=True, exist_ok=True)
            with tempfile.TemporaryDirectory(dir=staging, prefix="demo-") as folder:
                made = write_virtual_test(
                    Path(folder), name, n_test_frames=test_frames, as_zip=True, seed=index, scenario=scenario
                )
                files = {
                    "camera_calibration": made.camera_calibration,
                    "projector_calibration": made.projector_calibration,
                    "test": made.test,
                }
                for kind, path in files.items():
                    if kind in have:
                        continue
                    register_upload(
                        state,
                        principal,
                        staged=path,
                        camera_id=camera_id,
                        kind=kind,
                        filename=path.name,
                        sha256=sha256_of_file(path).hexdigest(),
                        size_bytes=path.stat().st_size,
                        upload_id=None,
                    )
        if index == 0:
            first_camera_ready()


def _latest_job(jobs: list[Job], kind: str, recording_id: int) -> Job | None:
    mine = [job for job in jobs if job.kind == kind and recording_id in named_by(kind, job.spec, "recording")]
    return max(mine, key=lambda job: job.created_at) if mine else None


def advance(session: Session, state: AppState, experiment_id: int, presets: list[str]) -> bool:
    """Start, for each demo camera, the next job its ready inputs allow. True when nothing is left to start (every
    camera has its topography job, or a step failed and the demo stops there for that camera)."""
    from fringelab.science.virtual_test import preset

    cameras = {c.name: c for c in session.scalars(select(Camera).where(Camera.experiment_id == experiment_id))}
    jobs = list(session.scalars(select(Job).where(Job.experiment_id == experiment_id)))
    finished = True
    for name in presets:
        camera = cameras.get(name)
        recordings = {r.kind: r for r in sorted(camera.recordings, key=lambda r: r.id)} if camera else {}
        if camera is None or not set(recordings).issuperset(RECORDING_KINDS):
            finished = False  # still being simulated
            continue
        if any(r.state == "invalid" for r in recordings.values()):
            log.warning("demo camera %s: a recording is invalid; its jobs are not started", name)
            continue
        steps: list[tuple[str, Recording, dict[str, Any]]] = [
            ("camera_calibration", recordings["camera_calibration"], {"scale_on": preset(name).camera.scale_on}),
            ("projector_calibration", recordings["projector_calibration"], {}),
            ("topography", recordings["test"], {}),
        ]
        calibrations: dict[str, int] = {}
        for kind, recording, extra in steps:
            job = _latest_job(jobs, kind, recording.id)
            if job is None:
                if recording.state != "ready":
                    finished = False
                    break
                spec: dict[str, Any] = {"kind": kind, "recording_id": recording.id, **extra}
                if kind != "camera_calibration":
                    spec["camera_calibration_id"] = calibrations["camera"]
                if kind == "topography":
                    spec["projector_calibration_id"] = calibrations["projector"]
                try:
                    create_job(session, state.celery, _specs.validate_python(spec))
                except (DomainError, QueueUnavailable) as error:
                    log.warning("demo camera %s: %s not started: %s", name, kind, error)
                    break
                if kind != "topography":
                    finished = False
                break
            if job.state in ("failed", "cancelled"):
                break  # the user sees why on the job; the demo does not retry
            if job.state != "succeeded":
                finished = False
                break
            if kind != "topography":
                calibrations["camera" if kind == "camera_calibration" else "projector"] = job.result["calibration_id"]
    return finished
