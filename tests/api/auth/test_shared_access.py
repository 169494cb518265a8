"""What several API processes share through Redis, checked with two instances in this process (the real
processes: tests/system/test_api_processes.py): the token caches' access generation and the request rates, and
what happens while Redis does not answer (no cached token is trusted; rates are counted per process)."""

from __future__ import annotations

import pytest
from sqlalchemy import select

from backend.limits import SharedRateLimiter
from fringelab.core.accounts import AuthError, TokenCache, create_user, issue_token
from fringelab.core.db import make_engine, make_sessionmaker
from fringelab.core.models import ApiToken, utcnow
from fringelab.core.settings import Settings
from fringelab.core.startup_checks import free_port

HOUR_S = 3600.0  # a cache lifetime no test outlasts: what is refused is refused because of the generation


def _token(settings: Settings):  # type: ignore[no-untyped-def]
    sessions = make_sessionmaker(make_engine(settings.resolved_database_url))
    with sessions() as session:
        _row, secret = issue_token(session, create_user(session, "ada", "ada-password"))
        session.commit()
    return sessions, secret


def _revoke(sessions, secret: str) -> None:  # type: ignore[no-untyped-def]
    with sessions() as session:
        session.scalar(select(ApiToken)).revoked_at = utcnow()
        session.commit()


def test_a_revocation_forgotten_in_one_cache_is_forgotten_in_every_other(settings: Settings):
    sessions, secret = _token(settings)
    here, there = (TokenCache(ttl_s=HOUR_S, redis_url=settings.redis_url) for _ in range(2))
    assert here.resolve(sessions, secret).username == there.resolve(sessions, secret).username == "ada"
    _revoke(sessions, secret)
    assert there.resolve(sessions, secret).username == "ada"  # cached: the database is not asked again
    here.forget()  # what the API does after a revocation (and `fringelab user` through Redis)
    for cache in (here, there):
        with pytest.raises(AuthError, match="revoked"):
            cache.resolve(sessions, secret)


def test_an_announcement_returns_once_every_process_has_taken_it_in(settings: Settings, monkeypatch):
    """`announce_access_change` (a revocation's answer, `fringelab user disable`) returns only after every
    listening process has acknowledged the new generation, however slowly its listener takes it in (here 50 ms
    late): none can trust a token checked before it."""
    import time

    import redis
    from redis.client import PubSub

    from fringelab.core.access_changes import ACCESS_GENERATION_KEY, AccessWatch, announce_access_change

    handle_message = PubSub.handle_message

    def late(self, response, ignore_subscribe_messages=False):  # type: ignore[no-untyped-def]
        time.sleep(0.05)  # a listener thread waiting for a busy process's GIL
        return handle_message(self, response, ignore_subscribe_messages)

    watches = [AccessWatch(settings.redis_url) for _ in range(3)]
    try:
        assert all(watch.current() is not None for watch in watches)
        monkeypatch.setattr(PubSub, "handle_message", late)
        shared = redis.Redis.from_url(settings.redis_url)
        for _ in range(3):
            assert announce_access_change(settings.redis_url)
            now = int(shared.get(ACCESS_GENERATION_KEY) or 0)
            assert [watch.generation for watch in watches] == [now] * 3  # at once, no waiting here
    finally:
        for watch in watches:
            watch.stop()


def test_a_cached_token_costs_no_redis_call(settings: Settings):
    """Issue 26: a GET of the access generation on every request was about 9 % of a busy web server's samples.
    The listener knows it; Redis is asked at most once a second (the listener's check), not per request."""
    sessions, secret = _token(settings)
    cache = TokenCache(ttl_s=HOUR_S, redis_url=settings.redis_url)
    cache.resolve(sessions, secret)
    before = _calls(settings.redis_url, "cmdstat_get")
    for _ in range(200):
        assert cache.resolve(sessions, secret).username == "ada"
    assert _calls(settings.redis_url, "cmdstat_get") - before <= 3  # other tests' listeners may check meanwhile


def test_without_redis_no_checked_token_is_trusted(settings: Settings):
    sessions, secret = _token(settings)
    cache = TokenCache(ttl_s=HOUR_S, redis_url=f"redis://127.0.0.1:{free_port()}/0")  # nobody listens there
    assert cache.resolve(sessions, secret).username == "ada"  # requests are still served, from the database
    _revoke(sessions, secret)
    with pytest.raises(AuthError, match="revoked"):  # not trusted while Redis cannot say whether it changed
        cache.resolve(sessions, secret)


def test_request_rates_are_counted_once_over_every_limiter(settings: Settings):
    namespace = f"test-{free_port()}"  # buckets of this test only, in the tests' shared Redis
    one, two = (
        SharedRateLimiter(redis_url=settings.redis_url, rate_per_s=0.001, burst=4, namespace=namespace)
        for _ in range(2)
    )
    waits = [limiter.take(7) for limiter in (one, two, one, two, one, two)]
    assert waits[:4] == [0.0] * 4  # the burst, shared
    assert all(wait > 100 for wait in waits[4:])  # then one request per 1000 s
    assert one.take(8) == 0.0  # another user has a bucket of their own


def test_without_redis_rates_are_counted_per_limiter(settings: Settings):
    limiter = SharedRateLimiter(redis_url=f"redis://127.0.0.1:{free_port()}/0", rate_per_s=0.001, burst=2)
    assert [limiter.take("ada") > 0 for _ in range(3)] == [False, False, True]


def _calls(redis_url: str, *names: str) -> int:
    """Calls of these commands Redis has answered so far (its own count)."""
    import redis

    stats = redis.Redis.from_url(redis_url).info("commandstats")
    return sum(int(stats.get(name, {}).get("calls", 0)) for name in names)


def _script_calls(redis_url: str) -> int:
    """Rate-limit script calls Redis has answered so far."""
    return _calls(redis_url, "cmdstat_evalsha", "cmdstat_eval")


def test_a_lease_asks_redis_once_for_several_requests_and_a_refusal_not_again(settings: Settings):
    """Issue 26: a Redis round trip per request was 16 % of the web server's CPU. A limiter takes a lease of
    `lease_for(burst)` tokens per call (9 at the default burst of 300) and remembers a refusal until its wait."""
    from backend.limits import lease_for

    assert (lease_for(30), lease_for(300), lease_for(10_000)) == (1, 9, 16)  # exact below 64, then a 32nd, <= 16
    limiter = SharedRateLimiter(redis_url=settings.redis_url, rate_per_s=0.001, burst=300,
                                namespace=f"test-{free_port()}")  # fmt: skip
    before = _script_calls(settings.redis_url)
    assert [limiter.take("ada") for _ in range(18)] == [0.0] * 18
    assert _script_calls(settings.redis_url) - before == 2
    assert [limiter.take("ada") for _ in range(300 - 18)] == [0.0] * (300 - 18)  # the whole burst, no more
    calls = _script_calls(settings.redis_url)
    waits = [limiter.take("ada") for _ in range(20)]
    assert all(wait > 100 for wait in waits)  # one request per 1000 s
    assert _script_calls(settings.redis_url) - calls == 1  # the first refusal asked; the others waited on it


def test_leases_miss_a_shared_count_by_at_most_a_lease_per_other_process(settings: Settings):
    """The tolerance stated in `SharedRateLimiter`: with two processes (two limiters), one holding the rest of
    its lease, the other is refused after burst - (lease - 1) requests; the lease's holder then spends it, so
    the two together allow the burst exactly: none is lost for good, none is added."""
    namespace = f"test-{free_port()}"
    one, two = (
        SharedRateLimiter(redis_url=settings.redis_url, rate_per_s=0.001, burst=300, namespace=namespace)
        for _ in range(2)
    )
    lease = one.lease
    assert one.take("ada") == 0.0  # takes a lease of 9, spends 1: 8 held by `one`
    allowed_two = 0
    while two.take("ada") == 0.0:
        allowed_two += 1
    assert allowed_two == 300 - lease  # refused while `one` holds lease - 1 = 8 tokens
    allowed_one = 1
    while one.take("ada") == 0.0:
        allowed_one += 1
    assert allowed_one == lease and allowed_one + allowed_two == 300
