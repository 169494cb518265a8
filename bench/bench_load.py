"""Load benchmark of a shared lab server: `fringelab up` with accounts on, hammered over loopback while it works.

Run from the repository root:  .venv/bin/python bench/bench_load.py [--rate 200] [--duration 30] [--connections 100]

It starts its own system (`python -m backend.cli up`, its own Redis, worker and web server) with accounts on in
a temporary data directory, on a free loopback port, and stops it at the end (also on Ctrl-C or an error). Four
users, each with an API token, share the load. A demo experiment (the virtual kodak camera) is measured first,
so that results exist; a second demo is started just before the load, so that its calibrations and topography
job run while the load runs. Then, open loop, `--rate` requests per second for `--duration` seconds from at most
`--connections` concurrent connections, spread over results (topography grid, overview, profile), lists (jobs,
recordings, experiments), single objects and Server-Sent-Event streams of jobs (read for at most 2 s). It
prints the count of 5xx answers, of 429s, of timeouts (no answer in 10 s) and of connection errors, the p50 /
p99 / max latency, and the web server's memory (RSS) before and after. Targets (issue 16): 0 × 5xx, no timeouts,
p99 < 500 ms, memory growth < 20 %. Exit status 1 when a target is missed.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import random
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

import httpx
import psutil

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fringelab.core.services import free_port  # noqa: E402

USERS = ("admin", "ada", "bob", "cy")
REQUEST_TIMEOUT_S = 10.0
SETUP_TIMEOUT_S = 600.0
STREAM_READ_S = 2.0


def cli(env: dict[str, str], *args: str, stdin: str = "") -> str:
    done = subprocess.run(
        [sys.executable, "-m", "backend.cli", *args], env=env, input=stdin, capture_output=True, text=True, timeout=120
    )
    if done.returncode != 0:
        raise RuntimeError(f"fringelab {' '.join(args)} failed: {done.stderr.strip()}")
    return done.stdout.strip()


def wait(predicate, *, timeout_s: float, what: str, interval_s: float = 0.5):  # type: ignore[no-untyped-def]
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(interval_s)
    raise TimeoutError(f"no {what} within {timeout_s:.0f} s")


class System:
    """`fringelab up` in a subprocess, its own process group, stopped with SIGTERM (then SIGKILL)."""

    def __init__(self, data_dir: Path) -> None:
        self.port = free_port()
        self.base_url = f"http://127.0.0.1:{self.port}"
        clean = {k: v for k, v in os.environ.items() if not k.startswith("FRINGELAB_")}
        self.env = {**clean, "FRINGELAB_DATA_DIR": str(data_dir), "FRINGELAB_PORT": str(self.port),
                    "FRINGELAB_AUTH_ENABLED": "true", "FRINGELAB_LOG_LEVEL": "warning"}  # fmt: skip
        self.log_path = data_dir.parent / "up.log"
        self.process: subprocess.Popen[bytes] | None = None

    def start(self) -> None:
        with self.log_path.open("wb") as log:
            self.process = subprocess.Popen(
                [sys.executable, "-m", "backend.cli", "up"], env=self.env, stdout=log, stderr=subprocess.STDOUT,
                start_new_session=True,
            )  # fmt: skip

        def healthy() -> bool:
            if self.process and self.process.poll() is not None:
                raise RuntimeError(f"`fringelab up` exited:\n{self.log_path.read_text()[-3000:]}")
            try:
                return httpx.get(f"{self.base_url}/api/v1/health", timeout=5).status_code == 200
            except httpx.HTTPError:
                return False

        wait(healthy, timeout_s=180, what="healthy `fringelab up`")

    def api_process(self) -> psutil.Process:
        assert self.process is not None
        for child in psutil.Process(self.process.pid).children(recursive=True):
            with contextlib.suppress(psutil.Error):
                if child.cmdline()[-1:] == ["api"]:
                    return child
        raise RuntimeError("no web server process under `fringelab up`")

    def stop(self) -> None:
        if self.process is None or self.process.poll() is not None:
            return
        os.killpg(self.process.pid, signal.SIGTERM)
        try:
            self.process.wait(timeout=60)
        except subprocess.TimeoutExpired:
            os.killpg(self.process.pid, signal.SIGKILL)
            self.process.wait()


def demo(client: httpx.Client, *, test_frames: int) -> int:
    answer = client.post("/api/v1/demo", json={"cameras": ["kodak"], "test_frames": test_frames})
    answer.raise_for_status()
    return int(answer.json()["experiment_id"])


def topography_job(client: httpx.Client, experiment_id: int, *, finished: bool) -> dict | None:
    jobs = client.get("/api/v1/jobs", params={"experiment_id": experiment_id, "limit": 100}).json()["items"]
    for job in jobs:
        if job["kind"] == "topography" and (job["state"] == "succeeded" or not finished):
            return job
        if job["kind"] == "topography" and job["state"] in ("failed", "cancelled"):
            raise RuntimeError(f"the demo's topography job ended {job['state']}: {job.get('error')}")
    return None


def running_jobs(client: httpx.Client, experiment_id: int) -> list[str]:
    jobs = client.get("/api/v1/jobs", params={"experiment_id": experiment_id, "limit": 100}).json()["items"]
    return [job["id"] for job in jobs if job["state"] in ("queued", "running")]


def request_mix(job_id: str, running_job_ids: list[str], rng: random.Random) -> tuple[str, str, dict]:
    """(kind, path, params) of one request: results, lists, objects and event streams."""
    pick = rng.random()
    if pick < 0.30:
        return "grid", f"/api/v1/jobs/{job_id}/topography/grid", {"frame": rng.randrange(0, 8)}
    if pick < 0.40:
        return "overview", f"/api/v1/jobs/{job_id}/topography", {}
    if pick < 0.50:
        line = {"x0": -40.0, "y0": 0.0, "x1": 40.0, "y1": 0.0, "frames": [rng.randrange(0, 8)]}
        return "profile", f"/api/v1/jobs/{job_id}/topography/profile", line
    if pick < 0.65:
        return "list", rng.choice(["/api/v1/jobs", "/api/v1/recordings", "/api/v1/experiments"]), {}
    if pick < 0.80:
        return "object", f"/api/v1/jobs/{job_id}", {}
    if pick < 0.95:
        return "log", f"/api/v1/jobs/{job_id}/log", {}
    return "events", f"/api/v1/jobs/{rng.choice(running_job_ids or [job_id])}/events", {}


async def one_request(client: httpx.AsyncClient, token: str, kind: str, path: str, params: dict,
                      results: list[tuple[str, float, str]]) -> None:  # fmt: skip
    headers = {"Authorization": f"Bearer {token}"}
    started = time.perf_counter()
    try:
        if kind == "events":
            async with client.stream("GET", path, headers=headers, timeout=REQUEST_TIMEOUT_S) as answer:
                outcome = str(answer.status_code)
                latency = time.perf_counter() - started  # to the first byte of the stream
                with contextlib.suppress(TimeoutError):
                    async with asyncio.timeout(STREAM_READ_S):
                        async for _chunk in answer.aiter_bytes():
                            pass
        else:
            answer = await client.get(path, params=params, headers=headers, timeout=REQUEST_TIMEOUT_S)
            outcome = str(answer.status_code)
            latency = time.perf_counter() - started
    except httpx.TimeoutException:
        outcome, latency = "timeout", time.perf_counter() - started
    except httpx.HTTPError as error:
        outcome, latency = f"error:{type(error).__name__}", time.perf_counter() - started
    results.append((kind, latency, outcome))


Result = tuple[str, float, str]  # kind, latency in s, status code or "timeout" / "error:..."


async def load(base_url: str, tokens: list[str], job_id: str, running: list[str], *, rate: float,
               duration_s: float, connections: int, seed: int) -> tuple[list[Result], float]:  # fmt: skip
    rng = random.Random(seed)
    results: list[tuple[str, float, str]] = []
    limits = httpx.Limits(max_connections=connections, max_keepalive_connections=connections)
    gate = asyncio.Semaphore(connections)
    async with httpx.AsyncClient(base_url=base_url, limits=limits) as client:
        tasks = []
        started = time.perf_counter()
        total = int(rate * duration_s)

        async def gated(index: int) -> None:
            kind, path, params = request_mix(job_id, running, rng)
            async with gate:
                await one_request(client, tokens[index % len(tokens)], kind, path, params, results)

        for index in range(total):
            delay = started + index / rate - time.perf_counter()
            if delay > 0:
                await asyncio.sleep(delay)
            tasks.append(asyncio.create_task(gated(index)))
        await asyncio.gather(*tasks)
        elapsed = time.perf_counter() - started
    return results, elapsed


def percentile(values: list[float], q: float) -> float:
    return statistics.quantiles(values, n=1000, method="inclusive")[int(q * 10) - 1] if len(values) > 1 else values[0]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rate", type=float, default=200.0, help="requests per second")
    parser.add_argument("--duration", type=float, default=30.0, help="seconds of load")
    parser.add_argument("--connections", type=int, default=100, help="concurrent connections at most")
    parser.add_argument("--test-frames", type=int, default=8, help="frames of each demo's simulated test")
    parser.add_argument("--seed", type=int, default=16)
    args = parser.parse_args()

    with tempfile.TemporaryDirectory(prefix="fringelab-bench-load-") as temp:
        system = System(Path(temp) / "var")
        Path(temp, "var").mkdir()
        for index, name in enumerate(USERS):
            flags = ["--admin"] if index == 0 else []
            cli(system.env, "user", "add", name, *flags, "--password-stdin", stdin=f"{name}-password-16\n")
        tokens = [cli(system.env, "token", "create", name, "--name", "bench") for name in USERS]
        try:
            system.start()
            setup_started = time.monotonic()
            admin = httpx.Client(base_url=system.base_url, headers={"Authorization": f"Bearer {tokens[0]}"},
                                 timeout=30)  # fmt: skip
            first = demo(admin, test_frames=args.test_frames)
            job = wait(lambda: topography_job(admin, first, finished=True), timeout_s=SETUP_TIMEOUT_S,
                       what="finished topography job of the first demo", interval_s=2)  # fmt: skip
            print(f"setup: first demo measured in {time.monotonic() - setup_started:.0f} s", flush=True)
            second = demo(admin, test_frames=args.test_frames)
            running = wait(lambda: running_jobs(admin, second), timeout_s=120, what="job of the second demo")
            # Every user's requests name the admin's jobs: the admin reads them (half the requests), members get
            # the 404 of an object they may not see, which costs the server the same authentication and check.
            api = system.api_process()
            rss_before = api.memory_info().rss
            results, elapsed = asyncio.run(
                load(system.base_url, tokens[:1] * 3 + tokens[1:], job["id"], running, rate=args.rate,
                     duration_s=args.duration, connections=args.connections, seed=args.seed)
            )  # fmt: skip
            rss_after = api.memory_info().rss
            try:
                second_jobs = admin.get("/api/v1/jobs", params={"experiment_id": second, "limit": 100}).json()
                states = Counter(f"{j['kind']}:{j['state']}" for j in second_jobs["items"])
            except httpx.HTTPError as error:  # a server still swamped after the load: say so, keep the figures
                states = Counter({f"unanswered after the load ({type(error).__name__})": 1})
            admin.close()
        finally:
            system.stop()

    outcomes = Counter(outcome for _kind, _latency, outcome in results)
    answered = [latency for _kind, latency, outcome in results if outcome[0].isdigit()]
    server_errors = sum(count for outcome, count in outcomes.items() if outcome.startswith("5"))
    timeouts = outcomes.get("timeout", 0)
    failures = sum(count for outcome, count in outcomes.items() if outcome.startswith("error"))
    p50, p99 = percentile(answered, 50), percentile(answered, 99)
    growth = (rss_after - rss_before) / rss_before
    load_1, load_5, load_15 = os.getloadavg()
    print(f"load: {len(results)} requests in {elapsed:.1f} s ({len(results) / elapsed:.0f}/s asked {args.rate:.0f}/s), "
          f"at most {args.connections} connections, 4 users")  # fmt: skip
    print(f"answers: {json.dumps(dict(sorted(outcomes.items())))}")
    by_kind = Counter(kind for kind, _latency, _outcome in results)
    print(f"mix: {json.dumps(dict(sorted(by_kind.items())))}")
    print(f"5xx: {server_errors}   timeouts: {timeouts}   connection errors: {failures}   "
          f"429: {outcomes.get('429', 0)}")  # fmt: skip
    print(f"latency: p50 {p50 * 1000:.0f} ms   p99 {p99 * 1000:.0f} ms   max {max(answered) * 1000:.0f} ms")
    print(f"web server RSS: {rss_before / 2**20:.0f} MiB -> {rss_after / 2**20:.0f} MiB ({growth * 100:+.1f} %)")
    print(f"jobs of the demo run during the load: {dict(states)}")
    print(f"load average (1/5/15 min): {load_1:.2f} {load_5:.2f} {load_15:.2f}")
    missed = [name for name, ok in (("0 × 5xx", server_errors == 0), ("no timeouts", timeouts == 0 and failures == 0),
              ("p99 < 500 ms", p99 < 0.5), ("memory growth < 20 %", growth < 0.2)) if not ok]  # fmt: skip
    print("targets: all met" if not missed else f"targets missed: {', '.join(missed)}")
    return 1 if missed else 0


if __name__ == "__main__":
    sys.exit(main())
