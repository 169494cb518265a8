"""A cap on the event streams one user holds open in a web server process (FRINGELAB_EVENT_STREAMS_PER_USER).

Each open stream polls (shared per process, but still a wake-up every 0.25 s and a thread hop per access check):
one member held 965 streams at once, 40 % of a core (issue 26). A dashboard needs a few (the jobs list and the
jobs it shows); beyond the cap a new stream gets 429 with Retry-After, and the others go on.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Iterator
from contextlib import contextmanager

from fringelab.core.errors import RateLimited

# A slot whose stream never started (its client went away between the check and the first event) is forgotten
# after this long; a stream that runs longer keeps its slot until it ends.
FORGOTTEN_AFTER_S = 6 * 3600.0


class StreamSlots:
    def __init__(self, *, per_user: int) -> None:
        self.per_user = per_user
        self._open: dict[object, dict[int, float]] = {}
        self._ids = itertools.count()

    def take(self, user: object, *, name: str) -> int:
        """A slot for one more stream of `user`, or RateLimited (429) when they hold `per_user` already."""
        now = time.monotonic()
        held = self._open.setdefault(user, {})
        for slot, since in list(held.items()):
            if now - since > FORGOTTEN_AFTER_S:
                del held[slot]
        if len(held) >= self.per_user:
            raise RateLimited(
                f"{name} holds {len(held)} event streams open on this server process, the most one user may "
                "(FRINGELAB_EVENT_STREAMS_PER_USER); close some pages or tabs",
                retry_after_s=5,
            )
        slot = next(self._ids)
        held[slot] = now
        return slot

    def give_back(self, user: object, slot: int) -> None:
        held = self._open.get(user, {})
        held.pop(slot, None)
        if not held:
            self._open.pop(user, None)

    @contextmanager
    def held(self, user: object, slot: int) -> Iterator[None]:
        """While the stream runs: its slot is given back when it ends, however it ends."""
        try:
            yield
        finally:
            self.give_back(user, slot)
