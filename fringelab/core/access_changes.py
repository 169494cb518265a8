"""Access changes shared by every API process through Redis: a revoked token, a disabled account or a changed
role raises the access generation (`announce_access_change`), and each process's `AccessWatch` knows the
current generation without asking Redis on every request.

The rule: a change reaches every process at once. Each process's token cache trusts a checked token only while
the generation is the one it was checked at, so a process must know the current generation whenever it answers.
Asking Redis for it on every request (a GET) was about 9 % of a busy web server's samples, mostly a request
thread waiting for the answer and then for the GIL (issue 26). Instead, one thread per process listens on a
channel: the announcement is published with the new generation, each listener takes it in and then
acknowledges it, and the announcer returns only once every listener has (at most ANNOUNCE_WAIT_S). So a
revocation's own answer (or `fringelab user disable`) comes back only after every process refuses the token.
redis-py's client-side caching would do the listening for us, but it needs Redis 7.4 and `fringelab up` runs
the system's Redis (7.0 here).

Whenever the listener cannot vouch for the generation (not subscribed yet, Redis down, its connection lost), the
generation is unknown (None) and no checked token is trusted. A subscription that died without a word is found
by re-reading the generation every ACCESS_CHECK_S.
"""

from __future__ import annotations

import threading
import time
import weakref
from urllib.parse import urlsplit

import redis
from redis.backoff import NoBackoff
from redis.retry import Retry

ACCESS_GENERATION_KEY = "fringelab:access-generation"
ACCESS_ACKS_KEY = "fringelab:access-acks:{generation}"
ACCESS_ACKS_TTL_S = 60
REDIS_TIMEOUT_S = 0.5
REDIS_RETRY_S = 1.0  # after Redis failed to answer, how long until the listener tries again
ACCESS_CHECK_S = 1.0  # how often a listener re-reads the generation with no message
ANNOUNCE_WAIT_S = 1.0  # how long an announcement waits for the listeners' acknowledgements
ACK_POLL_S = 0.002

# One command: the generation goes up and is published to the listeners, whose count comes back.
_ANNOUNCE = """
local generation = redis.call('INCR', KEYS[1])
return {generation, redis.call('PUBLISH', ARGV[1], generation)}
"""


def access_channel(redis_url: str) -> str:
    """The channel of the generation's database: channels are global to a Redis server, keys are per database."""
    database = urlsplit(redis_url).path.strip("/") or "0"
    return f"fringelab:access-changed:{database}"


def announce_access_change(redis_url: str) -> bool:
    """Tell every API process that a token was revoked or an account changed (the access generation in Redis
    goes up; each process's token cache then asks the database again), and wait until each listening process
    has taken it in (at most ANNOUNCE_WAIT_S). False when Redis could not be reached: the change then reaches
    other processes within FRINGELAB_TOKEN_CACHE_S."""
    if not redis_url:
        return False
    try:
        connection = redis.Redis.from_url(
            redis_url, socket_timeout=REDIS_TIMEOUT_S * 4, socket_connect_timeout=REDIS_TIMEOUT_S * 4
        )
        try:
            generation, listeners = connection.eval(_ANNOUNCE, 1, ACCESS_GENERATION_KEY, access_channel(redis_url))
            acks_key = ACCESS_ACKS_KEY.format(generation=int(generation))
            deadline_s = time.monotonic() + ANNOUNCE_WAIT_S
            while int(connection.get(acks_key) or 0) < int(listeners) and time.monotonic() < deadline_s:
                time.sleep(ACK_POLL_S)
        finally:
            connection.close()
    except redis.RedisError:
        return False
    return True


class AccessWatch:
    """The access generation in Redis as this process knows it (`generation`, None when unknown), kept by a
    listener thread; reading it asks nothing. The thread starts with `start` (or the first `current`) and
    ends with `stop`, or within ACCESS_CHECK_S after the watch is garbage-collected."""

    def __init__(self, redis_url: str) -> None:
        self.redis_url = redis_url
        self.generation: int | None = None
        self._tried = threading.Event()  # the listener's first try is over (subscribed or failed)
        self._stopped = threading.Event()
        self._start_lock = threading.Lock()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        with self._start_lock:
            if self._thread is None:
                self._thread = threading.Thread(
                    target=_listen,
                    args=(weakref.ref(self), self.redis_url, self._tried, self._stopped),
                    name="fringelab-access-watch",
                    daemon=True,
                )
                self._thread.start()

    def current(self) -> int | None:
        """The generation; the first call starts the listener and waits for its first try (bounded)."""
        if self._thread is None:
            self.start()
            self._tried.wait(REDIS_TIMEOUT_S * 2)
        return self.generation

    def stop(self) -> None:
        self._stopped.set()
        self.generation = None


def _listen(
    watch_ref: weakref.ref[AccessWatch], redis_url: str, tried: threading.Event, stopped: threading.Event
) -> None:
    """The listener thread: subscribe, read the generation, then take in each announcement and acknowledge it;
    on any failure the generation is unknown until it has subscribed and read it again."""
    client = redis.Redis.from_url(
        redis_url, socket_timeout=REDIS_TIMEOUT_S, socket_connect_timeout=REDIS_TIMEOUT_S, retry=Retry(NoBackoff(), 0)
    )
    channel = access_channel(redis_url)

    def publish(generation: int | None) -> bool:
        watch = watch_ref()
        if watch is None or stopped.is_set():
            return False
        watch.generation = generation
        return True

    try:
        while not stopped.is_set():
            pubsub = client.pubsub()
            try:
                pubsub.subscribe(channel)
                if pubsub.get_message(timeout=REDIS_TIMEOUT_S) is None:  # the confirmation
                    raise redis.TimeoutError("no confirmation of the subscription")
                # Subscribed: every later change comes as a message, and this read sees every earlier one.
                if not publish(int(client.get(ACCESS_GENERATION_KEY) or 0)):
                    return
                tried.set()
                while True:
                    message = pubsub.get_message(timeout=ACCESS_CHECK_S)
                    if message is None:
                        generation = int(client.get(ACCESS_GENERATION_KEY) or 0)
                    elif message["type"] == "message":
                        generation = int(message["data"])
                    else:
                        continue
                    if not publish(generation):
                        return
                    if message is not None:  # taken in: the announcer may answer now
                        acks_key = ACCESS_ACKS_KEY.format(generation=generation)
                        acknowledge = client.pipeline(transaction=False)
                        acknowledge.incr(acks_key)
                        acknowledge.expire(acks_key, ACCESS_ACKS_TTL_S)
                        acknowledge.execute()
            except (redis.RedisError, ValueError, OSError):
                if not publish(None):
                    return
                tried.set()
                stopped.wait(REDIS_RETRY_S)
            finally:
                pubsub.close()
    finally:
        client.close()
