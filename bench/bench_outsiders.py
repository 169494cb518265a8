"""What anonymous outsiders can do to a shared lab server (issue 26): a flood of wrong logins and of health requests.

Run from the repository root:  .venv/bin/python bench/bench_outsiders.py [--logins 120] [--health 200]

It starts its own `fringelab up` (accounts on, two web server processes, a temporary data directory, a free
loopback port; stopped at the end) and, with nobody logged in:
- sends `--logins` wrong logins at once (one connection each) and samples the web server's memory (RSS of its
  serving processes) every 20 ms meanwhile; prints how many were checked (401) and refused (429), the idle and
  peak RSS, and the time another user's request took meanwhile. Targets: peak RSS within 300 MiB of idle, at
  most FRINGELAB_LOGIN_MAX_FAILURES (10) password checks;
- sends health requests from `--health` concurrent connections for `--seconds` s, then times 20 ordinary
  requests of a user. Targets: every health request answered (200 or 429), every later request served (200)
  within 1 s.
Exit status 1 when a target is missed. The figures follow the machine's load, printed at the end.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import sys
import tempfile
import threading
import time
from collections import Counter
from pathlib import Path

import httpx

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_load import System, cli, rss_bytes, serving  # noqa: E402

MIB = 2**20


class PeakRss(threading.Thread):
    def __init__(self, system: System) -> None:
        super().__init__(daemon=True)
        self.processes = serving(system.api_processes())
        self.peak = 0
        self._stopping = threading.Event()

    def run(self) -> None:
        while not self._stopping.wait(0.02):
            self.peak = max(self.peak, rss_bytes(self.processes))

    def stop(self) -> int:
        self._stopping.set()
        self.join()
        return self.peak


async def wrong_logins(base_url: str, count: int) -> list[int | str]:
    limits = httpx.Limits(max_connections=count)
    async with httpx.AsyncClient(base_url=base_url, limits=limits, timeout=120) as client:

        async def one(i: int) -> int | str:
            try:
                answer = await client.post("/api/v1/auth/login", json={"username": "ada", "password": f"no-{i}"})
            except httpx.HTTPError as error:
                return type(error).__name__
            return answer.status_code

        return list(await asyncio.gather(*(one(i) for i in range(count))))


async def health_flood(base_url: str, connections: int, seconds: float) -> list[int | str]:
    limits = httpx.Limits(max_connections=connections)
    async with httpx.AsyncClient(base_url=base_url, limits=limits, timeout=30) as client:
        deadline = time.monotonic() + seconds

        async def one() -> list[int | str]:
            seen: list[int | str] = []
            while time.monotonic() < deadline:
                try:
                    seen.append((await client.get("/api/v1/health")).status_code)
                except httpx.HTTPError as error:
                    seen.append(type(error).__name__)
            return seen

        return [o for outcomes in await asyncio.gather(*(one() for _ in range(connections))) for o in outcomes]


def timed_get(base_url: str, token: str, path: str) -> tuple[int | str, float]:
    started = time.perf_counter()
    try:
        status: int | str = httpx.get(f"{base_url}{path}", headers={"Authorization": f"Bearer {token}"},
                                      timeout=30).status_code  # fmt: skip
    except httpx.HTTPError as error:
        status = type(error).__name__
    return status, time.perf_counter() - started


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--logins", type=int, default=120, help="wrong logins at once")
    parser.add_argument("--health", type=int, default=200, help="concurrent health connections")
    parser.add_argument("--seconds", type=float, default=15.0, help="seconds of the health flood")
    args = parser.parse_args()
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory(prefix="fringelab-bench-outsiders-") as temp:
        system = System(Path(temp) / "var")
        Path(temp, "var").mkdir()
        system.env["FRINGELAB_API_PROCESSES"] = "2"
        for name in ("ada", "bob"):
            cli(system.env, "user", "add", name, "--password-stdin", stdin=f"{name}-password-26\n")
        token = cli(system.env, "token", "create", "bob", "--name", "bench")
        try:
            system.start()
            time.sleep(2.0)  # the processes settle (each makes its dummy hash in the background at start)
            idle = rss_bytes(serving(system.api_processes()))
            sampler = PeakRss(system)
            sampler.start()
            other: list[tuple[int | str, float]] = []
            meanwhile = threading.Thread(target=lambda: other.append(timed_get(system.base_url, token,
                                                                              "/api/v1/experiments")))  # fmt: skip
            started = time.perf_counter()
            meanwhile.start()
            logins = asyncio.run(wrong_logins(system.base_url, args.logins))
            took = time.perf_counter() - started
            meanwhile.join()
            peak = sampler.stop()

            flood = asyncio.run(health_flood(system.base_url, args.health, args.seconds))
            after = [timed_get(system.base_url, token, "/api/v1/experiments") for _ in range(20)]
        finally:
            system.stop()
    load_after = os.getloadavg()

    counted = Counter(map(str, logins))
    checked = counted.get("401", 0)
    print(f"{args.logins} wrong logins at once (2 web server processes): {dict(counted)} in {took:.1f} s; "
          f"{checked} password checks (401)")  # fmt: skip
    print(f"web server RSS: idle {idle / MIB:.0f} MiB, peak {peak / MIB:.0f} MiB (+{(peak - idle) / MIB:.0f} MiB); "
          f"another user's request meanwhile: {other[0][0]} in {other[0][1] * 1000:.0f} ms")  # fmt: skip
    flooded = Counter(map(str, flood))
    print(f"health flood: {args.health} connections for {args.seconds:g} s: {dict(flooded)} "
          f"({len(flood) / args.seconds:.0f} answers/s)")  # fmt: skip
    statuses = Counter(str(status) for status, _ in after)
    slowest = max(seconds for _, seconds in after)
    print(f"then 20 requests of a user: {dict(statuses)}, slowest {slowest * 1000:.0f} ms")
    print(f"load average (1/5/15 min): before {' '.join(f'{v:.2f}' for v in load_before)}, "
          f"after {' '.join(f'{v:.2f}' for v in load_after)}; {os.cpu_count()} CPUs")  # fmt: skip
    targets = (
        ("RSS within 300 MiB of idle", peak - idle <= 300 * MIB),
        ("at most 10 password checks", checked <= 10),
        ("every login answered 401/429 (or 503: shed)", set(counted) <= {"401", "429", "503"}),
        ("every health request answered 200/429", set(flooded) <= {"200", "429"}),
        ("later requests served within 1 s", set(statuses) == {"200"} and slowest < 1.0),
    )
    missed = [name for name, ok in targets if not ok]
    print("targets: all met" if not missed else f"targets missed: {', '.join(missed)}")
    return 1 if missed else 0


if __name__ == "__main__":
    sys.exit(main())
