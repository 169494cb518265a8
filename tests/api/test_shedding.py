"""Load shedding's bound of requests in flight (`backend.shedding`), on an application whose requests the test
holds and lets go: no timing asserted."""

from __future__ import annotations

import asyncio
import json

from backend.shedding import LoadShedding


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
