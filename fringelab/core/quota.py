"""How much of the data volume one user may hold: FRINGELAB_USER_QUOTA_BYTES over their experiments' recordings,
simulations and job results, plus what their unfinished uploads have reserved (counted against them only).

One member's tus upload announcing the whole free disk and sending nothing made every other user's upload fail
with 413 for five days (issue 26): a reservation is now its owner's, within their quota, and it lapses hours
after its last byte (FRINGELAB_UPLOAD_RESERVATION_H; the bytes already sent stay counted as files on the disk).
"""

from __future__ import annotations

from sqlalchemy import func, select
from sqlalchemy.orm import Session

from fringelab.core.accounts import Principal
from fringelab.core.errors import TooLarge
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
    simulations = session.scalar(
        select(func.coalesce(func.sum(Simulation.size_bytes), 0)).where(Simulation.experiment_id.in_(owned))
    )
    results = sum(
        int(entry.get("size_bytes") or 0)
        for files in session.scalars(select(Job.files).where(Job.experiment_id.in_(owned)))
        for entry in files or []
    )
    return int(recordings or 0) + int(simulations or 0) + results


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
