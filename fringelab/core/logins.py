"""The gate every password check passes: attempts counted before the check, and a cap on checks at once.

- Counted first, atomically: one Redis script adds the attempt to its account's and its address's counters and
  returns both, so N concurrent wrong logins get exactly FRINGELAB_LOGIN_MAX_FAILURES checks between them (before,
  the limit was read, the password checked, then the failure counted: 80 at once got 76 checks). A login that
  succeeds takes its attempt back. Addresses are counted by network: all of loopback (127/8, ::1) is one address
  and an IPv6 address counts by its /64, so rotating source addresses gains nothing; and the account's counter
  holds whatever the address.
- At most FRINGELAB_LOGIN_CONCURRENCY checks at once per web server process: an argon2 check takes 64 MiB, so 120
  at once took a process from 131 to 1929 MiB. Beyond the cap a login gets 429 at once, with its attempt taken
  back (it checked nothing). Its default is the server's share: at most MAX_AUTO_CHECKS at once on the whole
  server (256 MiB), split between its web server processes, at least one each.

Without Redis the counters are this process's own (a login still works).
"""

from __future__ import annotations

import hashlib
import ipaddress
import logging
import os
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager

import redis

from fringelab.core.errors import RateLimited
from fringelab.core.settings import Settings

KEY_PREFIX = "fringelab:login-attempts:"
# The memory one argon2 check takes (argon2-cffi's default memory_cost, 64 MiB), what the cap is sized from.
CHECK_BYTES = 64 * 1024 * 1024
# Checks at once on the whole server (all its web server processes) when the cap follows memory: 4 × 64 MiB.
MAX_AUTO_CHECKS = 4

# KEYS: the counters; ARGV[1]: the window in s. Adds one to each (a new counter lives for the window) and returns them.
_COUNT_SCRIPT = """
local counts = {}
for i, key in ipairs(KEYS) do
  local n = redis.call('INCR', key)
  if n == 1 then redis.call('EXPIRE', key, ARGV[1]) end
  counts[i] = n
end
return counts
"""
# KEYS: the counters. Takes one back from each that still exists.
_UNCOUNT_SCRIPT = """
for _, key in ipairs(KEYS) do
  if redis.call('EXISTS', key) == 1 then redis.call('DECR', key) end
end
return 0
"""


def address_key(client: str) -> str:
    """The network a login attempt is counted against: loopback is one, IPv6 by /64, IPv4 as it is."""
    try:
        address = ipaddress.ip_address(client)
    except ValueError:
        return client[:64]
    if address.is_loopback:
        return "loopback"
    if isinstance(address, ipaddress.IPv6Address):
        if address.ipv4_mapped is not None:
            return address_key(str(address.ipv4_mapped))
        return str(ipaddress.ip_network(f"{address}/64", strict=False))
    return str(address)


def auto_concurrency(available_bytes: int, processes: int) -> int:
    """Checks at once for one of `processes` web server processes when FRINGELAB_LOGIN_CONCURRENCY is 0: the
    server's checks, one per 16 checks' worth of available memory (a web server shares the machine with workers
    that need far more) and at most MAX_AUTO_CHECKS, shared between its processes, at least one each. Per process,
    4 each took two processes from 307 to 821 MiB under 120 wrong logins at once (8 checks)."""
    server_checks = max(1, min(MAX_AUTO_CHECKS, available_bytes // (16 * CHECK_BYTES)))
    return max(1, server_checks // max(1, processes))


def _available_bytes() -> int:
    import psutil

    return int(psutil.virtual_memory().available)


class LoginGate:
    def __init__(self, settings: Settings) -> None:
        self.max_attempts = settings.login_max_failures
        self.window_s = settings.login_window_s
        self.concurrency = settings.login_concurrency or auto_concurrency(
            _available_bytes(), settings.resolved_api_processes
        )
        self._checks = threading.BoundedSemaphore(self.concurrency)
        self._redis = (
            redis.Redis.from_url(settings.redis_url, socket_timeout=2, socket_connect_timeout=2)
            if settings.redis_url
            else None
        )
        self._count = self._redis.register_script(_COUNT_SCRIPT) if self._redis else None
        self._uncount = self._redis.register_script(_UNCOUNT_SCRIPT) if self._redis else None
        self._local: dict[str, tuple[int, float]] = {}  # key -> (attempts, window ends at, monotonic s)
        self._local_lock = threading.Lock()

    def _keys(self, client: str, username: str) -> list[str]:
        account = hashlib.sha256(username.strip().lower().encode("utf-8", "replace")).hexdigest()[:32]
        return [f"{KEY_PREFIX}address:{address_key(client)}", f"{KEY_PREFIX}account:{account}"]

    def _add(self, keys: list[str]) -> list[int]:
        if self._count is not None:
            try:
                return [int(n) for n in self._count(keys=keys, args=[self.window_s])]
            except redis.RedisError:
                logging.getLogger(__name__).warning("login attempts counted per process: Redis did not answer")
        now = time.monotonic()
        counts = []
        with self._local_lock:
            if len(self._local) > 100_000:
                self._local = {k: v for k, v in self._local.items() if v[1] > now}
            for key in keys:
                attempts, ends = self._local.get(key, (0, now + self.window_s))
                if ends <= now:
                    attempts, ends = 0, now + self.window_s
                self._local[key] = (attempts + 1, ends)
                counts.append(attempts + 1)
        return counts

    def _take_back(self, keys: list[str]) -> None:
        if self._uncount is not None:
            try:
                self._uncount(keys=keys)
                return
            except redis.RedisError:
                pass
        with self._local_lock:
            for key in keys:
                if key in self._local:
                    attempts, ends = self._local[key]
                    self._local[key] = (max(0, attempts - 1), ends)

    @contextmanager
    def attempt(self, *, client: str, username: str) -> Iterator[Success]:
        """Count a login attempt, then hold one of the process's check slots while the body checks the password;
        RateLimited (429) when the account or the address is over its limit, or every slot is taken. The body
        calls `success()` when the password was right: the attempt is taken back."""
        keys = self._keys(client, username)
        if max(self._add(keys)) > self.max_attempts:
            raise RateLimited(
                f"too many login attempts for this account or from this address; wait {self.window_s} s",
                retry_after_s=self.window_s,
            )
        if not self._checks.acquire(blocking=False):
            self._take_back(keys)
            raise RateLimited("too many logins are being checked at once; retry in a second", retry_after_s=1)
        success = Success()
        try:
            yield success
        finally:
            self._checks.release()
            if success.done:
                self._take_back(keys)


class Success:
    done = False

    def __call__(self) -> None:
        self.done = True


_gates: dict[tuple[int, str, int, int, int], LoginGate] = {}
_gates_lock = threading.Lock()


def login_gate(settings: Settings) -> LoginGate:
    """This process's gate for these settings (one semaphore per process, made on first use)."""
    key = (os.getpid(), settings.redis_url, settings.login_max_failures, settings.login_window_s,
           settings.login_concurrency)  # fmt: skip
    with _gates_lock:
        if key not in _gates:
            _gates[key] = LoginGate(settings)
        return _gates[key]
