"""Load shedding: a web server process runs a bounded number of requests at once, lets requests wait for their
turn while their count stays within a bound, and answers 503 with Retry-After at once beyond.

Beyond what its threads can serve, a request would only queue behind the others until its client gives up: at 500
requests/s, 60 % of requests waited over 10 s and none was refused (issue 26). Refused at once, a client (the
dashboard, a script) retries after a second, and what is served is served quickly. The decision is made here, the
outermost middleware, on the event loop: before routing, authentication, the database, Redis or any thread, so
that a refusal costs no more than writing it. The health check (cheap, from a cache), event streams (long-lived,
capped per user by their own rule) and uploads (streamed to disk) are not counted.

Only the requests that run (at most `max_running`, the process's threads) hold a thread and a database connection;
those waiting for their turn here hold neither, first come first served. So the number a process takes at once
(`max_in_flight`, a burst of connections) is not bound by its database connections. Waiters are never refused
after waiting: a 503 after a wait is a slow one (expiring waiters at 500 ms made the 503s' p99 387 -> 1349 ms,
issue 26); refusing newcomers behind a queue older than a bound did not make what was served quicker either.

Admission by expected wait (refusing a newcomer whose (waiting ahead + 1) / running slots × an estimated service
time exceeded a budget) was built and measured in issue 26 and removed: it served fewer and no quicker
(docs/server-load.md).
"""

from __future__ import annotations

import asyncio
import contextvars
import json
import logging
import time
from collections.abc import Callable

from starlette.types import ASGIApp, Receive, Scope, Send

log = logging.getLogger(__name__)
RETRY_AFTER_S = 1
LOG_EVERY_S = 10.0

# Set in the task of a request being refused: `QuietRefusals` drops uvicorn's access line for it (a flood of
# refusals is one line per LOG_EVERY_S, not a formatted and written line each before its answer goes out).
_refusing: contextvars.ContextVar[bool] = contextvars.ContextVar("fringelab_refusing", default=False)


class QuietRefusals(logging.Filter):
    """For the "uvicorn.access" logger: no line per refused request (`LoadShedding` logs them per period)."""

    def filter(self, record: logging.LogRecord) -> bool:
        return not _refusing.get()


QUIET_REFUSALS = QuietRefusals()


class LoadShedding:
    def __init__(
        self,
        app: ASGIApp,
        *,
        max_in_flight: int,
        exempt: Callable[[str], bool],
        max_running: int | None = None,
    ) -> None:
        """`max_in_flight`: requests taken at once, running and waiting; `max_running`: of them, running at once
        (default: all)."""
        self.app = app
        self.max_in_flight = max_in_flight
        self.max_running = max_in_flight if max_running is None else min(max_running, max_in_flight)
        self.exempt = exempt
        self.in_flight = 0  # one event loop per process: no lock needed
        self.running = 0
        self._turns: asyncio.Semaphore | None = None  # of the event loop in `_turns_loop`
        self._turns_loop: asyncio.AbstractEventLoop | None = None
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
            # First come first served (a newcomer never passes a waiter); a waiter that goes away keeps no turn.
            async with self._turns_of_this_loop():
                self.running += 1
                try:
                    await self.app(scope, receive, send)
                finally:
                    self.running -= 1
        finally:
            self.in_flight -= 1

    def _turns_of_this_loop(self) -> asyncio.Semaphore:
        """A semaphore belongs to the event loop it first waited in: a server has one, tests may run several."""
        loop = asyncio.get_running_loop()
        if self._turns is None or self._turns_loop is not loop:
            self._turns, self._turns_loop = asyncio.Semaphore(self.max_running), loop
        return self._turns

    async def _refuse(self, send: Send) -> None:
        self.refused += 1
        _refusing.set(True)  # this request's own task: its access line only
        now = time.monotonic()
        if now - self._logged_at >= LOG_EVERY_S:  # one line per period, not one per refusal: a flood stays a line
            log.warning("busy: %d requests refused with 503 so far (%d in flight, %d running)",
                        self.refused, self.in_flight, self.running)  # fmt: skip
            self._logged_at = now
        body = json.dumps({
            "detail": f"the server is busy ({self.in_flight} requests in progress); retry in {RETRY_AFTER_S} s",
            "code": "busy",
        }).encode()  # fmt: skip
        headers = [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode()),
                   (b"retry-after", str(RETRY_AFTER_S).encode())]  # fmt: skip
        await send({"type": "http.response.start", "status": 503, "headers": headers})
        await send({"type": "http.response.body", "body": body})
