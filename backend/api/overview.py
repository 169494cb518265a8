"""`/api/v1/queue` and `/api/v1/storage`: for a shared server, what runs and waits (on which worker) and what each
user's experiments take on disk. Thin: the rules are `fringelab.core.server_usage`."""

from __future__ import annotations

from fastapi import APIRouter
from pydantic import BaseModel, Field

from backend.api.deps import CurrentUser, SessionDep
from backend.errors import error_responses
from backend.schemas.common import UtcDatetime
from fringelab.core.server_usage import queue_overview, storage_by_user

router = APIRouter(tags=["queue"])


class QueuedJobOut(BaseModel):
    id: str
    kind: str
    state: str
    worker: str = Field(description="The worker process running it; empty while it waits.")
    experiment_id: int | None
    experiment_name: str
    owner: str
    created_at: UtcDatetime
    started_at: UtcDatetime | None
    position: int | None = Field(description="Place among the waiting jobs (1: next); null while running.")


class QueueOut(BaseModel):
    running: list[QueuedJobOut]
    waiting: list[QueuedJobOut]
    hidden_running: int = Field(description="Running jobs of experiments you may not read (counted, not shown).")
    hidden_waiting: int = Field(description="Waiting jobs of experiments you may not read.")
    workers: dict[str, int] = Field(description="Worker → the number of jobs it runs now.")


class StorageOut(BaseModel):
    user: str
    experiments: int
    recordings: int
    recording_bytes: int
    result_bytes: int


@router.get("/queue", response_model=QueueOut, responses=error_responses(401))
def queue(session: SessionDep, principal: CurrentUser) -> QueueOut:
    """Running jobs (with their worker) and waiting ones in the order they will start."""
    overview = queue_overview(session, principal)
    return QueueOut.model_validate(overview, from_attributes=True)


@router.get("/storage", response_model=list[StorageOut], responses=error_responses(401))
def storage(session: SessionDep, principal: CurrentUser) -> list[StorageOut]:
    """Bytes of recordings and results per user (admins: every user; members: their own)."""
    return [StorageOut.model_validate(row, from_attributes=True) for row in storage_by_user(session, principal)]
