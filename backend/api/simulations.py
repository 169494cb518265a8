"""Simulations of an experiment: a streamed upload (one model file, or a ZIP of a folder format), list, read, delete.

`PUT /api/v1/experiments/{experiment_id}/simulations/{filename}` with the file as the body answers 201 with the
simulation stored and `checking`: its check job reads it in a worker (never in this process), and it turns `ready`
or `failed` with the reason. A name, size or archive that cannot be a simulation is refused at once (4xx) and leaves
nothing behind. Access follows the experiment (write access to upload or delete). The work is in
`fringelab.core.simulations`.
"""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Depends, Path, Request, Response
from fastapi.responses import JSONResponse
from sqlalchemy import select
from starlette.concurrency import run_in_threadpool

from backend.api.deps import CurrentUser, ExperimentId, ReadableExperiment, SessionDep, StateDep
from backend.errors import error_responses
from backend.schemas.common import MAX_ID
from backend.schemas.simulations import SimulationOut
from backend.streaming import declared_length, staged_body
from fringelab.core.models import Simulation
from fringelab.core.simulations import (
    check_simulation_request,
    delete_simulation,
    register_simulation,
    simulation_for,
)

router = APIRouter(tags=["simulations"])

SimulationId = Annotated[int, Path(ge=1, le=MAX_ID, description="A simulation id.")]


def readable_simulation(simulation_id: SimulationId, session: SessionDep, principal: CurrentUser) -> Simulation:
    return simulation_for(session, principal, simulation_id)


def writable_simulation(simulation_id: SimulationId, session: SessionDep, principal: CurrentUser) -> Simulation:
    return simulation_for(session, principal, simulation_id, write=True)


ReadableSimulation = Annotated[Simulation, Depends(readable_simulation)]
WritableSimulation = Annotated[Simulation, Depends(writable_simulation)]


@router.get(
    "/experiments/{experiment_id}/simulations",
    response_model=list[SimulationOut],
    responses=error_responses(401, 404, 422),
)
def list_simulations(experiment: ReadableExperiment, session: SessionDep) -> list[SimulationOut]:
    """The experiment's simulations, oldest first."""
    query = select(Simulation).where(Simulation.experiment_id == experiment.id).order_by(Simulation.id)
    return [SimulationOut.model_validate(s) for s in session.scalars(query)]


@router.get("/simulations/{simulation_id}", response_model=SimulationOut, responses=error_responses(401, 404, 422))
def read_simulation(simulation: ReadableSimulation) -> SimulationOut:
    return SimulationOut.model_validate(simulation)


@router.delete("/simulations/{simulation_id}", status_code=204, responses=error_responses(401, 403, 404, 409, 422))
def remove_simulation(
    simulation: WritableSimulation, session: SessionDep, state: StateDep, principal: CurrentUser
) -> Response:
    """Deletes the simulation and its files; 409 `in_use` naming the comparison jobs still reading it. Finished
    comparisons keep their files."""
    delete_simulation(session, state.settings, principal, simulation)
    return Response(status_code=204)


@router.put(
    "/experiments/{experiment_id}/simulations/{filename}",
    status_code=201,
    response_model=SimulationOut,
    responses=error_responses(400, 401, 403, 404, 413, 422),
    openapi_extra={
        "requestBody": {
            "content": {"application/octet-stream": {"schema": {"type": "string", "format": "binary"}}},
            "required": True,
        }
    },
)
async def put_simulation(
    experiment_id: ExperimentId, filename: str, request: Request, state: StateDep, principal: CurrentUser
) -> JSONResponse:
    """Upload a simulation in one streamed request (e.g. `curl -T plate.zip URL`): a model file (.csv, .vtu,
    .e/.exo) or a ZIP of a folder (a d3plot family with nodout/rcforc, a .pvd with its .vtu files, a nodal CSV
    with its punch CSV). Within FRINGELAB_MAX_UPLOAD_BYTES and the free disk. Answers the simulation `checking`;
    its check job reads it in a worker (GET /api/v1/simulations/{id} until `ready` or `failed`)."""
    settings = state.settings
    length = declared_length(request)
    await run_in_threadpool(
        lambda: check_simulation_request(
            state, principal, experiment_id=experiment_id, filename=filename, length=length
        )
    )
    async with staged_body(request, settings, length) as body:
        simulation_id = await run_in_threadpool(
            register_simulation,
            state,
            principal,
            staged=body.path,
            experiment_id=experiment_id,
            filename=filename,
            sha256=body.sha256,
            size_bytes=body.size_bytes,
        )

    def out() -> SimulationOut:
        with state.sessions() as session:
            return SimulationOut.model_validate(session.get(Simulation, simulation_id))

    simulation = await run_in_threadpool(out)
    return JSONResponse(
        simulation.model_dump(mode="json"),
        status_code=201,
        headers={"Location": f"/api/v1/simulations/{simulation.id}"},
    )
