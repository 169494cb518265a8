"""Polls of the database shared by the event streams of one API process.

Each open event stream polls the database a few times a second; a hundred viewers of the same job (a lab watching
one test) asked the same question a hundred times. Here the answer to a question (`key`) is fetched once, in a
thread, and given to every stream that asks within `max_age_s`; streams asking while it is being fetched wait
for that fetch instead of starting their own. Answers are shared, never copied: callers must not change them.
Bounded: answers older than a few `max_age_s` are dropped once many keys are kept.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Hashable
from typing import Any, TypeVar

import anyio

T = TypeVar("T")


class SharedPolls:
    PRUNE_ABOVE = 256  # keys kept before old answers are dropped

    def __init__(self, *, max_age_s: float) -> None:
        self.max_age_s = max_age_s
        self._kept: dict[Hashable, tuple[float, Any]] = {}
        self._locks: dict[Hashable, anyio.Lock] = {}
        self.fetches = 0  # how many times the database was asked (the tests count them)

    def _fresh(self, key: Hashable) -> tuple[bool, Any]:
        kept = self._kept.get(key)
        if kept is not None and time.monotonic() - kept[0] < self.max_age_s:
            return True, kept[1]
        return False, None

    async def get(self, key: Hashable, fetch: Callable[[], T]) -> T:
        """The answer to `key`: a shared one at most `max_age_s` old, else `fetch()` run in a thread."""
        fresh, value = self._fresh(key)
        if fresh:
            return value
        lock = self._locks.setdefault(key, anyio.Lock())
        async with lock:
            fresh, value = self._fresh(key)  # another stream fetched it while this one waited
            if fresh:
                return value
            value = await anyio.to_thread.run_sync(fetch)
            self.fetches += 1
            self._kept[key] = (time.monotonic(), value)
        if len(self._locks) > self.PRUNE_ABOVE:
            self._prune()
        return value

    def _prune(self) -> None:
        old = time.monotonic() - 4 * self.max_age_s
        for key in [k for k, (at, _value) in self._kept.items() if at < old]:
            lock = self._locks.get(key)
            if lock is None or not lock.locked():
                self._kept.pop(key, None)
                self._locks.pop(key, None)
        for key in [k for k, lock in self._locks.items() if k not in self._kept and not lock.locked()]:
            del self._locks[key]
