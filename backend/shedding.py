"""Load shedding: a web server process answers 503 with Retry-After at once beyond a bound of requests in flight.

Beyond what its threads can serve (FRINGELAB_API_THREADS busy plus FRINGELAB_API_QUEUE waiting), a request would
only queue behind the others until its client gives up: at 500 requests/s, 60 % of requests waited over 10 s and
none was refused (issue 26). Refused at once, a client (the dashboard, a script) retries after a second, and what
is served is served quickly. The health check (cheap, from a cache), event streams (long-lived, capped per user by
their own rule) and uploads (streamed to disk) are not counted.
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Callable

from starlette.types import ASGIApp, Receive, Scope, Send

log = logging.getLogger(__name__)
RETRY_AFTER_S = 1
LOG_EVERY_S = 10.0


class LoadShedding:
    def __init__(self, app: ASGIApp, *, max_in_flight: int, exempt: Callable[[str], bool]) -> None:
        self.app = app
        self.max_in_flight = max_in_flight
        self.exempt = exempt
        self.in_flight = 0  # one event loop per process: no lock needed
        self.refused = 0
        self._logged_at = 0.0

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or self.exempt(scope["path"]):
            await self.app(scope, receive, send)
            return
        if self.in_flight >= self.max_in_flight:
            await self._refuse(send)
            return
        self.in_flight += 1
        try:
            await self.app(scope, receive, send)
        finally:
            self.in_flight -= 1

    async def _refuse(self, send: Send) -> None:
        self.refused += 1
        now = time.monotonic()
        if now - self._logged_at >= LOG_EVERY_S:  # one line per period, not one per refusal: a flood stays a line
            log.warning("busy: %d requests refused with 503 so far (%d in flight)", self.refused, self.in_flight)
            self._logged_at = now
        body = json.dumps({
            "detail": f"the server is busy ({self.in_flight} requests in progress); retry in {RETRY_AFTER_S} s",
            "code": "busy",
        }).encode()  # fmt: skip
        headers = [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode()),
                   (b"retry-after", str(RETRY_AFTER_S).encode())]  # fmt: skip
        await send({"type": "http.response.start", "status": 503, "headers": headers})
        await send({"type": "http.response.body", "body": body})
