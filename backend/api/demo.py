"""`POST /api/v1/demo`: the dashboard's "Load demo experiment" button.

It stores a new experiment (the caller's) and sends the `fringelab.demo` task by name; a worker adds the cameras,
simulates their recordings (the `simulate` command's science) and starts their calibration and topography jobs
(worker/jobs/demo.py). Thin: no science and no task code here. The cameras, recordings and jobs appear in the
experiment as they are made, and follow the same rules as uploaded ones.
"""

from __future__ import annotations

from typing import Annotated, Literal

from fastapi import APIRouter, Body
from pydantic import BaseModel, Field

from backend.api.deps import CurrentUser, SessionDep, StateDep
from backend.errors import error_responses
from fringelab.core.jobs import start_demo

router = APIRouter(tags=["demo"])


class DemoIn(BaseModel):
    model_config = {"extra": "forbid"}

    cameras: list[Literal["kodak", "phantom"]] = Field(
        default_factory=lambda: ["kodak", "phantom"],
        min_length=1,
        max_length=2,
        description="Virtual cameras (the paper's): kodak, 512 × 480 px, quick; phantom, 1024 × 1024 px, about "
        "four times slower. The first camera's results come first.",
    )
    test_frames: int = Field(20, ge=4, le=200, description="Frames of the simulated punch test.")


class DemoOut(BaseModel):
    experiment_id: int = Field(description="The new experiment; its cameras, recordings and jobs appear as made.")


@router.post("/demo", status_code=202, response_model=DemoOut, responses=error_responses(401, 422, 503))
def make_demo(
    session: SessionDep,
    state: StateDep,
    principal: CurrentUser,
    body: Annotated[DemoIn | None, Body(examples=[{"cameras": ["kodak"], "test_frames": 20}])] = None,
) -> DemoOut:
    """Make a virtual experiment and measure it: simulated recordings, calibrations and topography."""
    body = body or DemoIn()
    cameras = list(dict.fromkeys(body.cameras))  # each camera once, in the order asked
    return DemoOut(experiment_id=start_demo(session, state.celery, principal, cameras, body.test_frames))
