"""CPU per call of the shared per-user rate limit (`backend.limits.SharedRateLimiter`), one Redis call per request
(lease 1, as before issue 26) against a lease of tokens per call (the default), in one process.

Run from the repository root:  .venv/bin/python bench/bench_rate_limit.py [--calls 20000] [--threads 8] [--rounds 3]

A redis-server of its own on a free port; `--threads` threads (as the web server's request threads) each take
`--calls` / `--threads` requests for 4 users in turn, at the default rate and burst raised so that nothing is
refused (the allowed path is what every request pays). Printed per variant, alternating rounds, as medians: CPU
time of this process per call (robust to a shared machine's load) and the median wall time of one call; plus the
load average.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from backend.limits import SharedRateLimiter, lease_for  # noqa: E402
from tests.support import RedisServer  # noqa: E402

USERS = (1, 2, 3, 4)


def one_round(limiter: SharedRateLimiter, *, calls: int, threads: int) -> tuple[float, float]:
    """(CPU µs per call of the process, median wall µs of one call)."""
    walls: list[list[float]] = [[] for _ in range(threads)]

    def work(index: int) -> None:
        mine = walls[index]
        for n in range(calls // threads):
            started = time.perf_counter()
            assert limiter.take(USERS[n % len(USERS)]) == 0.0
            mine.append(time.perf_counter() - started)

    workers = [threading.Thread(target=work, args=(i,)) for i in range(threads)]
    cpu_before = time.process_time()
    for worker in workers:
        worker.start()
    for worker in workers:
        worker.join()
    cpu_s = time.process_time() - cpu_before
    every = [wall for mine in walls for wall in mine]
    return cpu_s / len(every) * 1e6, statistics.median(every) * 1e6


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--calls", type=int, default=20000)
    parser.add_argument("--threads", type=int, default=8)
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="fringelab-bench-rate-") as temp:
        redis_server = RedisServer(Path(temp))
        redis_server.start()
        try:
            burst = 1_000_000  # nothing refused: the allowed path
            variants = {
                "lease 1 (a Redis call per request)": 1,
                f"lease {lease_for(300)} (default at burst 300)": lease_for(300),
            }
            figures: dict[str, list[tuple[float, float]]] = {name: [] for name in variants}
            load_before = os.getloadavg()
            for number in range(args.rounds):
                for name, lease in variants.items():
                    limiter = SharedRateLimiter(redis_url=redis_server.url, rate_per_s=100.0, burst=burst,
                                                namespace=f"bench{number}-{lease}", lease=lease)  # fmt: skip
                    figures[name].append(one_round(limiter, calls=args.calls, threads=args.threads))
            print(f"{args.calls} calls per round, {args.threads} threads, {len(USERS)} users, {args.rounds} rounds")
            for name, rounds in figures.items():
                cpu = statistics.median(r[0] for r in rounds)
                wall = statistics.median(r[1] for r in rounds)
                each = " ".join(f"{r[0]:.0f}" for r in rounds)
                print(f"{name}: CPU {cpu:.1f} µs per call (rounds {each}), median wall {wall:.1f} µs per call")
            print(f"load average before {' '.join(f'{v:.2f}' for v in load_before)}, "
                  f"after {' '.join(f'{v:.2f}' for v in os.getloadavg())}; {os.cpu_count()} CPUs")  # fmt: skip
        finally:
            redis_server.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
