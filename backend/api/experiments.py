"""Experiments and their cameras: create, list, read, update, delete (a delete removes the recordings' files
and is refused while a job uses them)."""

from __future__ import annotations

from fastapi import APIRouter, Query, Response
from sqlalchemy import select

from backend.api.deps import SessionDep, StateDep
from backend.api.errors import ApiError
from backend.models import Camera, Experiment
from backend.recordings import delete_camera, delete_experiment, get_or_404
from backend.schemas.cameras import CameraCreate, CameraOut, CameraUpdate
from backend.schemas.common import error_responses
from backend.schemas.experiments import ExperimentCreate, ExperimentOut, ExperimentUpdate

router = APIRouter(tags=["experiments"])


@router.post("/experiments", status_code=201, response_model=ExperimentOut, responses=error_responses(422))
def create_experiment(body: ExperimentCreate, session: SessionDep) -> Experiment:
    experiment = Experiment(**body.model_dump())
    session.add(experiment)
    session.commit()
    return experiment


@router.get("/experiments", response_model=list[ExperimentOut])
def list_experiments(
    session: SessionDep, limit: int = Query(100, ge=1, le=1000), offset: int = Query(0, ge=0)
) -> list[Experiment]:
    """Newest first."""
    return list(session.scalars(select(Experiment).order_by(Experiment.id.desc()).limit(limit).offset(offset)))


@router.get("/experiments/{experiment_id}", response_model=ExperimentOut, responses=error_responses(404))
def read_experiment(experiment_id: int, session: SessionDep) -> Experiment:
    return get_or_404(session, Experiment, experiment_id)


@router.patch("/experiments/{experiment_id}", response_model=ExperimentOut, responses=error_responses(404, 422))
def update_experiment(experiment_id: int, body: ExperimentUpdate, session: SessionDep) -> Experiment:
    experiment = get_or_404(session, Experiment, experiment_id)
    for name, value in body.model_dump(exclude_unset=True, exclude_none=True).items():
        setattr(experiment, name, value)
    session.commit()
    return experiment


@router.delete("/experiments/{experiment_id}", status_code=204, responses=error_responses(404, 409))
def remove_experiment(experiment_id: int, session: SessionDep, state: StateDep) -> Response:
    """Deletes the experiment, its cameras and recordings with their files; 409 while a job uses any of them."""
    delete_experiment(session, state.settings, get_or_404(session, Experiment, experiment_id))
    return Response(status_code=204)


@router.post(
    "/experiments/{experiment_id}/cameras",
    status_code=201,
    response_model=CameraOut,
    tags=["cameras"],
    responses=error_responses(404, 409, 422),
)
def create_camera(experiment_id: int, body: CameraCreate, session: SessionDep) -> Camera:
    experiment = get_or_404(session, Experiment, experiment_id)
    _refuse_duplicate_name(session, experiment_id, body.name)
    camera = Camera(experiment_id=experiment.id, **body.model_dump())
    session.add(camera)
    session.commit()
    return camera


@router.get(
    "/experiments/{experiment_id}/cameras",
    response_model=list[CameraOut],
    tags=["cameras"],
    responses=error_responses(404),
)
def list_cameras(experiment_id: int, session: SessionDep) -> list[Camera]:
    get_or_404(session, Experiment, experiment_id)
    return list(session.scalars(select(Camera).where(Camera.experiment_id == experiment_id).order_by(Camera.id)))


@router.get("/cameras/{camera_id}", response_model=CameraOut, tags=["cameras"], responses=error_responses(404))
def read_camera(camera_id: int, session: SessionDep) -> Camera:
    return get_or_404(session, Camera, camera_id)


@router.patch(
    "/cameras/{camera_id}", response_model=CameraOut, tags=["cameras"], responses=error_responses(404, 409, 422)
)
def update_camera(camera_id: int, body: CameraUpdate, session: SessionDep) -> Camera:
    camera = get_or_404(session, Camera, camera_id)
    changes = body.model_dump(exclude_unset=True, exclude_none=True)
    if "name" in changes and changes["name"] != camera.name:
        _refuse_duplicate_name(session, camera.experiment_id, changes["name"])
    for name, value in changes.items():
        setattr(camera, name, value)
    session.commit()
    return camera


@router.delete("/cameras/{camera_id}", status_code=204, tags=["cameras"], responses=error_responses(404, 409))
def remove_camera(camera_id: int, session: SessionDep, state: StateDep) -> Response:
    """Deletes the camera and its recordings with their files; 409 while a job uses any of them."""
    delete_camera(session, state.settings, get_or_404(session, Camera, camera_id))
    return Response(status_code=204)


def _refuse_duplicate_name(session: SessionDep, experiment_id: int, name: str) -> None:
    taken = session.scalar(select(Camera.id).where(Camera.experiment_id == experiment_id, Camera.name == name))
    if taken is not None:
        raise ApiError(409, "camera_exists", f"experiment {experiment_id} already has a camera named {name!r}")
