"""`POST /api/v1/demo`: the dashboard's "Load demo experiment" button.

It stores a new experiment (the caller's) and sends the `fringelab.demo` task by name; a worker adds the cameras,
renders their recordings as virtual tests (the `virtual-test` command's science) and starts their calibration and
topography jobs (worker/jobs/demo.py). Thin: no science and no task code here. The cameras, recordings and jobs
appear in the experiment as they are made, and follow the same rules as uploaded ones.
"""

from __future__ import annotations

from enum import StrEnum
from typing import Annotated, Literal, Self

from fastapi import APIRouter, Body
from pydantic import BaseModel, Field, model_validator

from backend.api.deps import CurrentUser, SessionDep, StateDep
from backend.errors import error_responses
from fringelab.core.jobs import start_demo
from fringelab.science.scenarios import SCENARIOS, min_test_frames

router = APIRouter(tags=["demo"])

# The virtual tests, as the API's enum (the list is `science.scenarios`').
DemoScenario = StrEnum("DemoScenario", {name: name for name in SCENARIOS})  # type: ignore[misc]


DemoCamera = Literal["kodak", "phantom"]


def _both_cameras() -> list[DemoCamera]:
    return ["kodak", "phantom"]


class DemoIn(BaseModel):
    model_config = {"extra": "forbid"}

    cameras: list[DemoCamera] = Field(
        default_factory=_both_cameras,
        min_length=1,
        max_length=2,
        description="Virtual cameras (the paper's): kodak, 512 × 480 px, quick; phantom, 1024 × 1024 px, about "
        "four times slower. The first camera's results come first.",
    )
    test_frames: int = Field(20, ge=4, le=200, description="Frames of the simulated punch test.")
    scenario: DemoScenario = Field(
        DemoScenario("quasi-static"),
        description="The virtual test: quasi-static, the paper's; fast, large motion per frame, then an 18 mm hole "
        "and 6 mm of springback within one frame; petals, the fast test with radial cracks and petals around the "
        "hole; highlight, a specular highlight on the plate; shadow, the fast test with the punch coming through "
        "and shadowing part of the stripes; hard, all of them at once. The fast ones need at least 6 frames.",
    )

    @model_validator(mode="after")
    def _enough_frames(self) -> Self:
        needed = min_test_frames(self.scenario.value)
        if self.test_frames < needed:
            raise ValueError(
                f"test_frames: the {self.scenario.value} scenario needs at least {needed} frames (a ramp, then the "
                f"perforated frames), got {self.test_frames}"
            )
        return self


class DemoOut(BaseModel):
    experiment_id: int = Field(description="The new experiment; its cameras, recordings and jobs appear as made.")


@router.post("/demo", status_code=202, response_model=DemoOut, responses=error_responses(401, 413, 422, 503))
def make_demo(
    session: SessionDep,
    state: StateDep,
    principal: CurrentUser,
    body: Annotated[
        DemoIn | None, Body(examples=[{"cameras": ["kodak"], "test_frames": 20, "scenario": "quasi-static"}])
    ] = None,
) -> DemoOut:
    """Make a virtual test and measure it: simulated recordings, calibrations and topography."""
    body = body or DemoIn.model_validate({})
    cameras = list(dict.fromkeys(body.cameras))  # each camera once, in the order asked
    experiment_id = start_demo(session, state.celery, principal, cameras, body.test_frames, body.scenario.value)
    return DemoOut(experiment_id=experiment_id)
