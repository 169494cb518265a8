"""Limits of the web server: a cap on request bodies (413, except on the upload routes, which stream to disk under
their own limit), and a request rate per user (429), shared by all API processes through Redis."""

from __future__ import annotations

import logging
import re
import threading
import time
from collections.abc import Callable

import redis
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from fringelab.core.errors import TooLarge

log = logging.getLogger(__name__)


class BodySizeLimit:
    def __init__(self, app: ASGIApp, *, max_bytes: int, exempt: Callable[[str], bool]) -> None:
        self.app = app
        self.max_bytes = max_bytes
        self.exempt = exempt

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or self.exempt(scope["path"]):
            await self.app(scope, receive, send)
            return
        declared = dict(scope["headers"]).get(b"content-length")
        if declared is not None and declared.isdigit() and int(declared) > self.max_bytes:
            await self._reject(send, scope)
            return
        received = 0
        started = False

        async def counting_receive() -> Message:
            nonlocal received
            message = await receive()
            received += len(message.get("body", b""))
            if received > self.max_bytes:
                raise TooLarge(self._message())
            return message

        async def watching_send(message: Message) -> None:
            nonlocal started
            started = started or message["type"] == "http.response.start"
            await send(message)

        try:
            await self.app(scope, counting_receive, watching_send)
        except TooLarge:
            # A body without Content-Length (chunked) that went over while a middleware or route read it: the
            # same 413 as a declared one, not a 500.
            if started:
                raise
            await self._reject(send, scope)

    def _message(self) -> str:
        return (
            f"request body over {self.max_bytes} bytes (FRINGELAB_MAX_JSON_BYTES); upload recordings and simulations "
            "through their upload routes"
        )

    async def _reject(self, send: Send, scope: Scope) -> None:
        import json

        log.warning("refused %s %s: body over %d bytes", scope["method"], scope["path"], self.max_bytes)
        body = json.dumps({"detail": self._message(), "code": "payload_too_large"}).encode()
        headers = [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode())]
        await send({"type": "http.response.start", "status": 413, "headers": headers})
        await send({"type": "http.response.body", "body": body})


class UserRateLimiter:
    """A token bucket per user in this process: `rate_per_s` requests per second on average, `burst` at once.

    One user's script cannot starve everyone else: beyond its rate it gets a 429 with Retry-After, while other
    users' requests are served. `SharedRateLimiter` keeps the buckets in Redis, for all API processes together,
    and falls back on this one while Redis does not answer.
    """

    MAX_USERS = 100_000

    def __init__(self, *, rate_per_s: float, burst: int) -> None:
        self.rate_per_s = rate_per_s
        self.burst = burst
        self._buckets: dict[object, tuple[float, float]] = {}  # user -> (tokens, at monotonic s)
        self._lock = threading.Lock()

    def take(self, user: object) -> float:
        """Take one request from `user`'s bucket: 0 when allowed, else the seconds until one is."""
        now = time.monotonic()
        with self._lock:
            tokens, at = self._buckets.get(user, (float(self.burst), now))
            tokens = min(float(self.burst), tokens + (now - at) * self.rate_per_s)
            if tokens < 1.0:
                self._buckets[user] = (tokens, now)
                return (1.0 - tokens) / self.rate_per_s
            if len(self._buckets) >= self.MAX_USERS:
                self._buckets.clear()
            self._buckets[user] = (tokens - 1.0, now)
            return 0.0


# KEYS[1]: the user's bucket; ARGV: rate per s, burst, tokens wanted. Returns {tokens granted, seconds to wait}:
# as many of those wanted as the bucket holds (at least 1, else none and the wait until one is, as a string: Redis
# turns Lua numbers into integers). The time is Redis's own, the same for every API process.
_TAKE_SCRIPT = """
local rate = tonumber(ARGV[1])
local burst = tonumber(ARGV[2])
local wanted = tonumber(ARGV[3])
local clock = redis.call('TIME')
local now = tonumber(clock[1]) + tonumber(clock[2]) / 1000000
local bucket = redis.call('HMGET', KEYS[1], 'tokens', 'at')
local tokens = tonumber(bucket[1]) or burst
local at = tonumber(bucket[2]) or now
tokens = math.min(burst, tokens + math.max(0, now - at) * rate)
local granted = 0
local wait = 0
if tokens < 1 then
  wait = (1 - tokens) / rate
else
  granted = math.min(wanted, math.floor(tokens))
  tokens = tokens - granted
end
redis.call('HSET', KEYS[1], 'tokens', tostring(tokens), 'at', tostring(now))
redis.call('EXPIRE', KEYS[1], math.ceil(burst / rate) + 1)
return {granted, tostring(wait)}
"""


def lease_for(burst: int) -> int:
    """Tokens a process takes from a user's shared bucket in one Redis call: 1 (exact) for bursts under 64, then
    a 32nd of the burst, at most 16. What the tokens leased to processes can make a user's count miss by is then
    under a 32nd of the burst per process (see `SharedRateLimiter`)."""
    return max(1, min(SharedRateLimiter.MAX_LEASE, burst // 32))


class SharedRateLimiter:
    """`UserRateLimiter`'s bucket per user, kept in Redis, so that a user's rate is the same whether one API
    process or eight serve them. While Redis does not answer, each process counts on its own (the limit is a
    courtesy to other users, not a security boundary: it must not fail requests).

    A Redis round trip per request was 12 % of the web server's busy samples on issue 26's heavy mix (py-spy), most
    of it a thread waiting for the reply while holding its database connection. A process therefore
    takes a lease of up to `lease` tokens at once (one atomic script call) and spends it locally; a lease unspent
    after LEASE_S is dropped (its tokens stay counted). A refusal is remembered until its wait is over: no request
    can be allowed before then anyway, by any process (they only take tokens), so it is answered without Redis.
    The tolerance this buys, across P processes: a user may get up to P × (lease - 1) requests beyond the bucket
    (tokens leased before a window, spent in it), and may be refused while up to (P - 1) × (lease - 1) tokens sit
    leased in other processes for at most LEASE_S. At the defaults (burst 300, lease 9) that is 8 requests per
    process, under 3 % of the burst, for one Redis call per 9 requests; bursts under 64 lease 1 and are exact.
    """

    KEY_PREFIX = "fringelab:rate:"
    TIMEOUT_S = 0.5
    RETRY_S = 1.0
    MAX_LEASE = 16
    LEASE_S = 1.0  # a lease older than this is dropped: a user who comes back later asks Redis afresh
    MAX_USERS = 100_000

    def __init__(
        self, *, redis_url: str, rate_per_s: float, burst: int, namespace: str = "", lease: int | None = None
    ) -> None:
        """`namespace`: what tells apart the users of different databases sharing one Redis (user ids repeat).
        `lease`: tokens taken per Redis call (default `lease_for(burst)`; 1 asks Redis for every request)."""
        self.key_prefix = f"{self.KEY_PREFIX}{namespace}:" if namespace else self.KEY_PREFIX
        self.rate_per_s = rate_per_s
        self.burst = burst
        self.lease = lease_for(burst) if lease is None else max(1, lease)
        self.local = UserRateLimiter(rate_per_s=rate_per_s, burst=burst)
        self._redis = redis.Redis.from_url(
            redis_url, socket_timeout=self.TIMEOUT_S, socket_connect_timeout=self.TIMEOUT_S
        )
        self._take = self._redis.register_script(_TAKE_SCRIPT)
        self._down_until_s = 0.0
        self._lock = threading.Lock()
        self._leased: dict[object, tuple[int, float]] = {}  # user -> (tokens left, usable until, monotonic s)
        self._refused_until: dict[object, float] = {}  # user -> monotonic s

    def take(self, user: object) -> float:
        """Take one request from `user`'s bucket: 0 when allowed, else the seconds until one is."""
        now = time.monotonic()
        held = self.take_held(user, now)
        if held is not None:
            return held
        if now >= self._down_until_s:
            try:
                granted, wait = self._take(
                    keys=[f"{self.key_prefix}{user}"], args=[self.rate_per_s, self.burst, self.lease]
                )
                return self._record(user, int(granted), float(wait), now)
            except (redis.RedisError, ValueError, TypeError):
                self._down_until_s = time.monotonic() + self.RETRY_S
                logging.getLogger(__name__).warning("request rates counted per process: Redis did not answer")
        return self.local.take(user)

    def take_held(self, user: object, now: float | None = None) -> float | None:
        """`take` when this process can answer alone (from its lease, or a refusal it remembers), asking
        nothing (fit for the event loop); None when it would ask Redis."""
        now = time.monotonic() if now is None else now
        with self._lock:
            left, until = self._leased.get(user, (0, 0.0))
            if left > 0 and now < until:
                self._leased[user] = (left - 1, until)
                return 0.0
            refused_until = self._refused_until.get(user, 0.0)
            if now < refused_until:
                return refused_until - now
        return None

    def _record(self, user: object, granted: int, wait_s: float, asked_at: float) -> float:
        with self._lock:
            if len(self._leased) >= self.MAX_USERS or len(self._refused_until) >= self.MAX_USERS:
                self._leased.clear()
                self._refused_until.clear()
            if granted < 1:
                self._refused_until[user] = asked_at + wait_s
                return wait_s
            self._refused_until.pop(user, None)
            left, until = self._leased.get(user, (0, 0.0))
            left = left if asked_at < until else 0  # another thread's lease, still usable: keep it
            self._leased[user] = (left + granted - 1, asked_at + self.LEASE_S)
            return 0.0


INT64_MAX = (1 << 63) - 1


class _NotPlainJson(ValueError):
    pass


def _refuse_constant(name: str) -> object:
    raise _NotPlainJson(f"{name} is not a JSON number; send finite numbers only")


def _checked_int(text: str) -> int:
    if len(text.lstrip("-")) > 19 or abs(int(text)) > INT64_MAX:
        raise _NotPlainJson(f"the integer {text[:24]}{'…' if len(text) > 24 else ''} is out of range (|n| < 2**63)")
    return int(text)


class PlainJsonNumbers:
    """Refuse (422) a JSON request body holding NaN, Infinity or an integer beyond 64 bits, before any route or
    validator sees it. Python's JSON parser accepts these; a validator then reports them back in its 422, which
    cannot be serialised (500), and a huge integer overflows in the database driver (500). Bodies are capped by
    BodySizeLimit before this runs; upload routes (no JSON) are exempt."""

    def __init__(self, app: ASGIApp, *, exempt: Callable[[str], bool]) -> None:
        self.app = app
        self.exempt = exempt

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        content_type = dict(scope.get("headers", [])).get(b"content-type", b"")
        if scope["type"] != "http" or self.exempt(scope["path"]) or b"json" not in content_type.lower():
            await self.app(scope, receive, send)
            return
        chunks = []
        more = True
        while more:
            message = await receive()
            if message["type"] != "http.request":
                await self.app(scope, _replay([message]), send)
                return
            chunks.append(message.get("body", b""))
            more = message.get("more_body", False)
        body = b"".join(chunks)
        problem = _number_problem(body)
        if problem:
            import json

            code = "invalid_number" if "number" in problem or "integer" in problem else "invalid_input"
            log.warning("refused %s %s: body %s", scope["method"], scope["path"], problem)
            payload = json.dumps({"detail": f"body: {problem}", "code": code}).encode()
            headers = [(b"content-type", b"application/json"), (b"content-length", str(len(payload)).encode())]
            await send({"type": "http.response.start", "status": 422, "headers": headers})
            await send({"type": "http.response.body", "body": payload})
            return
        await self.app(scope, _replay([{"type": "http.request", "body": body, "more_body": False}], then=receive), send)


MAX_JSON_DEPTH = 32
"""Deepest nesting of lists and objects a request body may have (the deepest the API reads is 3)."""


def _number_problem(body: bytes) -> str:
    import json

    try:
        document = json.loads(body, parse_constant=_refuse_constant, parse_int=_checked_int)
    except _NotPlainJson as error:
        return str(error)
    except RecursionError:
        return f"nested deeper than {MAX_JSON_DEPTH} levels"
    except ValueError:
        return ""  # not JSON at all: the route's own validation answers with its 422
    return _shape_problem(document)


def _shape_problem(document: object) -> str:
    """Why a parsed body is refused before any route reads it: nested deeper than MAX_JSON_DEPTH (a 900-deep list
    made a 500 and 311 KB of log), or a string no database can store (a lone surrogate, "\\ud800"; a NUL byte)."""
    from fringelab.core.text import text_problem

    pending: list[tuple[object, int]] = [(document, 1)]
    while pending:
        value, depth = pending.pop()
        if isinstance(value, dict | list):
            if depth > MAX_JSON_DEPTH:
                return f"nested deeper than {MAX_JSON_DEPTH} levels"
            items = list(value.items()) if isinstance(value, dict) else [(None, item) for item in value]
            for key, item in items:
                if key is not None:
                    pending.append((key, depth))
                pending.append((item, depth + 1))
        elif isinstance(value, str) and (problem := _stored_text_problem(value, text_problem)):
            return f"a string {problem}"
    return ""


_UNSTORABLE = re.compile("[\x00\ud800-\udfff]")


def _stored_text_problem(value: str, text_problem: Callable[..., str]) -> str:
    found = _UNSTORABLE.search(value)
    if found is None:
        return ""
    if found.group() == "\x00":
        return "holds a NUL byte (U+0000), which cannot be stored"
    return text_problem(value)


def _replay(messages: list[Message], then: Receive | None = None) -> Receive:
    pending = list(messages)

    async def receive() -> Message:
        if pending:
            return pending.pop(0)
        if then is not None:
            return await then()
        return {"type": "http.disconnect"}

    return receive
