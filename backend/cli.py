"""The `fringelab` command: `up`, `api`, `worker`, `db upgrade`, `version`, and the science commands.

Every handler returns an exit code. Expected failures (bad settings, Redis or database down, port in use, bad
input) print one line on stderr and exit non-zero, without a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import os
import subprocess
import sys
from collections.abc import Sequence

from backend import __version__
from fringelab.core.settings import Settings, SettingsError, load_settings

EXPECTED_ERRORS: tuple[type[Exception], ...] = (SettingsError,)


def _fail(message: str) -> int:
    print(f"fringelab: error: {message}", file=sys.stderr)
    return 2


def cmd_version(_args: argparse.Namespace) -> int:
    print(f"fringelab {__version__}")
    return 0


def cmd_db_upgrade(_args: argparse.Namespace) -> int:
    from fringelab.core.db import upgrade_database

    settings = load_settings()
    upgrade_database(settings.resolved_database_url)
    print(f"database is up to date: {_safe_url(settings.resolved_database_url)}")
    return 0


def cmd_api(_args: argparse.Namespace) -> int:
    import uvicorn

    from backend.app import uvicorn_options
    from fringelab.core.db import upgrade_database
    from fringelab.core.startup_checks import check_port_free, check_redis

    settings = load_settings()
    require_safe_binding(settings)
    _require_redis_url(settings)
    check_redis(settings.redis_url)
    check_port_free(settings.host, settings.port)
    upgrade_database(settings.resolved_database_url)
    # By import string: each of the FRINGELAB_API_PROCESSES processes builds its own app from the environment
    # (uvicorn's parent holds the port and restarts a process that dies).
    uvicorn.run(
        "backend.app:app_from_env",
        factory=True,
        workers=settings.resolved_api_processes,
        **uvicorn_options(settings),  # type: ignore[arg-type]
    )
    return 0


def cmd_worker(_args: argparse.Namespace) -> int:
    """The worker is its own application (`python -m worker`): this process becomes it, so signals reach it."""
    from fringelab.core.startup_checks import check_redis

    settings = load_settings()
    _require_redis_url(settings)
    check_redis(settings.redis_url, wait_s=settings.worker_redis_wait_s)
    command = [sys.executable, "-m", "worker"]
    if os.name == "posix":
        os.execv(sys.executable, command)
    return subprocess.call(command)


def cmd_health(args: argparse.Namespace) -> int:
    if args.url:
        import httpx

        try:
            response = httpx.get(f"{args.url.rstrip('/')}/api/v1/health", timeout=10)
        except httpx.HTTPError as error:
            return _fail(f"no answer from {args.url}: {error}")
        print(response.text)
        return 0 if response.status_code == 200 else 1

    from backend.health import health_redis_client, system_health
    from fringelab.core.db import make_engine

    settings = load_settings()
    _require_redis_url(settings)
    engine = make_engine(settings.resolved_database_url)
    body = system_health(
        engine=engine,
        redis_client=health_redis_client(settings.redis_url, timeout_s=settings.health_worker_timeout_s),
        redis_url=settings.redis_url,
    )
    engine.dispose()
    print(body.model_dump_json())
    return 0 if body.ok else 1


def cmd_up(_args: argparse.Namespace) -> int:
    from backend.supervisor import run_up

    settings = load_settings()
    require_safe_binding(settings)
    return run_up(settings)


def require_safe_binding(settings: Settings) -> None:
    from fringelab.core.startup_checks import ServiceError

    if not settings.auth_enabled and not settings.binds_loopback_only:
        raise ServiceError(
            f"refusing to serve on {settings.host} with authentication off: anyone on the network could use it; "
            "set FRINGELAB_AUTH_ENABLED=true (and create an admin with `fringelab user add NAME --admin`) "
            "or bind FRINGELAB_HOST=127.0.0.1"
        )


def cmd_user(args: argparse.Namespace) -> int:
    import getpass

    from sqlalchemy import select

    from fringelab.core.accounts import change_user, create_user
    from fringelab.core.db import make_engine, make_sessionmaker, upgrade_database
    from fringelab.core.errors import Conflict
    from fringelab.core.models import User

    settings = load_settings()
    upgrade_database(settings.resolved_database_url)
    sessions = make_sessionmaker(make_engine(settings.resolved_database_url))
    with sessions() as session:
        if args.user_command == "add":
            password = sys.stdin.readline().rstrip("\n") if args.password_stdin else getpass.getpass("Password: ")
            try:
                user = create_user(session, args.username, password, role="admin" if args.admin else "member")
            except ValueError as error:
                return _fail(str(error))
            session.commit()
            print(f"created {user.role} {user.username}")
        elif args.user_command == "list":
            for user in session.scalars(select(User).order_by(User.username)):
                print(f"{user.username}\t{user.role}\t{'disabled' if user.disabled else 'active'}")
        else:
            named = session.scalar(select(User).where(User.username == args.username))
            if named is None:
                return _fail(f"no user {args.username!r}")
            change = {
                "disable": {"disabled": True},
                "enable": {"disabled": False},
                "promote": {"role": "admin"},
                "demote": {"role": "member"},
            }[args.user_command]
            try:
                change_user(session, named, **change)  # type: ignore[arg-type]
            except Conflict as error:
                return _fail(error.detail)
            session.commit()
            print(f"{args.user_command}d {named.username}")
            _announce_access_change(settings)
    return 0


def _announce_access_change(settings: Settings) -> None:
    """Make running API processes drop the tokens they have checked (a disabled account stops at once)."""
    from backend.supervisor import running_redis_url
    from fringelab.core.access_changes import announce_access_change

    if not announce_access_change(running_redis_url(settings)):
        print(
            f"(no running fringelab reached: API processes notice within FRINGELAB_TOKEN_CACHE_S, "
            f"{settings.token_cache_s:g} s)",
            file=sys.stderr,
        )


def cmd_token_create(args: argparse.Namespace) -> int:
    from datetime import timedelta

    from sqlalchemy import select

    from fringelab.core.accounts import issue_token
    from fringelab.core.db import make_engine, make_sessionmaker, upgrade_database
    from fringelab.core.models import User

    settings = load_settings()
    upgrade_database(settings.resolved_database_url)
    sessions = make_sessionmaker(make_engine(settings.resolved_database_url))
    with sessions() as session:
        user = session.scalar(select(User).where(User.username == args.username))
        if user is None or user.disabled:
            return _fail(f"no active user {args.username!r}; add one with `fringelab user add`")
        ttl = timedelta(days=args.days) if args.days else None
        _, secret = issue_token(session, user, name=args.name, kind="api", ttl=ttl)
        session.commit()
    print(secret)
    return 0


def _days(text: str) -> int:
    """A token lifetime in days: 0 (never expires) to 3650; a negative one would make a token already expired."""
    try:
        days = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number of days, got {text!r}") from None
    if not 0 <= days <= 3650:
        raise argparse.ArgumentTypeError(f"expected 0 (never expires) to 3650 days, got {days}")
    return days


def _require_redis_url(settings: Settings) -> None:
    from fringelab.core.startup_checks import ServiceError

    if not settings.redis_url:
        raise ServiceError("FRINGELAB_REDIS_URL is empty; set it, or run `fringelab up` to start Redis too")


def _safe_url(url: str) -> str:
    from sqlalchemy.engine import make_url

    return make_url(url).render_as_string(hide_password=True)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="fringelab", description="Out-of-plane plate deformation from structured light and photogrammetry."
    )
    commands = parser.add_subparsers(title="commands", dest="command", required=True, metavar="COMMAND")
    commands.add_parser("up", help="start Redis, a worker and the web server (the embedded default)").set_defaults(
        handler=cmd_up
    )
    commands.add_parser("api", help="run the web server (API + dashboard)").set_defaults(handler=cmd_api)
    commands.add_parser("worker", help="run a Celery worker (prefork, one process per core)").set_defaults(
        handler=cmd_worker
    )
    db = commands.add_parser("db", help="database maintenance")
    db_commands = db.add_subparsers(dest="db_command", required=True, metavar="DB_COMMAND")
    db_commands.add_parser("upgrade", help="apply the migrations").set_defaults(handler=cmd_db_upgrade)
    user = commands.add_parser("user", help="accounts (admin)")
    user_commands = user.add_subparsers(dest="user_command", required=True, metavar="USER_COMMAND")
    add = user_commands.add_parser("add", help="create an account (asks for the password)")
    add.add_argument("username")
    add.add_argument("--admin", action="store_true", help="give the admin role")
    add.add_argument("--password-stdin", action="store_true", help="read the password from standard input")
    user_commands.add_parser("list", help="list the accounts")
    verbs = (
        ("disable", "disable an account"),
        ("enable", "enable an account"),
        ("promote", "give an account the admin role"),
        ("demote", "make an admin a member (not the last active admin)"),
    )
    for verb, what in verbs:
        user_commands.add_parser(verb, help=what).add_argument("username")
    user.set_defaults(handler=cmd_user)
    token = commands.add_parser("token", help="API tokens for scripts")
    token_commands = token.add_subparsers(dest="token_command", required=True, metavar="TOKEN_COMMAND")
    create = token_commands.add_parser("create", help="create a token for a user and print it")
    create.add_argument("username")
    create.add_argument("--name", default="cli", help="what the token is for")
    create.add_argument("--days", type=_days, default=0, help="days until it expires (0: never)")
    create.set_defaults(handler=cmd_token_create)
    health = commands.add_parser("health", help="check database, Redis and workers; exit 1 when one is down")
    health.add_argument("--url", help="ask a running web server instead (e.g. http://127.0.0.1:8000)")
    health.set_defaults(handler=cmd_health)
    commands.add_parser("version", help="print the version").set_defaults(handler=cmd_version)

    from fringelab.commands import COMMAND_MODULES

    for name in COMMAND_MODULES:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as error:
            if error.name != name:
                raise
            continue
        module.register(commands)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    from fringelab.core.db import DatabaseError
    from fringelab.core.startup_checks import ServiceError

    args = build_parser().parse_args(argv)
    try:
        return int(args.handler(args))
    except (SettingsError, ServiceError, DatabaseError) as error:
        return _fail(str(error))
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
