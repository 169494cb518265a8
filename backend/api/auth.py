"""Login, API tokens, users, groups and the audit trail (`/api/v1/auth`, `/api/v1/users`, ...)."""

from __future__ import annotations

from datetime import timedelta
from typing import Annotated

import redis
from fastapi import APIRouter, Path, Query, Request, Response
from sqlalchemy import select

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
from fringelab.core.accounts import audit, authenticate, change_user, create_user, issue_token, token_digest
from fringelab.core.errors import Conflict, NotFound, RateLimited, Unauthorized
from fringelab.core.models import ApiToken, AuditEvent, Group, GroupMember, User, utcnow

router = APIRouter(tags=["accounts"])


def _count_failure(state: StateDep, client: str) -> int:
    """Failed logins of this client address in the current window (kept in Redis, shared by all API processes)."""
    key = f"fringelab:login-failures:{client}"
    try:
        connection = redis.Redis.from_url(state.settings.redis_url, socket_timeout=2)
        failures = int(connection.incr(key))
        if failures == 1:
            connection.expire(key, state.settings.login_window_s)
        connection.close()
    except redis.RedisError:
        return 0  # no rate limit without Redis; the login itself still works
    return failures


def _failures_so_far(state: StateDep, client: str) -> int:
    try:
        connection = redis.Redis.from_url(state.settings.redis_url, socket_timeout=2)
        value = connection.get(f"fringelab:login-failures:{client}")
        connection.close()
    except redis.RedisError:
        return 0
    return int(value or 0)


@router.post("/auth/login", response_model=Me, responses=error_responses(401, 429))
def login(body: LoginIn, request: Request, response: Response, state: StateDep, session: SessionDep) -> Me:
    """Check a username and password and set the browser's session cookie."""
    client = request.client.host if request.client else "unknown"
    window = state.settings.login_window_s
    if _failures_so_far(state, client) >= state.settings.login_max_failures:
        raise RateLimited(f"too many failed logins from {client}; wait {window} s", retry_after_s=window)
    user = authenticate(session, body.username, body.password)
    if user is None:
        _count_failure(state, client)
        raise Unauthorized("wrong username or password, or the account is disabled")
    ttl = timedelta(hours=state.settings.session_ttl_h)
    _, secret = issue_token(session, user, name="browser session", kind="session", ttl=ttl)
    session.commit()
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
        row = session.scalar(select(ApiToken).where(ApiToken.token_hash == token_digest(secret)))
        if row is not None and row.revoked_at is None:
            row.revoked_at = utcnow()
            session.commit()
            state.tokens.forget()
    response.delete_cookie(SESSION_COOKIE, path="/")


@router.get("/auth/me", response_model=Me, responses=error_responses(401))
def me(principal: CurrentUser, state: StateDep) -> Me:
    """Who the server thinks you are."""
    return Me(username=principal.username, role=principal.role, auth_enabled=state.settings.auth_enabled)


def _own_user(session: SessionDep, principal: CurrentUser) -> User:
    if principal.user_id is None:
        raise Conflict("API tokens need accounts: turn FRINGELAB_AUTH_ENABLED on and log in", code="auth_disabled")
    user = session.get(User, principal.user_id)
    if user is None:
        raise NotFound("user not found")
    return user


@router.get("/auth/tokens", response_model=list[TokenOut], responses=error_responses(401))
def list_tokens(session: SessionDep, principal: CurrentUser) -> list[ApiToken]:
    """Your API tokens (not their secrets)."""
    if principal.user_id is None:
        return []
    rows = session.scalars(
        select(ApiToken).where(ApiToken.user_id == principal.user_id, ApiToken.kind == "api").order_by(ApiToken.id)
    )
    return list(rows)


@router.post("/auth/tokens", response_model=TokenCreated, status_code=201, responses=error_responses(401, 409))
def create_token(body: TokenIn, session: SessionDep, principal: CurrentUser) -> TokenCreated:
    """Create an API token for scripts; the secret is in this response only."""
    user = _own_user(session, principal)
    ttl = timedelta(days=body.expires_in_days) if body.expires_in_days else None
    row, secret = issue_token(session, user, name=body.name, kind="api", ttl=ttl)
    audit(session, principal, "create", "token", row.id, name=body.name)
    session.commit()
    return TokenCreated(**TokenOut.model_validate(row).model_dump(), token=secret)


@router.delete("/auth/tokens/{token_id}", status_code=204, responses=error_responses(401, 404))
def revoke_token(
    token_id: Annotated[int, Path(ge=1, le=MAX_ID)], session: SessionDep, state: StateDep, principal: CurrentUser
) -> None:
    """Revoke one of your tokens; scripts using it get 401 from now on."""
    row = session.get(ApiToken, token_id)
    if row is None or (row.user_id != principal.user_id and not principal.is_admin):
        raise NotFound(f"token {token_id} not found")
    if row.revoked_at is None:
        row.revoked_at = utcnow()
        audit(session, principal, "revoke", "token", token_id)
        session.commit()
        state.tokens.forget()


@router.get("/users", response_model=list[UserOut], responses=error_responses(401, 403))
def list_users(session: SessionDep, _admin: AdminUser) -> list[User]:
    """All accounts (admin)."""
    return list(session.scalars(select(User).order_by(User.username)))


@router.post("/users", response_model=UserOut, status_code=201, responses=error_responses(401, 403, 409))
def add_user(body: UserIn, session: SessionDep, admin: AdminUser) -> User:
    """Create an account (admin)."""
    try:
        user = create_user(session, body.username, body.password, role=body.role)
    except ValueError as error:
        raise Conflict(str(error)) from None
    audit(session, admin, "create", "user", user.id, username=user.username, role=user.role)
    session.commit()
    return user


@router.patch("/users/{user_id}", response_model=UserOut, responses=error_responses(401, 403, 404, 409))
def update_user(
    user_id: Annotated[int, Path(ge=1, le=MAX_ID)],
    body: UserPatch,
    session: SessionDep,
    state: StateDep,
    admin: AdminUser,
) -> User:
    """Change an account's role or disable it (admin); a disabled account's tokens stop working at once."""
    user = session.get(User, user_id)
    if user is None:
        raise NotFound(f"user {user_id} not found")
    changes = body.model_dump(exclude_none=True)
    change_user(session, user, **changes)
    audit(session, admin, "update", "user", user_id, **changes)
    session.commit()
    state.tokens.forget()
    return user


def _group_out(session: SessionDep, group: Group) -> GroupOut:
    names = session.scalars(
        select(User.username).join(GroupMember, GroupMember.user_id == User.id).where(GroupMember.group_id == group.id)
    )
    return GroupOut(id=group.id, name=group.name, members=sorted(names))


@router.get("/groups", response_model=list[GroupOut], responses=error_responses(401))
def list_groups(session: SessionDep, _principal: CurrentUser) -> list[GroupOut]:
    """Groups that experiments can be shared with."""
    return [_group_out(session, group) for group in session.scalars(select(Group).order_by(Group.name))]


@router.post("/groups", response_model=GroupOut, status_code=201, responses=error_responses(401, 403, 409))
def add_group(body: GroupIn, session: SessionDep, admin: AdminUser) -> GroupOut:
    """Create a group with its members (admin)."""
    if session.scalar(select(Group).where(Group.name == body.name)):
        raise Conflict(f"group {body.name!r} exists")
    users = {u.username: u for u in session.scalars(select(User).where(User.username.in_(body.members)))}
    if missing := sorted(set(body.members) - set(users)):
        raise Conflict(f"members: no such user {', '.join(missing)}")
    group = Group(name=body.name)
    session.add(group)
    session.flush()
    session.add_all(GroupMember(group_id=group.id, user_id=user.id) for user in users.values())
    audit(session, admin, "create", "group", group.id, name=body.name, members=body.members)
    session.commit()
    return _group_out(session, group)


@router.get("/audit", response_model=list[AuditOut], responses=error_responses(401, 403))
def audit_trail(
    session: SessionDep, _admin: AdminUser, limit: Annotated[int, Query(ge=1, le=5000)] = 200
) -> list[AuditEvent]:
    """Who uploaded, started, cancelled or deleted what, newest first (admin)."""
    return list(session.scalars(select(AuditEvent).order_by(AuditEvent.id.desc()).limit(limit)))
