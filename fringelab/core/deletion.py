"""Deleting experiments, cameras, recordings and jobs (with their results): what goes with each, and doing it.

One rule for all four: a `DeletionPlan` lists everything that goes (cameras, recordings, the finished jobs that
worked on them with their files, logs and calibrations, and the exports of those jobs) and the queued or
running jobs that use any of it. The dashboard shows the plan as its confirmation; the delete itself is refused
(`Conflict`, code `in_use`, naming the jobs) while `blocked_by` is not empty, and otherwise removes the rows and
then the files. Jobs that merely used a deleted calibration's numbers keep their own results.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sqlalchemy import delete, select
from sqlalchemy.orm import Session

from fringelab.core.accounts import Principal, audit
from fringelab.core.errors import Conflict
from fringelab.core.job_kinds import named_by
from fringelab.core.models import Calibration, Camera, Experiment, Job, JobChunk, JobLog, Recording
from fringelab.core.settings import Settings
from fringelab.core.storage import job_dir, recording_dir, remove_tree, simulation_dir

ACTIVE_STATES = ("queued", "running")


@dataclass
class DeletionPlan:
    """What goes when `what` is deleted, and what stops it."""

    what: str
    experiments: list[Experiment] = field(default_factory=list)
    cameras: list[Camera] = field(default_factory=list)
    recordings: list[Recording] = field(default_factory=list)
    jobs: list[Job] = field(default_factory=list)
    calibrations: list[Calibration] = field(default_factory=list)
    blocked_by: list[Job] = field(default_factory=list)
    bytes: int = 0

    def summary(self) -> str:
        """One sentence a person reads before confirming."""
        parts = [
            _count(len(self.cameras), "camera"),
            _count(len(self.recordings), "recording"),
            _count(len(self.jobs), "job"),
            _count(len(self.calibrations), "calibration"),
        ]
        listed = [part for part in parts if part]
        goes = f"with {_join(listed)}" if listed else "alone"
        text = f"Deletes {self.what} {goes}: {_megabytes(self.bytes)} of files."
        if self.blocked_by:
            text += f" Not possible now: {_in_use(self.blocked_by)}."
        return text

    def refuse_if_blocked(self) -> None:
        if self.blocked_by:
            raise Conflict(
                f"{self.what} is in use by {_in_use(self.blocked_by)}; cancel the job or wait until it ends",
                code="in_use",
            )


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}{'' if n == 1 else 's'}" if n else ""


def _join(parts: list[str]) -> str:
    return parts[0] if len(parts) == 1 else ", ".join(parts[:-1]) + " and " + parts[-1]


def _megabytes(n: int) -> str:
    return f"{n / 1e6:.1f} MB" if n >= 1e5 else f"{n / 1e3:.0f} kB"


def _in_use(jobs: list[Job]) -> str:
    return ", ".join(f"{job.kind} job {job.id} ({job.state})" for job in jobs[:5]) + (
        f" and {len(jobs) - 5} more" if len(jobs) > 5 else ""
    )


def _file_bytes(data_path: Path, relative: str) -> int:
    try:
        return (data_path / relative).stat().st_size
    except OSError:
        return 0


def _job_bytes(job: Job) -> int:
    return sum(int(entry.get("size_bytes") or 0) for entry in job.files or [])


def _names(job: Job, names: str) -> set[Any]:
    """The ids of the `names` the job's spec names (its kind's inputs, `fringelab.core.job_kinds`)."""
    return named_by(job.kind, job.spec, names)


def _complete(session: Session, settings: Settings, plan: DeletionPlan, seed_jobs: Iterable[Job]) -> DeletionPlan:
    """Add to `plan`: the jobs on its recordings and cameras, the jobs' calibrations and exports, every active job
    that uses any of it, and the bytes."""
    recording_ids = {r.id for r in plan.recordings}
    camera_ids = {c.id for c in plan.cameras}
    experiment_ids = {e.id for e in plan.experiments}
    everything = list(session.scalars(select(Job)))
    going: dict[str, Job] = {job.id: job for job in seed_jobs}
    for job in everything:
        if (
            _names(job, "recording") & recording_ids
            or _names(job, "camera") & camera_ids
            or (job.experiment_id is not None and job.experiment_id in experiment_ids)
        ):
            going[job.id] = job
    calibrations = {c.id: c for c in plan.calibrations}
    changed = True
    while changed:  # exports of going jobs, calibrations made by going jobs, until nothing is added
        changed = False
        for calibration in session.scalars(select(Calibration)):
            made_here = calibration.job_id in going or calibration.camera_id in camera_ids
            if made_here and calibration.id not in calibrations:
                calibrations[calibration.id] = calibration
                changed = True
        for job in everything:
            if job.id not in going and _names(job, "job") & set(going):
                going[job.id] = job
                changed = True
    calibration_ids = set(calibrations)
    plan.calibrations = sorted(calibrations.values(), key=lambda c: c.id)
    plan.jobs = [job for job in going.values() if job.state not in ACTIVE_STATES]
    used = calibration_ids
    plan.blocked_by = [
        job
        for job in everything
        if job.state in ACTIVE_STATES
        and (job.id in going or _names(job, "job") & set(going) or _names(job, "calibration") & used)
    ]
    plan.bytes = (
        sum(r.size_bytes or 0 for r in plan.recordings)
        + sum(_job_bytes(job) for job in plan.jobs)
        + sum(_file_bytes(settings.data_path, c.path) for c in plan.calibrations if c.job_id not in going)
    )
    return plan


def plan_experiment(session: Session, settings: Settings, experiment: Experiment) -> DeletionPlan:
    cameras = list(experiment.cameras)
    plan = DeletionPlan(
        what=f"experiment {experiment.id} ({experiment.name})",
        experiments=[experiment],
        cameras=cameras,
        recordings=[r for camera in cameras for r in camera.recordings],
    )
    return _complete(session, settings, plan, [])


def plan_camera(session: Session, settings: Settings, camera: Camera) -> DeletionPlan:
    recordings = list(camera.recordings)
    plan = DeletionPlan(what=f"camera {camera.id} ({camera.name})", cameras=[camera], recordings=recordings)
    return _complete(session, settings, plan, [])


def plan_recording(session: Session, settings: Settings, recording: Recording) -> DeletionPlan:
    plan = DeletionPlan(what=f"recording {recording.id} ({recording.filename})", recordings=[recording])
    return _complete(session, settings, plan, [])


def plan_job(session: Session, settings: Settings, job: Job) -> DeletionPlan:
    plan = DeletionPlan(what=f"{job.kind} job {job.id}")
    plan = _complete(session, settings, plan, [job])
    if job.state in ACTIVE_STATES and job not in plan.blocked_by:
        plan.blocked_by.insert(0, job)
    return plan


def execute(session: Session, settings: Settings, principal: Principal, plan: DeletionPlan, **audited: Any) -> None:
    """Delete what the plan lists (rows first, in one transaction; then the files). Refused while blocked."""
    plan.refuse_if_blocked()
    job_ids = [job.id for job in plan.jobs]
    folders = [recording_dir(settings.data_path, r.id) for r in plan.recordings]
    folders += [job_dir(settings.data_path, job_id) for job_id in job_ids]
    # an experiment's simulations go with it (ORM cascade), their files here
    folders += [simulation_dir(settings.data_path, s.id) for e in plan.experiments for s in e.simulations]
    files = [settings.data_path / c.path for c in plan.calibrations]
    for calibration in plan.calibrations:
        session.delete(calibration)
    if job_ids:
        for recording in session.scalars(select(Recording).where(Recording.ingest_job_id.in_(job_ids))):
            recording.ingest_job_id = None
        session.execute(delete(JobLog).where(JobLog.job_id.in_(job_ids)))
        session.execute(delete(JobChunk).where(JobChunk.job_id.in_(job_ids)))
        for job in session.scalars(select(Job).where(Job.retry_of.in_(job_ids))):
            job.retry_of = None
        session.flush()
        session.execute(delete(Job).where(Job.id.in_(job_ids)))
    for thing in [*plan.recordings, *plan.cameras, *plan.experiments]:
        if thing not in plan.experiments and any(thing in e.cameras for e in plan.experiments):
            continue  # goes with its experiment (ORM cascade)
        if isinstance(thing, Recording) and any(thing in c.recordings for c in plan.cameras):
            continue  # goes with its camera
        session.delete(thing)
    audit(session, principal, "delete", audited.pop("kind"), audited.pop("id"), what=plan.what, **audited)
    session.commit()
    for folder in folders:
        remove_tree(settings.data_path, folder)
    for path in files:
        path.unlink(missing_ok=True)
