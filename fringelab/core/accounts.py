"""Users, passwords, tokens and access to experiments.

With auth off (the laptop default) every request acts as the built-in local admin. With auth on, a request
carries a bearer token (`Authorization: Bearer flb_...`, for scripts) or the browser's session cookie; both are
rows of `api_tokens`, of which only the SHA-256 is stored. Access to anything inside an experiment follows the
experiment: its owner and admins may do everything, members of its group may read (or write, if granted);
everyone else gets a 404, as if it did not exist.
"""

from __future__ import annotations

import functools
import hashlib
import re
import secrets
import threading
import time
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from typing import Any, Literal

from argon2 import PasswordHasher
from argon2.exceptions import InvalidHashError, VerificationError
from sqlalchemy import ColumnElement, or_, select, true, update
from sqlalchemy.orm import Session, sessionmaker

from fringelab.core.access_changes import AccessWatch, announce_access_change
from fringelab.core.errors import Conflict, Forbidden, NotFound, Unauthorized
from fringelab.core.models import ApiToken, AuditEvent, Experiment, Group, GroupMember, User, utcnow
from fringelab.core.settings import Settings

TOKEN_PREFIX = "flb_"
USERNAME_PATTERN = re.compile(r"^[a-z0-9][a-z0-9._-]{1,63}$")
MIN_PASSWORD_LENGTH = 8
ROLES = ("admin", "member")
_hasher = PasswordHasher()


class AuthError(Exception):
    """Authentication failed; the message says why (missing, unknown, expired, revoked token; disabled user)."""


@dataclass(frozen=True)
class Principal:
    """Who is asking: a user, or the built-in local admin when auth is off."""

    user_id: int | None
    username: str
    role: str

    @property
    def is_admin(self) -> bool:
        return self.role == "admin"


LOCAL_ADMIN = Principal(user_id=None, username="local", role="admin")


def hash_password(password: str) -> str:
    return _hasher.hash(password)


@functools.cache
def dummy_hash() -> str:
    """What an unknown user's password is checked against: made once per process, not at import (a hash costs a
    quarter of a second, which every command paid at start); the web server makes it in the background as it
    starts, so that not even its first login tells names apart by time."""
    return _hasher.hash(secrets.token_urlsafe(16))


def authenticate(session: Session, username: str, password: str) -> User | None:
    """The active user with this username and password, or None. Takes one password check whether or not the
    user exists (an unknown name is checked against a dummy hash), so the time does not tell names apart."""
    user = session.scalar(select(User).where(User.username == username))
    matches = verify_password(user.password_hash if user else dummy_hash(), password)
    return user if user is not None and matches and not user.disabled else None


def change_user(session: Session, user: User, *, role: str | None = None, disabled: bool | None = None) -> None:
    """Change an account's role or state (not committed). The last active admin can be neither demoted nor
    disabled, by anyone including itself: a lab server without an admin could not be administered any more."""
    if role is not None and role not in ROLES:
        raise ValueError(f"role: expected one of {', '.join(ROLES)}, got {role!r}")
    loses_admin = user.role == "admin" and not user.disabled and (role == "member" or disabled is True)
    if loses_admin:
        others = session.scalars(
            select(User.id).where(User.role == "admin", User.disabled.is_(False), User.id != user.id)
        ).first()
        if others is None:
            raise Conflict(
                f"{user.username} is the last active admin; promote another account first "
                "(`fringelab user promote NAME`)",
                code="last_admin",
            )
    if role is not None:
        user.role = role
    if disabled is not None:
        user.disabled = disabled


def verify_password(password_hash: str, password: str) -> bool:
    try:
        return _hasher.verify(password_hash, password)
    except (VerificationError, InvalidHashError):
        return False


def token_digest(token: str) -> str:
    return hashlib.sha256(token.encode()).hexdigest()


def create_user(session: Session, username: str, password: str, *, role: str = "member") -> User:
    """Validate and add a user (not committed). Raises ValueError naming the problem."""
    if not USERNAME_PATTERN.match(username):
        raise ValueError("username: 2-64 characters, lower-case letters, digits, '.', '_' or '-'")
    if len(password) < MIN_PASSWORD_LENGTH:
        raise ValueError(f"password: at least {MIN_PASSWORD_LENGTH} characters")
    if role not in ROLES:
        raise ValueError(f"role: expected one of {', '.join(ROLES)}, got {role!r}")
    if session.scalar(select(User).where(User.username == username)):
        raise ValueError(f"username: {username!r} is taken")
    user = User(username=username, password_hash=hash_password(password), role=role)
    session.add(user)
    session.flush()
    return user


def issue_token(
    session: Session, user: User, *, name: str = "", kind: str = "api", ttl: timedelta | None = None
) -> tuple[ApiToken, str]:
    """A new token for `user` (not committed); the secret is returned once and never stored."""
    secret = TOKEN_PREFIX + secrets.token_urlsafe(32)
    row = ApiToken(
        user_id=user.id,
        name=name,
        kind=kind,
        token_hash=token_digest(secret),
        prefix=secret[:10],
        expires_at=(utcnow() + ttl) if ttl else None,
    )
    session.add(row)
    session.flush()
    return row, secret


def _aware(moment: datetime) -> datetime:
    return moment if moment.tzinfo else moment.replace(tzinfo=UTC)  # SQLite returns naive datetimes


def resolve_token(session: Session, secret: str) -> Principal:
    """Who a token belongs to, read from the database (no write: last uses are recorded by `TokenCache`)."""
    return _lookup_token(session, secret)[0]


def _lookup_token(session: Session, secret: str) -> tuple[Principal, int, datetime | None]:
    row = session.scalar(select(ApiToken).where(ApiToken.token_hash == token_digest(secret)))
    if row is None:
        raise AuthError("unknown token; create one in the dashboard or with `fringelab token create`")
    if row.revoked_at is not None:
        raise AuthError("this token was revoked; create a new one")
    if row.expires_at is not None and _aware(row.expires_at) <= utcnow():
        raise AuthError("this token has expired; log in again or create a new token")
    user = session.get(User, row.user_id)
    if user is None or user.disabled:
        raise AuthError("this account is disabled; ask an admin")
    expires_at = _aware(row.expires_at) if row.expires_at is not None else None
    return Principal(user_id=user.id, username=user.username, role=user.role), row.id, expires_at


@dataclass(frozen=True)
class _Known:
    principal: Principal | None
    error: str
    token_id: int
    expires_at: datetime | None
    checked_at_s: float
    generation: int | None  # the access generation when it was checked (None: unknown, never trusted)


class TokenCache:
    """Tokens this API process has checked, trusted for `ttl_s` seconds without asking the database again.

    Authentication is on every request: a database read (and, before, a write of `last_used_at`) each time
    made 200 requests/s exhaust the connection pool. Here a token costs one read per `ttl_s`; refusals are
    remembered as well (a flood of bad tokens costs no more). `last_used_at` is kept in memory and written by
    `flush_last_used` in one transaction (the API calls it every few seconds and at shutdown).

    Several API processes each keep a cache. A revocation, a disabled account or a changed role calls `forget()`,
    which empties this cache and raises the access generation in Redis (`announce_access_change`, also what the
    `fringelab user` commands call); each process knows the generation from a listener (`AccessWatch`, no Redis
    call per request), and the announcement returns once every process has taken it in, so a revoked token is
    refused by all of them at once. While Redis does not answer, no checked token is trusted: each request asks
    the database.
    """

    MAX_ENTRIES = 10_000

    def __init__(self, ttl_s: float, *, redis_url: str = "") -> None:
        self.ttl_s = ttl_s
        self.redis_url = redis_url
        self._known: dict[str, _Known] = {}
        self._last_used: dict[int, datetime] = {}
        self._lock = threading.Lock()
        self._generation: int | None = None
        self.watch = AccessWatch(redis_url) if redis_url else None

    def resolve(self, sessions: sessionmaker[Session], secret: str) -> Principal:
        generation = self.watch.current() if self.watch is not None else 0
        principal = self._trusted(secret, generation)
        if principal is not None:
            return principal
        now_s = time.monotonic()
        with sessions() as session:
            try:
                principal, token_id, expires_at = _lookup_token(session, secret)
                known = _Known(principal, "", token_id, expires_at, now_s, generation)
            except AuthError as error:
                known = _Known(None, str(error), 0, None, now_s, generation)
        with self._lock:
            if len(self._known) >= self.MAX_ENTRIES:
                self._known.clear()
            self._known[token_digest(secret)] = known
        return self._used(known)

    def cached(self, secret: str) -> Principal | None:
        """What `resolve` answers when it need not ask anything (no database, no Redis, no waiting: fit for the
        event loop); None when the token must be checked first."""
        if self.watch is None:
            return self._trusted(secret, 0)
        generation = self.watch.generation
        return None if generation is None else self._trusted(secret, generation)

    def _trusted(self, secret: str, generation: int | None) -> Principal | None:
        """The principal of a token checked within `ttl_s` at this access generation (AuthError for a token
        refused likewise); None when it must be checked again."""
        if generation is not None and generation != self._generation:
            with self._lock:  # entries of older generations are never trusted again: free them
                self._known.clear()
                self._generation = generation
        known = self._known.get(token_digest(secret))
        if (
            known is None
            or generation is None
            or known.generation != generation
            or time.monotonic() - known.checked_at_s >= self.ttl_s
        ):
            return None
        return self._used(known)

    def _used(self, known: _Known) -> Principal:
        if known.principal is None:
            raise AuthError(known.error)
        now = utcnow()
        if known.expires_at is not None and known.expires_at <= now:
            raise AuthError("this token has expired; log in again or create a new token")
        with self._lock:
            self._last_used[known.token_id] = now
        return known.principal

    def forget(self) -> None:
        """Drop every checked token, here and in every other API process (after a revocation, a disabled user,
        a role change)."""
        with self._lock:
            self._known.clear()
        announce_access_change(self.redis_url)

    def flush_last_used(self, sessions: sessionmaker[Session]) -> int:
        """Write the last uses seen since the previous flush; returns how many tokens were written."""
        with self._lock:
            pending, self._last_used = self._last_used, {}
        if not pending:
            return 0
        with sessions() as session:
            for token_id, moment in pending.items():
                session.execute(update(ApiToken).where(ApiToken.id == token_id).values(last_used_at=moment))
            session.commit()
        return len(pending)


def readable_experiments(session: Session, principal: Principal) -> ColumnElement[bool]:
    """A WHERE clause selecting the experiments `principal` may read."""
    if principal.is_admin:
        return true()
    groups = select(GroupMember.group_id).where(GroupMember.user_id == principal.user_id)
    return or_(Experiment.owner_id == principal.user_id, Experiment.group_id.in_(groups))


Access = Literal["admin", "owner", "write", "read"]


def access_level(session: Session, principal: Principal, experiment: Experiment) -> Access | None:
    """What `principal` may do with `experiment`: everything (admin, owner), write or read (its group), or nothing."""
    if principal.is_admin:
        return "admin"
    if experiment.owner_id is not None and experiment.owner_id == principal.user_id:
        return "owner"
    if experiment.group_id is None or session.get(GroupMember, (experiment.group_id, principal.user_id)) is None:
        return None
    return "write" if experiment.group_access == "write" else "read"


def can_access(session: Session, principal: Principal, experiment: Experiment, *, write: bool) -> bool:
    level = access_level(session, principal, experiment)
    return level is not None and (level != "read" or not write)


def require_access(session: Session, principal: Principal, experiment: Experiment, *, write: bool, what: str) -> None:
    """Pass when `principal` may read `experiment` (or write it). Someone without access learns nothing: a 404
    naming `what` (the object asked for), exactly as for an id that does not exist. A group member with read
    access who tries to change something gets a 403 instead: they can see it, so hiding it would only confuse."""
    level = access_level(session, principal, experiment)
    if level is None:
        raise NotFound(f"{what} not found")
    if write and level == "read":
        raise Forbidden(
            f"read-only access: experiment {experiment.id} is shared with your group for reading; "
            "ask its owner for write access",
            code="read_only",
        )


def audit(
    session: Session, principal: Principal, action: str, object_type: str, object_id: object, **detail: Any
) -> None:
    """Record who did what (not committed: it commits with the change it describes)."""
    session.add(
        AuditEvent(
            user_id=principal.user_id,
            username=principal.username,
            action=action,
            object_type=object_type,
            object_id=str(object_id),
            detail=detail,
        )
    )


# ---------------------------------------------------------------------------------------------- logins


def log_in(
    session: Session, settings: Settings, *, client: str, username: str, password: str
) -> tuple[User, str, timedelta]:
    """Check a username and password from `client` (an address) and open a browser session: the user, the session
    token's secret and its lifetime (committed). The attempt is counted before the check, per account and per
    address, and the check waits for no one (`fringelab.core.logins`): RateLimited over either limit or while
    every check slot of this process is taken."""
    from fringelab.core.logins import login_gate

    with login_gate(settings).attempt(client=client, username=username) as success:
        user = authenticate(session, username, password)  # as long for an unknown name as for a known one
        if user is None:
            raise Unauthorized("wrong username or password, or the account is disabled")
        success()
    ttl = timedelta(hours=settings.session_ttl_h)
    _, secret = issue_token(session, user, name="browser session", kind="session", ttl=ttl)
    session.commit()
    return user, secret, ttl


def log_out(session: Session, secret: str) -> None:
    """Revoke the browser session whose token this is (nothing if it is unknown or already revoked)."""
    row = session.scalar(select(ApiToken).where(ApiToken.token_hash == token_digest(secret)))
    if row is not None and row.revoked_at is None:
        row.revoked_at = utcnow()
        session.commit()


# ---------------------------------------------------------------------------------------------- tokens


def _own_user(session: Session, principal: Principal) -> User:
    if principal.user_id is None:
        raise Conflict("API tokens need accounts: turn FRINGELAB_AUTH_ENABLED on and log in", code="auth_disabled")
    user = session.get(User, principal.user_id)
    if user is None:
        raise NotFound("user not found")
    return user


def api_tokens_of(session: Session, principal: Principal) -> list[ApiToken]:
    """The caller's API tokens (not browser sessions), oldest first."""
    if principal.user_id is None:
        return []
    query = select(ApiToken).where(ApiToken.user_id == principal.user_id, ApiToken.kind == "api")
    return list(session.scalars(query.order_by(ApiToken.id)))


def create_api_token(
    session: Session, principal: Principal, *, name: str, expires_in_days: int | None
) -> tuple[ApiToken, str]:
    """A new API token of the caller (committed); its secret is returned once."""
    user = _own_user(session, principal)
    ttl = timedelta(days=expires_in_days) if expires_in_days else None
    row, secret = issue_token(session, user, name=name, kind="api", ttl=ttl)
    audit(session, principal, "create", "token", row.id, name=name)
    session.commit()
    return row, secret


def revoke_token(session: Session, principal: Principal, token_id: int) -> None:
    """Revoke one of the caller's tokens (an admin: anyone's); scripts using it are refused from now on."""
    row = session.get(ApiToken, token_id)
    if row is None or (row.user_id != principal.user_id and not principal.is_admin):
        raise NotFound(f"token {token_id} not found")
    if row.revoked_at is None:
        row.revoked_at = utcnow()
        audit(session, principal, "revoke", "token", token_id)
        session.commit()


# ---------------------------------------------------------------------------------------------- users, groups


def all_users(session: Session) -> list[User]:
    return list(session.scalars(select(User).order_by(User.username)))


def add_user(session: Session, admin: Principal, *, username: str, password: str, role: str) -> User:
    """Create an account (committed); Conflict for a taken or invalid name."""
    try:
        user = create_user(session, username, password, role=role)
    except ValueError as error:
        raise Conflict(str(error)) from None
    audit(session, admin, "create", "user", user.id, username=user.username, role=user.role)
    session.commit()
    return user


def update_user(session: Session, admin: Principal, user_id: int, changes: dict[str, Any]) -> User:
    """Change an account's role or disable it (committed); a disabled account's tokens stop working at once."""
    user = session.get(User, user_id)
    if user is None:
        raise NotFound(f"user {user_id} not found")
    change_user(session, user, **changes)
    audit(session, admin, "update", "user", user_id, **changes)
    session.commit()
    return user


def group_members(session: Session, group: Group) -> list[str]:
    """Usernames of a group's members, sorted."""
    query = select(User.username).join(GroupMember, GroupMember.user_id == User.id)
    return sorted(session.scalars(query.where(GroupMember.group_id == group.id)))


def all_groups(session: Session) -> list[Group]:
    return list(session.scalars(select(Group).order_by(Group.name)))


def add_group(session: Session, admin: Principal, *, name: str, members: list[str]) -> Group:
    """Create a group with its members (committed); Conflict for a taken name or an unknown member."""
    if session.scalar(select(Group).where(Group.name == name)):
        raise Conflict(f"group {name!r} exists")
    users = {u.username: u for u in session.scalars(select(User).where(User.username.in_(members)))}
    if missing := sorted(set(members) - set(users)):
        raise Conflict(f"members: no such user {', '.join(missing)}")
    group = Group(name=name)
    session.add(group)
    session.flush()
    session.add_all(GroupMember(group_id=group.id, user_id=user.id) for user in users.values())
    audit(session, admin, "create", "group", group.id, name=name, members=members)
    session.commit()
    return group


def audit_events(session: Session, *, limit: int) -> list[AuditEvent]:
    """The audit trail, newest first."""
    return list(session.scalars(select(AuditEvent).order_by(AuditEvent.id.desc()).limit(limit)))
