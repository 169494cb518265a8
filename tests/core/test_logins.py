"""The login gate (`fringelab.core.logins`) against a real Redis: attempts counted per account whatever the
address, loopback as one address, and the cap on password checks at once."""

from __future__ import annotations

import pytest
import redis

from fringelab.core.errors import RateLimited
from fringelab.core.logins import LoginGate, address_key, auto_concurrency


@pytest.fixture
def gate(settings) -> LoginGate:
    redis.Redis.from_url(settings.redis_url).flushdb()
    return LoginGate(settings.model_copy(update={"login_max_failures": 3, "login_concurrency": 1}))


def test_attempts_on_one_account_count_whatever_the_address(gate):
    """Finding 2: rotating source addresses got 60 of 60 checks; the account's counter holds them."""
    for i in range(3):
        with pytest.raises(ValueError), gate.attempt(client=f"10.0.0.{i}", username="Ada"):
            raise ValueError("wrong password")
    with pytest.raises(RateLimited), gate.attempt(client="10.0.0.99", username="ada"):
        pytest.fail("a fourth attempt on the account was let through to the password check")
    with gate.attempt(client="10.0.0.99", username="bob") as success:  # another account from there still may
        success()


def test_a_successful_login_takes_its_attempt_back(gate):
    for _ in range(5):
        with gate.attempt(client="10.0.0.1", username="ada") as success:
            success()


def test_beyond_the_checks_at_once_a_login_is_refused_at_once_and_not_counted(gate):
    with (
        gate.attempt(client="10.0.0.1", username="ada"),
        pytest.raises(RateLimited, match="at once"),
        gate.attempt(client="10.0.0.2", username="bob"),
    ):
        pytest.fail("a second check ran beside the first with a cap of 1")
    for _ in range(3):  # bob's refused attempt was taken back: three more are allowed
        with pytest.raises(ValueError), gate.attempt(client="10.0.0.3", username="bob"):
            raise ValueError("wrong password")


def test_addresses_are_counted_by_network():
    assert address_key("127.0.0.1") == address_key("127.0.0.77") == address_key("::1") == "loopback"
    assert address_key("2001:db8::1") == address_key("2001:db8::ffff") == "2001:db8::/64"
    assert address_key("::ffff:10.1.2.3") == "10.1.2.3"
    assert address_key("192.0.2.7") == "192.0.2.7"


def test_the_cap_follows_memory_and_is_shared_by_the_processes():
    gib = 1 << 30
    assert (
        auto_concurrency(gib // 2, 1) == 1 and auto_concurrency(2 * gib, 1) == 2 and auto_concurrency(64 * gib, 1) == 4
    )
    # The server's 4 checks (256 MiB) between its processes, at least one each.
    assert (
        auto_concurrency(64 * gib, 2) == 2 and auto_concurrency(64 * gib, 4) == 1 and auto_concurrency(64 * gib, 8) == 1
    )
    assert auto_concurrency(2 * gib, 2) == 1
