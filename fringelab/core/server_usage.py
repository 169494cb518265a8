"""For a shared server: the job queue (what runs, on which worker, and what waits, in order) and the storage each
user's experiments take. Reads the database only; the API shows it on the dashboard's Queue page.

Visibility follows the experiments: a member sees the jobs of experiments they may read and, for the others,
only how many there are (their place in the queue matters, their names do not); an admin sees everything.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime
from typing import Any

from sqlalchemy import func, select
from sqlalchemy.orm import Session

from fringelab.core.accounts import Principal, readable_experiments
from fringelab.core.models import Camera, Experiment, Job, Recording, User

ACTIVE_STATES = ("queued", "running")


@dataclass
class QueuedJob:
    id: str
    kind: str
    state: str
    worker: str
    experiment_id: int | None
    experiment_name: str
    owner: str
    created_at: datetime
    started_at: datetime | None
    position: int | None  # 1 for the next to start among the queued; None while running


@dataclass
class QueueOverview:
    running: list[QueuedJob]
    waiting: list[QueuedJob]
    hidden_running: int  # jobs of experiments the caller may not read
    hidden_waiting: int
    workers: dict[str, int]  # worker name → jobs it runs now


@dataclass
class UserStorage:
    user: str
    experiments: int
    recordings: int
    recording_bytes: int
    result_bytes: int


def queue_overview(session: Session, principal: Principal) -> QueueOverview:
    readable = set(session.scalars(select(Experiment.id).where(readable_experiments(session, principal))))
    names = dict(session.execute(select(Experiment.id, Experiment.name)).all())
    owners = dict(
        session.execute(select(Experiment.id, User.username).join(User, User.id == Experiment.owner_id)).all()
    )
    jobs = list(session.scalars(select(Job).where(Job.state.in_(ACTIVE_STATES)).order_by(Job.created_at, Job.id)))
    shown: dict[str, list[QueuedJob]] = {"running": [], "queued": []}
    hidden = {"running": 0, "queued": 0}
    workers: dict[str, int] = {}
    position = 0
    for job in jobs:
        if job.state == "queued":
            position += 1
        if job.state == "running" and job.worker:
            workers[job.worker] = workers.get(job.worker, 0) + 1
        visible = principal.is_admin or (job.experiment_id is not None and job.experiment_id in readable)
        if not visible:
            hidden[job.state] += 1
            continue
        shown[job.state].append(
            QueuedJob(
                id=job.id,
                kind=job.kind,
                state=job.state,
                worker=job.worker,
                experiment_id=job.experiment_id,
                experiment_name=names.get(job.experiment_id, "") if job.experiment_id else "",
                owner=owners.get(job.experiment_id, "local") if job.experiment_id else "system",
                created_at=job.created_at,
                started_at=job.started_at,
                position=position if job.state == "queued" else None,
            )
        )
    return QueueOverview(
        running=shown["running"],
        waiting=shown["queued"],
        hidden_running=hidden["running"],
        hidden_waiting=hidden["queued"],
        workers=workers,
    )


def storage_by_user(session: Session, principal: Principal) -> list[UserStorage]:
    """Bytes of recordings and of job results per experiment owner (experiments without an owner: "local").
    A member sees their own line; an admin every user's."""
    usernames = dict(session.execute(select(User.id, User.username)).all())
    per_owner: dict[str, dict[str, Any]] = {}

    def entry(owner_id: int | None) -> dict[str, Any]:
        name = usernames.get(owner_id, "local") if owner_id is not None else "local"
        return per_owner.setdefault(name, {"experiments": 0, "recordings": 0, "recording_bytes": 0, "result_bytes": 0})

    for owner_id, count in session.execute(select(Experiment.owner_id, func.count()).group_by(Experiment.owner_id)):
        entry(owner_id)["experiments"] += int(count)
    recordings = session.execute(
        select(Experiment.owner_id, func.count(Recording.id), func.coalesce(func.sum(Recording.size_bytes), 0))
        .join(Camera, Camera.experiment_id == Experiment.id)
        .join(Recording, Recording.camera_id == Camera.id)
        .group_by(Experiment.owner_id)
    )
    for owner_id, count, size in recordings:
        entry(owner_id)["recordings"] += int(count)
        entry(owner_id)["recording_bytes"] += int(size or 0)
    owner_of = dict(session.execute(select(Experiment.id, Experiment.owner_id)).all())
    for experiment_id, files in session.execute(
        select(Job.experiment_id, Job.files).where(Job.experiment_id.is_not(None))
    ):
        entry(owner_of.get(experiment_id))["result_bytes"] += sum(int(f.get("size_bytes") or 0) for f in files or [])
    rows = [UserStorage(user=name, **numbers) for name, numbers in sorted(per_owner.items())]
    if principal.is_admin:
        return rows
    return [row for row in rows if row.user == principal.username]
