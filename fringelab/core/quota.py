"""How much of the data volume one user may hold: FRINGELAB_USER_QUOTA_BYTES over their experiments' recordings,
simulations (with the store their check writes, `checked.h5`) and job results, plus what their unfinished uploads
have reserved (counted against them only), plus what their experiments' queued and running jobs are expected to
write (each kind's `ResultSize` in `fringelab.core.job_kinds`: reserved when the job is queued, replaced by its
files' real sizes once it ends).

One member's tus upload announcing the whole free disk and sending nothing made every other user's upload fail
with 413 for five days (issue 26): a reservation is now its owner's, within their quota, and it lapses hours
after its last byte (FRINGELAB_UPLOAD_RESERVATION_H; the bytes already sent stay counted as files on the disk).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from sqlalchemy import case, func, select
from sqlalchemy.orm import Session

from fringelab.core.accounts import Principal
from fringelab.core.errors import TooLarge
from fringelab.core.job_kinds import JOB_KINDS, named_by
from fringelab.core.models import Camera, Experiment, Job, Recording, Simulation
from fringelab.core.settings import Settings


def used_bytes(session: Session, user_id: int | None) -> int:
    """Bytes of the recordings, simulations and job results of the experiments `user_id` owns."""
    owned = select(Experiment.id).where(Experiment.owner_id == user_id if user_id is not None else
                                        Experiment.owner_id.is_(None))  # fmt: skip
    recordings = session.scalar(
        select(func.coalesce(func.sum(Recording.size_bytes), 0))
        .join(Camera, Camera.id == Recording.camera_id)
        .where(Camera.experiment_id.in_(owned))
    )
    # A simulation is its upload plus the store its check writes beside it (`checked.h5`): its real size once
    # written, and while it is being checked, as much again as the upload (what the store takes, about).
    store = case((Simulation.state == "checking", Simulation.size_bytes), else_=Simulation.checked_bytes)
    simulations = session.scalar(
        select(func.coalesce(func.sum(Simulation.size_bytes + store), 0)).where(Simulation.experiment_id.in_(owned))
    )
    results = sum(
        int(entry.get("size_bytes") or 0)
        for files in session.scalars(select(Job.files).where(Job.experiment_id.in_(owned)))
        for entry in files or []
    )
    active = session.execute(
        select(Job.kind, Job.spec).where(Job.experiment_id.in_(owned), Job.state.in_(("queued", "running")))
    )
    expected = sum(expected_result_bytes(session, kind, spec or {}) for kind, spec in active)
    return int(recordings or 0) + int(simulations or 0) + results + expected


def expected_result_bytes(session: Session, kind: str, stored: Mapping[str, Any]) -> int:
    """What the result files of a job of `kind` with the stored spec `stored` are expected to take (its kind's
    `ResultSize`: flat, per pixel of the frames of the recordings it names, times the files of the job it reads);
    0 for a kind no longer known."""
    entry = JOB_KINDS.get(kind)
    if entry is None:
        return 0
    size = entry.result_size
    total = float(size.flat_bytes)
    if size.bytes_per_pixel_frame:
        ids = [i for i in named_by(kind, stored, "recording") if isinstance(i, int)]
        pixel_frames = session.scalar(
            select(func.coalesce(func.sum(Recording.frame_count * Recording.width_px * Recording.height_px), 0))
            .where(Recording.id.in_(ids))
        ) if ids else 0  # fmt: skip
        total += size.bytes_per_pixel_frame * int(pixel_frames or 0)
    if size.times_source:
        sources = [i for i in named_by(kind, stored, "job") if isinstance(i, str)]
        total += size.times_source * sum(
            int(entry.get("size_bytes") or 0)
            for files in session.scalars(select(Job.files).where(Job.id.in_(sources)))
            for entry in files or []
        )
    return int(total)


def check_result_quota(
    session: Session, settings: Settings, *, experiment_id: int | None, kind: str, stored: Mapping[str, Any]
) -> None:
    """Refuse (TooLarge, 413 `over_quota`) to queue a job whose results, as expected, would take the owner of
    `experiment_id` beyond FRINGELAB_USER_QUOTA_BYTES (the owner's quota: the results are kept in their experiment,
    whoever starts the job). No quota: 0, a job outside any experiment, an experiment of the local admin."""
    quota = settings.user_quota_bytes
    experiment = session.get(Experiment, experiment_id) if quota and experiment_id is not None else None
    if experiment is None or experiment.owner_id is None:
        return
    expected = expected_result_bytes(session, kind, stored)
    used = used_bytes(session, experiment.owner_id)
    if used + expected > quota:
        raise TooLarge(
            f"the results of this {kind} job are expected to take {expected} bytes, and the owner of experiment "
            f"{experiment_id} holds {used} bytes (what their queued and running jobs are expected to write "
            f"included), over the {quota}-byte quota of one user (FRINGELAB_USER_QUOTA_BYTES); delete something "
            "or ask an admin",
            code="over_quota",
        )


def check_quota(session: Session, settings: Settings, principal: Principal, *, incoming_bytes: int) -> None:
    """Refuse (TooLarge, 413 `over_quota`) `incoming_bytes` more for `principal` beyond FRINGELAB_USER_QUOTA_BYTES
    (0: no quota; the built-in local admin of a server without accounts has none)."""
    quota = settings.user_quota_bytes
    if not quota or principal.user_id is None:
        return
    used = used_bytes(session, principal.user_id)
    if used + incoming_bytes > quota:
        raise TooLarge(
            f"{principal.username} holds {used} bytes (and reserves {incoming_bytes} more for this and unfinished "
            f"uploads), over the {quota}-byte quota of one user (FRINGELAB_USER_QUOTA_BYTES); delete something "
            "or ask an admin",
            code="over_quota",
        )
