"""Experiments and their cameras: create, list, read, update, delete.

Access follows the experiment (`fringelab.core.accounts`): its owner, admins and its group; anyone else gets a
404, checked by the path dependencies of `backend.api.deps` before a body is validated. A delete removes the recordings'
files too, and is refused (409) while a job uses them.
"""

from __future__ import annotations

from fastapi import APIRouter, Query, Response
from sqlalchemy import select

from backend.api.deps import (
    CurrentUser,
    ReadableCamera,
    ReadableExperiment,
    SessionDep,
    StateDep,
    WritableCamera,
    WritableExperiment,
)
from backend.errors import error_responses
from backend.schemas.cameras import CameraCreate, CameraOut, CameraUpdate
from backend.schemas.common import MAX_ID
from backend.schemas.deletion import DeletionOut, deletion_out
from backend.schemas.experiments import ExperimentCreate, ExperimentOut, ExperimentUpdate, experiment_out
from fringelab.core.accounts import readable_experiments
from fringelab.core.deletion import plan_camera, plan_experiment
from fringelab.core.errors import Conflict
from fringelab.core.models import Camera, Experiment
from fringelab.core.recordings import delete_camera, delete_experiment, update_experiment

router = APIRouter(tags=["experiments"])


@router.post("/experiments", status_code=201, response_model=ExperimentOut, responses=error_responses(401, 422))
def create_experiment(body: ExperimentCreate, session: SessionDep, principal: CurrentUser) -> ExperimentOut:
    """A new experiment, owned by the caller (and shared with a group if `group_id` is given)."""
    experiment = Experiment(owner_id=principal.user_id)
    update_experiment(session, principal, experiment, body.model_dump())
    session.add(experiment)
    session.commit()
    return experiment_out(session, principal, experiment)


@router.get("/experiments", response_model=list[ExperimentOut], responses=error_responses(401, 422))
def list_experiments(
    session: SessionDep,
    principal: CurrentUser,
    limit: int = Query(100, ge=1, le=1000),
    offset: int = Query(0, ge=0, le=MAX_ID),
) -> list[ExperimentOut]:
    """The experiments the caller may read (own, shared with a group of theirs; all for admins), newest first."""
    query = select(Experiment).where(readable_experiments(session, principal)).order_by(Experiment.id.desc())
    return [experiment_out(session, principal, e) for e in session.scalars(query.limit(limit).offset(offset))]


@router.get("/experiments/{experiment_id}", response_model=ExperimentOut, responses=error_responses(401, 404, 422))
def read_experiment(experiment: ReadableExperiment, session: SessionDep, principal: CurrentUser) -> ExperimentOut:
    return experiment_out(session, principal, experiment)


@router.patch(
    "/experiments/{experiment_id}", response_model=ExperimentOut, responses=error_responses(401, 403, 404, 422)
)
def patch_experiment(
    experiment: WritableExperiment, body: ExperimentUpdate, session: SessionDep, principal: CurrentUser
) -> ExperimentOut:
    """Change fields; only the owner or an admin may change `group_id`/`group_access` (403 `not_owner`)."""
    changes = body.model_dump(exclude_unset=True)
    # null means "keep" for the descriptive fields, but "not shared" for group_id
    changes = {name: value for name, value in changes.items() if value is not None or name == "group_id"}
    update_experiment(session, principal, experiment, changes)
    session.commit()
    return experiment_out(session, principal, experiment)


@router.get(
    "/experiments/{experiment_id}/deletion", response_model=DeletionOut, responses=error_responses(401, 403, 404, 422)
)
def experiment_deletion(experiment: WritableExperiment, session: SessionDep, state: StateDep) -> DeletionOut:
    """What deleting the experiment takes with it, and the jobs that stop it now (nothing is deleted)."""
    return deletion_out(plan_experiment(session, state.settings, experiment))


@router.delete("/experiments/{experiment_id}", status_code=204, responses=error_responses(401, 403, 404, 409, 422))
def remove_experiment(
    experiment: WritableExperiment, session: SessionDep, state: StateDep, principal: CurrentUser
) -> Response:
    """Deletes the experiment, its cameras and recordings with their files, and the finished jobs on them with
    their results (see `.../deletion`); 409 `in_use` naming the jobs while a queued or running job uses any of it."""
    delete_experiment(session, state.settings, principal, experiment)
    return Response(status_code=204)


@router.post(
    "/experiments/{experiment_id}/cameras",
    status_code=201,
    response_model=CameraOut,
    tags=["cameras"],
    responses=error_responses(401, 403, 404, 409, 422),
)
def create_camera(experiment: WritableExperiment, body: CameraCreate, session: SessionDep) -> Camera:
    _refuse_duplicate_name(session, experiment.id, body.name)
    camera = Camera(experiment_id=experiment.id, **body.model_dump())
    session.add(camera)
    session.commit()
    return camera


@router.get(
    "/experiments/{experiment_id}/cameras",
    response_model=list[CameraOut],
    tags=["cameras"],
    responses=error_responses(401, 404, 422),
)
def list_cameras(experiment: ReadableExperiment) -> list[Camera]:
    return sorted(experiment.cameras, key=lambda camera: camera.id)


@router.get(
    "/cameras/{camera_id}", response_model=CameraOut, tags=["cameras"], responses=error_responses(401, 404, 422)
)
def read_camera(camera: ReadableCamera) -> Camera:
    return camera


@router.patch(
    "/cameras/{camera_id}",
    response_model=CameraOut,
    tags=["cameras"],
    responses=error_responses(401, 403, 404, 409, 422),
)
def update_camera(camera: WritableCamera, body: CameraUpdate, session: SessionDep) -> Camera:
    changes = body.model_dump(exclude_unset=True, exclude_none=True)
    if "name" in changes and changes["name"] != camera.name:
        _refuse_duplicate_name(session, camera.experiment_id, changes["name"])
    for name, value in changes.items():
        setattr(camera, name, value)
    session.commit()
    return camera


@router.get(
    "/cameras/{camera_id}/deletion",
    response_model=DeletionOut,
    tags=["cameras"],
    responses=error_responses(401, 403, 404, 422),
)
def camera_deletion(camera: WritableCamera, session: SessionDep, state: StateDep) -> DeletionOut:
    """What deleting the camera takes with it, and the jobs that stop it now (nothing is deleted)."""
    return deletion_out(plan_camera(session, state.settings, camera))


@router.delete(
    "/cameras/{camera_id}", status_code=204, tags=["cameras"], responses=error_responses(401, 403, 404, 409, 422)
)
def remove_camera(camera: WritableCamera, session: SessionDep, state: StateDep, principal: CurrentUser) -> Response:
    """Deletes the camera, its recordings and calibrations with their files, and the finished jobs on them with
    their results; 409 `in_use` naming the jobs while a queued or running job uses any of it."""
    delete_camera(session, state.settings, principal, camera)
    return Response(status_code=204)


def _refuse_duplicate_name(session: SessionDep, experiment_id: int, name: str) -> None:
    taken = session.scalar(select(Camera.id).where(Camera.experiment_id == experiment_id, Camera.name == name))
    if taken is not None:
        raise Conflict(f"experiment {experiment_id} already has a camera named {name!r}", code="camera_exists")
