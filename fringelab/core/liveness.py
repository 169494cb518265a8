"""Which workers are alive, from their own heartbeats in Redis: each worker's main process refreshes a key with a
short lifetime every few seconds, and whoever asks counts the keys that still exist.

This replaces Celery's broadcast ping in the web server: a ping takes two broker connections from a pool of ten and
waits for replies, so a burst of health requests left every request thread waiting on the pool for good (issue 26).
Counting keys is one bounded Redis round trip. What beats is the worker's main process; a job's own progress has
its heartbeat in the database (`worker.runner`)."""

from __future__ import annotations

import contextlib
import logging
import threading

import redis

WORKER_KEY_PREFIX = "fringelab:worker-alive:"
BEAT_EVERY_S = 2.0
# A worker is taken as gone after this long without a beat: several missed beats, so that a busy machine (a
# topography on every core at niceness 10) does not make a live worker look dead.
BEAT_LIFETIME_S = 15


def beat(client: redis.Redis, name: str) -> None:
    """Say that the worker `name` is alive for the next BEAT_LIFETIME_S."""
    client.set(f"{WORKER_KEY_PREFIX}{name}", "1", ex=BEAT_LIFETIME_S)


def forget(client: redis.Redis, name: str) -> None:
    """A worker that stops says so at once (one that dies is forgotten after BEAT_LIFETIME_S)."""
    client.delete(f"{WORKER_KEY_PREFIX}{name}")


def live_workers(client: redis.Redis) -> list[str]:
    """Names of the workers that have beaten within BEAT_LIFETIME_S (the client's timeouts bound the call)."""
    names = client.scan_iter(match=f"{WORKER_KEY_PREFIX}*", count=1000)
    return sorted(name.decode()[len(WORKER_KEY_PREFIX) :] for name in names)


class Heartbeat:
    """A daemon thread that beats for the worker `name` until `stop`; a Redis that does not answer is logged once
    per outage and tried again at the next beat (the worker itself goes on)."""

    def __init__(self, redis_url: str, name: str) -> None:
        self.name = name
        self._client = redis.Redis.from_url(redis_url, socket_timeout=5, socket_connect_timeout=5)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="fringelab-heartbeat", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def _run(self) -> None:
        failing = False
        while True:
            try:
                beat(self._client, self.name)
                failing = False
            except redis.RedisError:
                if not failing:
                    logging.getLogger(__name__).warning("worker heartbeat: Redis did not answer; trying again")
                failing = True
            if self._stop.wait(BEAT_EVERY_S):
                return

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=BEAT_EVERY_S + 1)
        with contextlib.suppress(redis.RedisError):  # else the key expires by itself
            forget(self._client, self.name)
        self._client.close()
