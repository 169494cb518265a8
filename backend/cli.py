"""The `fringelab` command: `up`, `api`, `worker`, `db upgrade`, `version`, and the science commands.

Every handler returns an exit code. Expected failures (bad settings, Redis or database down, port in use, bad
input) print one line on stderr and exit non-zero, without a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from collections.abc import Sequence

from backend import __version__
from backend.settings import Settings, SettingsError, load_settings

EXPECTED_ERRORS: tuple[type[Exception], ...] = (SettingsError,)


def _fail(message: str) -> int:
    print(f"fringelab: error: {message}", file=sys.stderr)
    return 2


def cmd_version(_args: argparse.Namespace) -> int:
    print(f"fringelab {__version__}")
    return 0


def cmd_db_upgrade(_args: argparse.Namespace) -> int:
    from backend.db import upgrade_database

    settings = load_settings()
    upgrade_database(settings.resolved_database_url)
    print(f"database is up to date: {_safe_url(settings.resolved_database_url)}")
    return 0


def cmd_api(_args: argparse.Namespace) -> int:
    import uvicorn

    from backend.app import create_app
    from backend.db import upgrade_database
    from backend.services import check_port_free, check_redis

    settings = load_settings()
    _require_redis_url(settings)
    check_redis(settings.redis_url)
    check_port_free(settings.host, settings.port)
    upgrade_database(settings.resolved_database_url)
    uvicorn.run(create_app(settings), host=settings.host, port=settings.port, log_level=settings.log_level)
    return 0


def cmd_worker(_args: argparse.Namespace) -> int:
    from backend.services import check_redis
    from worker.celery_app import create_celery

    settings = load_settings()
    _require_redis_url(settings)
    check_redis(settings.redis_url)
    app = create_celery(settings)
    app.worker_main(
        [
            "worker",
            "--pool=prefork",
            f"--concurrency={settings.resolved_worker_concurrency}",
            f"--loglevel={settings.log_level.upper()}",
            f"--hostname=fringelab-{os.getpid()}@%h",
            "--without-mingle",
            "--without-gossip",
        ]
    )
    return 0


def cmd_health(args: argparse.Namespace) -> int:
    if args.url:
        import httpx

        try:
            response = httpx.get(f"{args.url.rstrip('/')}/api/v1/health", timeout=10)
        except httpx.HTTPError as error:
            return _fail(f"no answer from {args.url}: {error}")
        print(response.text)
        return 0 if response.status_code == 200 else 1

    from backend.db import make_engine
    from backend.health import system_health
    from worker.celery_app import create_celery

    settings = load_settings()
    _require_redis_url(settings)
    engine = make_engine(settings.resolved_database_url)
    body = system_health(
        engine=engine,
        redis_url=settings.redis_url,
        celery=create_celery(settings),
        worker_timeout_s=settings.health_worker_timeout_s,
    )
    engine.dispose()
    print(body.model_dump_json())
    return 0 if body.ok else 1


def cmd_up(_args: argparse.Namespace) -> int:
    from backend.supervisor import run_up

    return run_up(load_settings())


def _require_redis_url(settings: Settings) -> None:
    from backend.services import ServiceError

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
    health = commands.add_parser("health", help="check database, Redis and workers; exit 1 when one is down")
    health.add_argument("--url", help="ask a running web server instead (e.g. http://127.0.0.1:8000)")
    health.set_defaults(handler=cmd_health)
    commands.add_parser("version", help="print the version").set_defaults(handler=cmd_version)

    from worker.commands import COMMAND_MODULES

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
    from backend.db import DatabaseError
    from backend.services import ServiceError

    args = build_parser().parse_args(argv)
    try:
        return int(args.handler(args))
    except (SettingsError, ServiceError, DatabaseError) as error:
        return _fail(str(error))
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
