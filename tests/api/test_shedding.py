"""Load shedding (`backend.shedding`): its bound of requests in flight, on an application whose requests the test
holds and lets go (no timing asserted), and its budget of expected wait, on an application whose requests each
hold a worker thread for a real 50 ms."""

from __future__ import annotations

import asyncio
import json
import os
import signal
import time

import httpx
import pytest

from backend.shedding import LoadShedding
from tests.support import RedisServer


class Held:
    """An ASGI app answering 200 to every request; a request to /held waits until `release` is set."""

    def __init__(self) -> None:
        self.release = asyncio.Event()

    async def __call__(self, scope, receive, send) -> None:  # type: ignore[no-untyped-def]
        if scope["path"] == "/held":
            await self.release.wait()
        await send({"type": "http.response.start", "status": 200, "headers": []})
        await send({"type": "http.response.body", "body": b"{}"})


async def ask(app: LoadShedding, path: str) -> tuple[int, dict[str, str], bytes]:
    answer: dict = {"headers": {}, "body": b""}

    async def receive() -> dict:
        return {"type": "http.request", "body": b"", "more_body": False}

    async def send(message: dict) -> None:
        if message["type"] == "http.response.start":
            answer["status"] = message["status"]
            answer["headers"] = {k.decode(): v.decode() for k, v in message["headers"]}
        else:
            answer["body"] += message.get("body", b"")

    await app({"type": "http", "path": path, "method": "GET", "headers": []}, receive, send)
    return answer["status"], answer["headers"], answer["body"]


def test_beyond_the_bound_a_request_is_answered_503_busy_and_the_health_check_never_is():
    async def scenario() -> None:
        held = Held()
        app = LoadShedding(held, max_in_flight=2, exempt=lambda path: path == "/api/v1/health")
        waiting = [asyncio.create_task(ask(app, "/held")) for _ in range(2)]
        await asyncio.sleep(0)  # both admitted (each runs to its wait)
        assert app.in_flight == 2
        status, headers, body = await ask(app, "/api/v1/jobs")
        assert status == 503 and headers["retry-after"] == "1" and json.loads(body)["code"] == "busy"
        assert (await ask(app, "/api/v1/health"))[0] == 200
        held.release.set()
        assert [s for s, _, _ in await asyncio.gather(*waiting)] == [200, 200]
        assert (await ask(app, "/api/v1/jobs"))[0] == 200 and app.in_flight == 0

    asyncio.run(scenario())


def test_beyond_the_running_bound_requests_wait_their_turn_first_come_first_served():
    """Only `max_running` requests run (hold a thread and a database connection); the others of `max_in_flight`
    wait here, in order, and run as the running ones end."""

    async def scenario() -> None:
        held = Held()
        app = LoadShedding(held, max_in_flight=4, max_running=1, exempt=lambda path: False)
        first = asyncio.create_task(ask(app, "/held"))
        await asyncio.sleep(0)
        finished: list[str] = []

        async def then(name: str) -> int:
            status = (await ask(app, "/quick"))[0]
            finished.append(name)
            return status

        waiting = [asyncio.create_task(then(name)) for name in ("second", "third")]
        await asyncio.sleep(0.01)
        assert (app.in_flight, app.running, finished) == (3, 1, [])  # waiting, not running
        held.release.set()
        assert (await first)[0] == 200 and await asyncio.gather(*waiting) == [200, 200]
        assert finished == ["second", "third"] and (app.in_flight, app.running) == (0, 0)

    asyncio.run(scenario())


def test_a_waiter_that_goes_away_keeps_no_turn():
    """A client that goes away (or a server that stops) while its request waits: the request after it runs in
    its place, and the counts come back to zero."""

    async def scenario() -> None:
        held = Held()
        app = LoadShedding(held, max_in_flight=5, max_running=1, exempt=lambda path: False)
        first = asyncio.create_task(ask(app, "/held"))
        await asyncio.sleep(0)
        gone = asyncio.create_task(ask(app, "/quick"))
        waiter = asyncio.create_task(ask(app, "/quick"))
        await asyncio.sleep(0.01)
        gone.cancel()
        await asyncio.gather(gone, return_exceptions=True)
        assert (app.in_flight, app.running) == (2, 1)
        held.release.set()
        assert (await first)[0] == 200 and (await waiter)[0] == 200
        assert (app.in_flight, app.running) == (0, 0)
        assert (await ask(app, "/quick"))[0] == 200 and app.running == 0

    asyncio.run(scenario())


@pytest.mark.integration
def test_a_refusal_asks_neither_redis_nor_the_database(settings, tmp_path):
    """The whole application, accounts on, its bound (4) taken by requests whose bodies have not arrived: with
    its Redis stopped (SIGSTOP: a call would hang until its timeout, 0.5 s) a fifth request with a token is
    answered 503 busy at once, and no database connection is checked out for it."""
    from sqlalchemy import event

    from backend.app import create_app
    from fringelab.core.accounts import create_user, issue_token
    from fringelab.core.db import make_engine, make_sessionmaker

    own_redis = RedisServer(tmp_path)
    own_redis.start()
    limited = settings.model_copy(update={"redis_url": own_redis.url, "auth_enabled": True, "api_threads": 4,
                                          "api_queue": 0})  # fmt: skip
    assert limited.resolved_api_in_flight == 4
    with make_sessionmaker(make_engine(limited.resolved_database_url))() as session:
        _row, secret = issue_token(session, create_user(session, "ada", "ada-password"))
        session.commit()
    app = create_app(limited)
    checkouts: list[object] = []
    event.listen(app.state.fringelab.engine, "checkout", lambda *_args: checkouts.append(1))
    token = {"Authorization": f"Bearer {secret}"}

    async def scenario() -> tuple[int, str, float, int]:
        arrive = asyncio.Event()

        async def late_body():  # type: ignore[no-untyped-def]
            await arrive.wait()
            yield b'{"name": "late"}'

        transport = httpx.ASGITransport(app=app)
        async with httpx.AsyncClient(transport=transport, base_url="http://testserver", timeout=30) as client:
            held = [
                asyncio.create_task(
                    client.post(
                        "/api/v1/experiments",
                        content=late_body(),
                        headers={**token, "content-type": "application/json"},
                    )
                )  # fmt: skip
                for _ in range(4)
            ]
            await asyncio.sleep(0.2)  # all four admitted, each waiting for its body
            before = len(checkouts)
            os.kill(own_redis.process.pid, signal.SIGSTOP)  # type: ignore[union-attr]
            try:
                started = time.perf_counter()
                answer = await client.get("/api/v1/jobs", headers=token)
                took_s = time.perf_counter() - started
                checked_out = len(checkouts) - before
            finally:
                os.kill(own_redis.process.pid, signal.SIGCONT)  # type: ignore[union-attr]
            arrive.set()
            await asyncio.gather(*held)
            return answer.status_code, answer.headers.get("retry-after", ""), took_s, checked_out

    try:
        status, retry_after, took_s, checked_out = asyncio.run(scenario())
    finally:
        own_redis.stop()
    assert (status, retry_after, checked_out) == (503, "1", 0)
    assert took_s < 0.25  # microseconds of work; any Redis call would have hung for its 0.5 s timeout


def test_a_refused_request_writes_no_access_line_of_its_own(caplog):
    """uvicorn formats and writes its access line before the answer's first byte: for a refusal that is one line
    per request of a flood. `QuietRefusals` drops those (the middleware logs refusals once per period); the
    lines of the requests that ran are kept. Each request runs in a task of its own, as under uvicorn."""
    import logging

    from backend.shedding import QUIET_REFUSALS

    access = logging.getLogger("uvicorn.access")
    access.addFilter(QUIET_REFUSALS)

    async def scenario() -> list[int]:
        held = Held()
        app = LoadShedding(held, max_in_flight=1, exempt=lambda path: False)

        async def logged(path: str) -> int:
            statuses: list[int] = []

            async def send(message: dict) -> None:  # as uvicorn's: the access line, then the status line
                if message["type"] == "http.response.start":
                    access.info('"GET %s" %d', path, message["status"])
                    statuses.append(message["status"])

            async def receive() -> dict:
                return {"type": "http.request", "body": b"", "more_body": False}

            await app({"type": "http", "path": path, "method": "GET", "headers": []}, receive, send)
            return statuses[0]

        first = asyncio.create_task(logged("/held"))
        await asyncio.sleep(0)
        refused = await asyncio.create_task(logged("/refused"))
        held.release.set()
        return [await first, refused, await asyncio.create_task(logged("/after"))]

    try:
        with caplog.at_level(logging.INFO, logger="uvicorn.access"):
            assert asyncio.run(scenario()) == [200, 503, 200]
    finally:
        access.removeFilter(QUIET_REFUSALS)
    lines = [r.getMessage() for r in caplog.records if r.name == "uvicorn.access"]
    assert lines == ['"GET /held" 200', '"GET /after" 200']


@pytest.mark.integration
def test_a_served_process_freezes_what_its_start_made_out_of_the_garbage_collectors_way(settings):
    """A full garbage collection walks every tracked object holding the GIL: in a web server process ~200,000 from
    its start, which took 400-940 ms under load, an event-loop stall in which no request (no 503 either) was
    answered. A served process (`openapi_at_start`) freezes them once started, so the collector walks only what
    requests made since."""
    import gc

    from starlette.testclient import TestClient

    from backend.app import create_app

    gc.collect()
    try:
        with TestClient(create_app(settings, openapi_at_start=True)) as client:
            assert client.get("/api/v1/experiments").status_code == 200
            frozen, tracked = gc.get_freeze_count(), len(gc.get_objects())
    finally:
        gc.unfreeze()  # this test process's objects back to the collector
    assert frozen > 100_000 and tracked < frozen / 10, (frozen, tracked)
