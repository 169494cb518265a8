"""Typed dependencies shared by the routers: state, database session, the principal and access checks."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Annotated

from fastapi import Depends, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from sqlalchemy.orm import Session

from backend.auth import LOCAL_ADMIN, AuthError, Principal, can_access, resolve_token
from backend.errors import Forbidden, NotFound, Unauthorized
from backend.models import Experiment
from backend.state import AppState

SESSION_COOKIE = "fringelab_session"
_bearer = HTTPBearer(auto_error=False, description="An API token (`flb_...`) or the browser's session cookie.")


def get_state(request: Request) -> AppState:
    return request.app.state.fringelab


def get_session(state: Annotated[AppState, Depends(get_state)]) -> Iterator[Session]:
    with state.sessions() as session:
        yield session


StateDep = Annotated[AppState, Depends(get_state)]
SessionDep = Annotated[Session, Depends(get_session)]


def get_principal(
    request: Request,
    state: StateDep,
    session: SessionDep,
    credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)],
) -> Principal:
    if not state.settings.auth_enabled:
        return LOCAL_ADMIN
    secret = credentials.credentials if credentials else request.cookies.get(SESSION_COOKIE)
    if not secret:
        raise Unauthorized(
            "authentication required: send `Authorization: Bearer <token>` or log in",
            headers={"WWW-Authenticate": "Bearer"},
        )
    try:
        return resolve_token(session, secret)
    except AuthError as error:
        raise Unauthorized(str(error), headers={"WWW-Authenticate": "Bearer"}) from None


CurrentUser = Annotated[Principal, Depends(get_principal)]


def get_admin(principal: CurrentUser) -> Principal:
    if not principal.is_admin:
        raise Forbidden("this needs an admin account")
    return principal


AdminUser = Annotated[Principal, Depends(get_admin)]


def experiment_for(session: Session, principal: Principal, experiment_id: int, *, write: bool = False) -> Experiment:
    """The experiment if `principal` may read it (or write it); otherwise a 404, as if it did not exist."""
    experiment = session.get(Experiment, experiment_id)
    if experiment is None or not can_access(session, principal, experiment, write=write):
        raise NotFound(f"experiment {experiment_id} not found")
    return experiment
