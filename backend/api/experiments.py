"""Experiments and their cameras: create, list, read, update, delete.

Access follows the experiment (`backend.auth`): its owner, admins and its group; anyone else gets a 404. A
delete removes the recordings' files too, and is refused (409) while a job uses them.
"""

from __future__ import annotations

from fastapi import APIRouter, Query, Response
from sqlalchemy import select

from backend.api.deps import CurrentUser, SessionDep, StateDep, experiment_for
from backend.auth import readable_experiments
from backend.errors import Conflict, error_responses
from backend.models import Camera, Experiment
from backend.recordings import camera_for, delete_camera, delete_experiment
from backend.schemas.cameras import CameraCreate, CameraOut, CameraUpdate
from backend.schemas.experiments import ExperimentCreate, ExperimentOut, ExperimentUpdate

router = APIRouter(tags=["experiments"])


@router.post("/experiments", status_code=201, response_model=ExperimentOut, responses=error_responses(401, 422))
def create_experiment(body: ExperimentCreate, session: SessionDep, principal: CurrentUser) -> Experiment:
    """A new experiment, owned by the caller."""
    experiment = Experiment(**body.model_dump(), owner_id=principal.user_id)
    session.add(experiment)
    session.commit()
    return experiment


@router.get("/experiments", response_model=list[ExperimentOut], responses=error_responses(401))
def list_experiments(
    session: SessionDep,
    principal: CurrentUser,
    limit: int = Query(100, ge=1, le=1000),
    offset: int = Query(0, ge=0),
) -> list[Experiment]:
    """The experiments the caller may read, newest first."""
    query = select(Experiment).where(readable_experiments(session, principal)).order_by(Experiment.id.desc())
    return list(session.scalars(query.limit(limit).offset(offset)))


@router.get("/experiments/{experiment_id}", response_model=ExperimentOut, responses=error_responses(401, 404))
def read_experiment(experiment_id: int, session: SessionDep, principal: CurrentUser) -> Experiment:
    return experiment_for(session, principal, experiment_id)


@router.patch("/experiments/{experiment_id}", response_model=ExperimentOut, responses=error_responses(401, 404, 422))
def update_experiment(
    experiment_id: int, body: ExperimentUpdate, session: SessionDep, principal: CurrentUser
) -> Experiment:
    experiment = experiment_for(session, principal, experiment_id, write=True)
    for name, value in body.model_dump(exclude_unset=True, exclude_none=True).items():
        setattr(experiment, name, value)
    session.commit()
    return experiment


@router.delete("/experiments/{experiment_id}", status_code=204, responses=error_responses(401, 404, 409))
def remove_experiment(experiment_id: int, session: SessionDep, state: StateDep, principal: CurrentUser) -> Response:
    """Deletes the experiment, its cameras and recordings with their files; 409 while a job uses any of them."""
    experiment = experiment_for(session, principal, experiment_id, write=True)
    delete_experiment(session, state.settings, principal, experiment)
    return Response(status_code=204)


@router.post(
    "/experiments/{experiment_id}/cameras",
    status_code=201,
    response_model=CameraOut,
    tags=["cameras"],
    responses=error_responses(401, 404, 409, 422),
)
def create_camera(experiment_id: int, body: CameraCreate, session: SessionDep, principal: CurrentUser) -> Camera:
    experiment = experiment_for(session, principal, experiment_id, write=True)
    _refuse_duplicate_name(session, experiment.id, body.name)
    camera = Camera(experiment_id=experiment.id, **body.model_dump())
    session.add(camera)
    session.commit()
    return camera


@router.get(
    "/experiments/{experiment_id}/cameras",
    response_model=list[CameraOut],
    tags=["cameras"],
    responses=error_responses(401, 404),
)
def list_cameras(experiment_id: int, session: SessionDep, principal: CurrentUser) -> list[Camera]:
    experiment = experiment_for(session, principal, experiment_id)
    return sorted(experiment.cameras, key=lambda camera: camera.id)


@router.get("/cameras/{camera_id}", response_model=CameraOut, tags=["cameras"], responses=error_responses(401, 404))
def read_camera(camera_id: int, session: SessionDep, principal: CurrentUser) -> Camera:
    return camera_for(session, principal, camera_id)


@router.patch(
    "/cameras/{camera_id}", response_model=CameraOut, tags=["cameras"], responses=error_responses(401, 404, 409, 422)
)
def update_camera(camera_id: int, body: CameraUpdate, session: SessionDep, principal: CurrentUser) -> Camera:
    camera = camera_for(session, principal, camera_id, write=True)
    changes = body.model_dump(exclude_unset=True, exclude_none=True)
    if "name" in changes and changes["name"] != camera.name:
        _refuse_duplicate_name(session, camera.experiment_id, changes["name"])
    for name, value in changes.items():
        setattr(camera, name, value)
    session.commit()
    return camera


@router.delete("/cameras/{camera_id}", status_code=204, tags=["cameras"], responses=error_responses(401, 404, 409))
def remove_camera(camera_id: int, session: SessionDep, state: StateDep, principal: CurrentUser) -> Response:
    """Deletes the camera and its recordings with their files; 409 while a job uses any of them."""
    delete_camera(session, state.settings, principal, camera_for(session, principal, camera_id, write=True))
    return Response(status_code=204)


def _refuse_duplicate_name(session: SessionDep, experiment_id: int, name: str) -> None:
    taken = session.scalar(select(Camera.id).where(Camera.experiment_id == experiment_id, Camera.name == name))
    if taken is not None:
        raise Conflict(f"experiment {experiment_id} already has a camera named {name!r}", code="camera_exists")
