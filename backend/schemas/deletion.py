"""What a delete takes with it (`GET .../deletion`), shown by the dashboard as its confirmation."""

from __future__ import annotations

from pydantic import BaseModel, Field

from fringelab.core.deletion import DeletionPlan


class BlockingJobOut(BaseModel):
    id: str
    kind: str
    state: str


class DeletionOut(BaseModel):
    what: str = Field(description="What is deleted, in words: 'experiment 3 (plate 3)'.")
    cameras: int = Field(description="Cameras that go with it.")
    recordings: int = Field(description="Recordings that go with it (their files too).")
    jobs: int = Field(description="Finished jobs that go with it: those on its recordings, and their exports.")
    calibrations: int = Field(description="Calibration results that go with it.")
    bytes: int = Field(description="Bytes of files removed.")
    blocked_by: list[BlockingJobOut] = Field(
        description="Queued or running jobs that use it: while there are any, the delete is refused (409 in_use)."
    )
    summary: str = Field(description="One sentence for a confirmation.")


def deletion_out(plan: DeletionPlan) -> DeletionOut:
    return DeletionOut(
        what=plan.what,
        cameras=len(plan.cameras),
        recordings=len(plan.recordings),
        jobs=len(plan.jobs),
        calibrations=len(plan.calibrations),
        bytes=plan.bytes,
        blocked_by=[BlockingJobOut(id=job.id, kind=job.kind, state=job.state) for job in plan.blocked_by],
        summary=plan.summary(),
    )
