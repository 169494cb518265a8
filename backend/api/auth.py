"""Login, API tokens, users, groups and the audit trail (`/api/v1/auth`, `/api/v1/users`, ...).

Thin: the rules are `fringelab.core.accounts`.
"""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Path, Query, Request, Response

from backend.api.deps import SESSION_COOKIE, AdminUser, CurrentUser, SessionDep, StateDep
from backend.errors import error_responses
from backend.schemas.auth import (
    AuditOut,
    GroupIn,
    GroupOut,
    LoginIn,
    Me,
    TokenCreated,
    TokenIn,
    TokenOut,
    UserIn,
    UserOut,
    UserPatch,
)
from backend.schemas.common import MAX_ID
from fringelab.core import accounts
from fringelab.core.models import ApiToken, AuditEvent, Group, User

router = APIRouter(tags=["accounts"])


@router.post("/auth/login", response_model=Me, responses=error_responses(401, 429))
def login(body: LoginIn, request: Request, response: Response, state: StateDep, session: SessionDep) -> Me:
    """Check a username and password and set the browser's session cookie."""
    client = request.client.host if request.client else "unknown"
    user, secret, ttl = accounts.log_in(
        session, state.settings, client=client, username=body.username, password=body.password
    )
    secure = state.settings.secure_cookies == "always" or (
        state.settings.secure_cookies == "auto" and request.url.scheme == "https"
    )
    response.set_cookie(
        SESSION_COOKIE,
        secret,
        max_age=int(ttl.total_seconds()),
        httponly=True,
        samesite="strict",
        path="/",
        secure=secure,
    )
    return Me(username=user.username, role=user.role, auth_enabled=True)


@router.post("/auth/logout", status_code=204, responses=error_responses(401))
def logout(request: Request, response: Response, session: SessionDep, state: StateDep, principal: CurrentUser) -> None:
    """End the browser session (its token is revoked)."""
    secret = request.cookies.get(SESSION_COOKIE)
    if secret:
        accounts.log_out(session, secret)
        state.tokens.forget()
    response.delete_cookie(SESSION_COOKIE, path="/")


@router.get("/auth/me", response_model=Me, responses=error_responses(401))
def me(principal: CurrentUser, state: StateDep) -> Me:
    """Who the server thinks you are."""
    return Me(username=principal.username, role=principal.role, auth_enabled=state.settings.auth_enabled)


@router.get("/auth/tokens", response_model=list[TokenOut], responses=error_responses(401))
def list_tokens(session: SessionDep, principal: CurrentUser) -> list[ApiToken]:
    """Your API tokens (not their secrets)."""
    return accounts.api_tokens_of(session, principal)


@router.post("/auth/tokens", response_model=TokenCreated, status_code=201, responses=error_responses(401, 409))
def create_token(body: TokenIn, session: SessionDep, principal: CurrentUser) -> TokenCreated:
    """Create an API token for scripts; the secret is in this response only."""
    row, secret = accounts.create_api_token(session, principal, name=body.name, expires_in_days=body.expires_in_days)
    return TokenCreated(**TokenOut.model_validate(row).model_dump(), token=secret)


@router.delete("/auth/tokens/{token_id}", status_code=204, responses=error_responses(401, 404))
def revoke_token(
    token_id: Annotated[int, Path(ge=1, le=MAX_ID)], session: SessionDep, state: StateDep, principal: CurrentUser
) -> None:
    """Revoke one of your tokens; scripts using it get 401 from now on (from other API processes within
    FRINGELAB_TOKEN_CACHE_S)."""
    accounts.revoke_token(session, principal, token_id)
    state.tokens.forget()


@router.get("/users", response_model=list[UserOut], responses=error_responses(401, 403))
def list_users(session: SessionDep, _admin: AdminUser) -> list[User]:
    """All accounts (admin)."""
    return accounts.all_users(session)


@router.post("/users", response_model=UserOut, status_code=201, responses=error_responses(401, 403, 409))
def add_user(body: UserIn, session: SessionDep, admin: AdminUser) -> User:
    """Create an account (admin)."""
    return accounts.add_user(session, admin, username=body.username, password=body.password, role=body.role)


@router.patch("/users/{user_id}", response_model=UserOut, responses=error_responses(401, 403, 404, 409))
def update_user(
    user_id: Annotated[int, Path(ge=1, le=MAX_ID)],
    body: UserPatch,
    session: SessionDep,
    state: StateDep,
    admin: AdminUser,
) -> User:
    """Change an account's role or disable it (admin); a disabled account's tokens stop working at once (in
    other API processes within FRINGELAB_TOKEN_CACHE_S). The last active admin is neither demoted nor disabled (409)."""
    user = accounts.update_user(session, admin, user_id, body.model_dump(exclude_none=True))
    state.tokens.forget()
    return user


def _group_out(session: SessionDep, group: Group, *, with_members: bool = True) -> GroupOut:
    members = accounts.group_members(session, group) if with_members else []
    return GroupOut(id=group.id, name=group.name, members=members)


@router.get("/groups", response_model=list[GroupOut], responses=error_responses(401))
def list_groups(session: SessionDep, principal: CurrentUser) -> list[GroupOut]:
    """Groups that experiments can be shared with; their members are listed to admins only (to anyone else a
    list of usernames would be a directory of the lab's accounts)."""
    return [_group_out(session, group, with_members=principal.is_admin) for group in accounts.all_groups(session)]


@router.post("/groups", response_model=GroupOut, status_code=201, responses=error_responses(401, 403, 409))
def add_group(body: GroupIn, session: SessionDep, admin: AdminUser) -> GroupOut:
    """Create a group with its members (admin)."""
    return _group_out(session, accounts.add_group(session, admin, name=body.name, members=body.members))


@router.get("/audit", response_model=list[AuditOut], responses=error_responses(401, 403))
def audit_trail(
    session: SessionDep, _admin: AdminUser, limit: Annotated[int, Query(ge=1, le=5000)] = 200
) -> list[AuditEvent]:
    """Who uploaded, started, cancelled or deleted what, newest first (admin)."""
    return accounts.audit_events(session, limit=limit)
