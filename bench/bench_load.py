"""Load benchmark of a shared lab server: `fringelab up` with accounts on, hammered over loopback while it works.

Run from the repository root:  .venv/bin/python bench/bench_load.py [--rate 200] [--duration 30] [--connections 100]

It starts its own system (`python -m backend.cli up`, its own Redis, worker and web server processes) with
accounts on in a temporary data directory, on a free loopback port, and stops it at the end (also on Ctrl-C or an
error). Four users (two admins, two members of a group the demo experiments are shared with), each with an API
token, share the load evenly (50/s each at 200/s, half the default per-user limit). A demo experiment (the virtual
kodak camera) is measured first, so that results exist; a second demo is started just before the load, so that
its calibrations and topography job run while the load runs. Then, open loop, `--rate` requests per second for
`--duration` seconds from at most `--connections` concurrent connections, spread over results (topography grid,
overview, profile), lists (jobs, recordings, experiments), single objects, logs and Server-Sent-Event streams of
jobs (read for at most 2 s). The load comes from two client processes (aiohttp; one Python process could not send
200 requests/s and time them honestly on a busy machine), plus a probe: a fifth user asking for one job every
100 ms, one request at a time, whose latency is what a person at the dashboard would see.

It prints the count of 5xx answers, of 429s, of timeouts (no answer in 10 s) and of connection errors, the p50 /
p99 / max latency (of the load and of the probe), the web server's memory (RSS of all its processes) before and
after, its CPU time per request, and the load average of the machine. Targets (issue 16): 0 × 5xx, no timeouts,
p99 < 500 ms, memory growth < 20 %. Exit status 1 when a target is missed.

`--mix heavy` (issue 26) sends instead grids of random frames, profiles along random lines over 1 to 10 random
frames, and 50-job lists; it also prints how many requests were shed (503, and how fast), the longest wait for
any answer, and how soon after the load the server serves a plain read normally again. Its targets: no 5xx but
503, no timeouts, p99 < 1 s for what is served, 503 within 100 ms (p99), no wait over 2 s, serving within 5 s
after. E.g. `--mix heavy --rate 200 --duration 30` and `--mix heavy --rate 500 --duration 20`.

The issue's three scenarios on one server (one setup): `--mix heavy --rate 200 --duration 30 --then 500:20
--health-flood 200` (`--then RATE:SECONDS`: another load after a `--pause`; `--health-flood N`: at the end, N
concurrent health requests for 5 s, then 20 plain reads, each a 200 within 2 s). On a loaded machine, shorter
durations (`--duration 10 --then 500:8`) still show each figure.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import multiprocessing
import os
import random
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import httpx
import psutil

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fringelab.core.startup_checks import free_port  # noqa: E402

USERS = ("admin", "lab", "ada", "bob")  # two admins, two members of the group the demos are shared with
ADMINS = ("admin", "lab")
PROBE_USER = "probe"
CLIENT_PROCESSES = 2
PROBE_INTERVAL_S = 0.1
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

    def _child(self, command: str) -> list[psutil.Process]:
        """The child of `up` running `fringelab <command>` (or `python -m <command>`) and its own processes."""
        assert self.process is not None
        for child in psutil.Process(self.process.pid).children():
            with contextlib.suppress(psutil.Error):
                if child.cmdline()[-1:] == [command]:
                    return [child, *child.children(recursive=True)]
        return []

    def api_processes(self) -> list[psutil.Process]:
        """The web server: the `fringelab api` process and the processes it serves with."""
        processes = self._child("api")
        if not processes:
            raise RuntimeError("no web server process under `fringelab up`")
        return processes

    def worker_processes(self) -> list[psutil.Process]:
        return self._child("worker")

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


def _topography_running(client: httpx.Client, experiment_id: int) -> bool:
    job = topography_job(client, experiment_id, finished=False)
    return job is not None and job["state"] == "running"


def running_jobs(client: httpx.Client, experiment_id: int) -> list[str]:
    jobs = client.get("/api/v1/jobs", params={"experiment_id": experiment_id, "limit": 100}).json()["items"]
    return [job["id"] for job in jobs if job["state"] in ("queued", "running")]


def heavy_mix(job_id: str, frames: int, rng: random.Random) -> tuple[str, str, dict]:
    """(kind, path, params) of one request of the mix that cost 8.2 ms of web CPU each (issue 26): grids of random
    frames, profiles along random lines over random frames, and 50-job lists."""
    pick = rng.random()
    if pick < 0.35:
        return "grid", f"/api/v1/jobs/{job_id}/topography/grid", {"frame": rng.randrange(0, frames)}
    if pick < 0.70:
        x0, y0, x1, y1 = (round(rng.uniform(-45.0, 45.0), 1) for _ in range(4))
        picked = rng.sample(range(frames), rng.randint(1, min(10, frames)))
        line = [("x0_mm", x0), ("y0_mm", y0), ("x1_mm", x1), ("y1_mm", y1), *(("frames", f) for f in picked)]
        return "profile", f"/api/v1/jobs/{job_id}/topography/profile", line  # type: ignore[return-value]
    return "list", "/api/v1/jobs", {"limit": 50}


def request_mix(
    job_id: str, running_job_ids: list[str], rng: random.Random, *, heavy: int = 0
) -> tuple[str, str, dict]:
    """(kind, path, params) of one request: results, lists, objects and event streams (`heavy`: the number of
    frames of the result, for the heavy mix instead)."""
    if heavy:
        return heavy_mix(job_id, heavy, rng)
    pick = rng.random()
    if pick < 0.30:
        return "grid", f"/api/v1/jobs/{job_id}/topography/grid", {"frame": rng.randrange(0, 8)}
    if pick < 0.40:
        return "overview", f"/api/v1/jobs/{job_id}/topography", {}
    if pick < 0.50:
        line = {"x0": -40.0, "y0": 0.0, "x1": 40.0, "y1": 0.0, "frames": rng.randrange(0, 8)}
        return "profile", f"/api/v1/jobs/{job_id}/topography/profile", line
    if pick < 0.65:
        return "list", rng.choice(["/api/v1/jobs", "/api/v1/recordings", "/api/v1/experiments"]), {}
    if pick < 0.80:
        return "object", f"/api/v1/jobs/{job_id}", {}
    if pick < 0.95:
        return "log", f"/api/v1/jobs/{job_id}/log", {}
    return "events", f"/api/v1/jobs/{rng.choice(running_job_ids or [job_id])}/events", {}


Result = tuple[str, float, str, float]  # kind, latency in s, status code or "timeout" / "error:...", sent at (unix s)


async def one_request(session, token: str, kind: str, path: str, params: dict) -> Result:  # type: ignore[no-untyped-def]
    import aiohttp

    headers = {"Authorization": f"Bearer {token}"}
    sent_at = time.time()
    started = time.perf_counter()
    try:
        async with asyncio.timeout(REQUEST_TIMEOUT_S):
            async with session.get(path, params=params, headers=headers) as answer:
                outcome = str(answer.status)
                latency = time.perf_counter() - started  # for a stream: to its first byte
                if kind != "events":
                    await answer.read()
                    latency = time.perf_counter() - started
                else:
                    with contextlib.suppress(TimeoutError):
                        async with asyncio.timeout(STREAM_READ_S):
                            async for _chunk in answer.content.iter_any():
                                pass
    except TimeoutError:
        outcome, latency = "timeout", time.perf_counter() - started
    except aiohttp.ClientError as error:
        outcome, latency = f"error:{type(error).__name__}", time.perf_counter() - started
    return kind, latency, outcome, sent_at


async def _client(base_url: str, tokens: list[str], job_id: str, running: list[str], *, rate: float,
                  duration_s: float, connections: int, seed: int, start_at: float, index: int,
                  processes: int, heavy: int = 0) -> tuple[list[Result], float]:  # fmt: skip
    import aiohttp

    rng = random.Random(seed * 1000 + index)
    gate = asyncio.Semaphore(connections)
    connector = aiohttp.TCPConnector(limit=connections, keepalive_timeout=30)
    results: list[Result] = []
    async with aiohttp.ClientSession(base_url, connector=connector) as session:

        async def gated(number: int, kind: str, path: str, params: dict) -> None:
            async with gate:
                results.append(await one_request(session, tokens[number % len(tokens)], kind, path, params))

        total = int(rate * duration_s)
        tasks = []
        # Both clients share one schedule: request n of all goes at start_at + n / rate; this one sends every
        # `processes`-th, so the server sees one even stream at the asked rate.
        await asyncio.sleep(max(0.0, start_at - time.time()))
        started = time.perf_counter()
        for number in range(index, total, processes):
            delay = started + number / rate - time.perf_counter()
            if delay > 0:
                await asyncio.sleep(delay)
            tasks.append(asyncio.create_task(gated(number, *request_mix(job_id, running, rng, heavy=heavy))))
        await asyncio.gather(*tasks)
        elapsed = time.perf_counter() - started
    return results, elapsed


def client_process(*arguments: object, **options: object) -> tuple[list[Result], float]:
    """One load client, in a process of its own (started by `load`)."""
    return asyncio.run(_client(*arguments, **options))  # type: ignore[arg-type]


async def _probe(base_url: str, token: str, job_id: str, *, start_at: float, duration_s: float) -> list[Result]:
    import aiohttp

    results: list[Result] = []
    connector = aiohttp.TCPConnector(limit=1, keepalive_timeout=30)
    async with aiohttp.ClientSession(base_url, connector=connector) as session:
        await asyncio.sleep(max(0.0, start_at - time.time()))
        ends = time.perf_counter() + duration_s
        while time.perf_counter() < ends:
            began = time.perf_counter()
            results.append(await one_request(session, token, "probe", f"/api/v1/jobs/{job_id}", {}))
            await asyncio.sleep(max(0.0, PROBE_INTERVAL_S - (time.perf_counter() - began)))
    return results


def probe_process(*arguments: object, **options: object) -> list[Result]:
    return asyncio.run(_probe(*arguments, **options))  # type: ignore[arg-type]


def load(base_url: str, tokens: list[str], probe_token: str, job_id: str, running: list[str], *, rate: float,
         duration_s: float, connections: int, seed: int,
         start_at: float, heavy: int = 0) -> tuple[list[Result], list[Result], float]:  # fmt: skip
    """The load from CLIENT_PROCESSES processes and the probe's from one more, from `start_at` (unix s); (load,
    probe, elapsed s)."""
    spawn = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=CLIENT_PROCESSES + 1, mp_context=spawn) as pool:
        clients = [
            pool.submit(client_process, base_url, tokens, job_id, running, rate=rate, duration_s=duration_s,
                        connections=max(1, connections // CLIENT_PROCESSES), seed=seed, start_at=start_at,
                        index=index, processes=CLIENT_PROCESSES, heavy=heavy)
            for index in range(CLIENT_PROCESSES)
        ]  # fmt: skip
        probe = pool.submit(probe_process, base_url, probe_token, job_id, start_at=start_at, duration_s=duration_s)
        results: list[Result] = []
        elapsed = 0.0
        for client in clients:
            part, took = client.result()
            results += part
            elapsed = max(elapsed, took)
        return results, probe.result(), elapsed


def _start_profilers(args: argparse.Namespace, processes: list[psutil.Process], *,
                     duration_s: float) -> list[subprocess.Popen[bytes]]:  # fmt: skip
    """With --profile DIR: py-spy sampling each web server process (idle threads too: where requests wait) for the
    load, as collapsed stacks in DIR/<rate>-<pid>.txt (`py-spy` must be installed: `pip install py-spy`)."""
    if not args.profile:
        return []
    Path(args.profile).mkdir(parents=True, exist_ok=True)
    return [
        subprocess.Popen(
            [
                "py-spy",
                "record",
                "--idle",
                "--format",
                "raw",
                "--rate",
                "50",
                "--nonblocking",
                "--duration",
                str(int(duration_s)),
                "--pid",
                str(process.pid),
                "--output",
                str(Path(args.profile) / f"{args.rate:g}-{process.pid}.txt"),
            ],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )  # fmt: skip
        for process in processes
    ]


def share_with_members(client: httpx.Client, experiment_ids: list[int]) -> None:
    """The members read the demos through a group share, as a lab does (not the 404 of someone else's data)."""
    members = [name for name in USERS if name not in ADMINS]
    group = client.post("/api/v1/groups", json={"name": "bench", "members": members})
    group.raise_for_status()
    for experiment_id in experiment_ids:
        client.patch(f"/api/v1/experiments/{experiment_id}", json={"group_id": group.json()["id"]}).raise_for_status()


def serving(processes: list[psutil.Process]) -> list[psutil.Process]:
    """The processes that serve requests: uvicorn's children, not its parent (which only holds the port) nor
    multiprocessing's resource tracker."""
    kept = []
    for process in processes[1:] or processes:
        with contextlib.suppress(psutil.Error):
            if "resource_tracker" not in " ".join(process.cmdline()):
                kept.append(process)
    return kept


def _load_s(moment: str | None, start_at: float) -> str:
    """An ISO time of the API as seconds from the start of the load."""
    if not moment:
        return "-"
    from datetime import datetime

    return f"{datetime.fromisoformat(moment.replace('Z', '+00:00')).timestamp() - start_at:.1f}"


class TopographyKeeper(threading.Thread):
    """Keeps two topography jobs of the running demo queued or running (its spec, one frame fewer each time: never
    the same spec as an active one), until stopped."""

    def __init__(self, base_url: str, token: str, experiment_id: int, spec: dict, *, frames: int) -> None:
        super().__init__(daemon=True)
        self.client = httpx.Client(base_url=base_url, headers={"Authorization": f"Bearer {token}"}, timeout=30)
        self.experiment_id, self.spec, self.frames = experiment_id, spec, frames
        self.started = 0
        self._stopping = threading.Event()

    def run(self) -> None:
        last = (self.spec.get("frames") or {}).get("last") or self.frames - 1
        while not self._stopping.wait(0.5):
            with contextlib.suppress(httpx.HTTPError):
                jobs = self.client.get("/api/v1/jobs", params={"experiment_id": self.experiment_id, "limit": 100})
                if jobs.status_code != 200:  # shed (503) under the load: ask again at the next turn
                    continue
                active = [j for j in jobs.json()["items"] if j["kind"] == "topography" and j["state"] in
                          ("queued", "running")]  # fmt: skip
                if len(active) < 2:  # one running, one queued behind it: no gap while the next one is picked up
                    self.started += 1
                    again = {**self.spec, "frames": {"first": 0, "last": last - self.started % 50}}
                    self.client.post("/api/v1/jobs", json=again)

    def stop(self) -> None:
        self._stopping.set()
        self.join(timeout=30)
        self.client.close()


def _covered_s(spans: list[tuple[str | None, str | None]], start_at: float, elapsed_s: float) -> float:
    """Seconds of the load (0 to `elapsed_s`) during which at least one of the jobs' spans was open."""
    intervals = []
    for begun, ended in spans:
        if begun:
            low = max(0.0, float(_load_s(begun, start_at)))
            high = min(elapsed_s, float(_load_s(ended, start_at)) if ended else elapsed_s)
            if high > low:
                intervals.append((low, high))
    covered, reached = 0.0, 0.0
    for low, high in sorted(intervals):
        low = max(low, reached)
        if high > low:
            covered += high - low
            reached = high
    return covered


def cpu_s(processes: list[psutil.Process]) -> float:
    total = 0.0
    for process in processes:
        with contextlib.suppress(psutil.Error):
            times = process.cpu_times()
            total += times.user + times.system
    return total


def rss_bytes(processes: list[psutil.Process]) -> int:
    total = 0
    for process in processes:
        with contextlib.suppress(psutil.Error):
            total += process.memory_info().rss
    return total


def percentile(values: list[float], q: float) -> float:
    return statistics.quantiles(values, n=1000, method="inclusive")[int(q * 10) - 1] if len(values) > 1 else values[0]


def recovery_s(base_url: str, token: str, job_id: str, *, within_s: float = 30.0) -> float:
    """Seconds after the load until the server answers a plain read normally (200 within 0.5 s) again."""
    started = time.monotonic()
    with httpx.Client(base_url=base_url, headers={"Authorization": f"Bearer {token}"}, timeout=10) as client:
        while time.monotonic() - started < within_s:
            asked = time.monotonic()
            with contextlib.suppress(httpx.HTTPError):
                if client.get(f"/api/v1/jobs/{job_id}").status_code == 200 and time.monotonic() - asked < 0.5:
                    return time.monotonic() - started
            time.sleep(0.1)
    return float("inf")


def health_flood(base_url: str, token: str, job_id: str, *, connections: int, seconds: float = 5.0) -> int:
    """`connections` clients asking for the health check back to back for `seconds` (issue 26: 100 of them hung
    both web server processes for good), then 20 plain reads one after another: each must be a 200 within 2 s.
    Prints what the flood got and the reads' slowest answer; 1 when a read was not served normally."""
    import aiohttp

    async def flood() -> Counter:
        outcomes: Counter = Counter()
        connector = aiohttp.TCPConnector(limit=connections)
        async with aiohttp.ClientSession(base_url, connector=connector) as session:
            deadline = time.monotonic() + seconds

            async def one() -> None:
                while time.monotonic() < deadline:
                    try:
                        async with asyncio.timeout(REQUEST_TIMEOUT_S):
                            async with session.get("/api/v1/health") as answer:
                                await answer.read()
                                outcomes[str(answer.status)] += 1
                    except (TimeoutError, aiohttp.ClientError) as error:
                        outcomes[type(error).__name__] += 1

            await asyncio.gather(*(one() for _ in range(connections)))
        return outcomes

    load_before = os.getloadavg()
    outcomes = asyncio.run(flood())
    slowest, statuses = 0.0, Counter()
    with httpx.Client(base_url=base_url, headers={"Authorization": f"Bearer {token}"}, timeout=10) as client:
        for _ in range(20):
            asked = time.monotonic()
            try:
                statuses[str(client.get(f"/api/v1/jobs/{job_id}").status_code)] += 1
            except httpx.HTTPError as error:
                statuses[type(error).__name__] += 1
            slowest = max(slowest, time.monotonic() - asked)
    flooded = json.dumps(dict(sorted(outcomes.items())))
    print(f"\n--- {connections} concurrent health requests for {seconds:.0f} s: {flooded}")
    print(
        f"then 20 reads: {json.dumps(dict(statuses))}, the slowest {slowest * 1000:.0f} ms; load average "
        f"{' '.join(f'{v:.2f}' for v in load_before)} before, {' '.join(f'{v:.2f}' for v in os.getloadavg())} after"
    )
    served = statuses.get("200", 0) == 20 and slowest <= 2.0
    print("health flood target (every later request served normally): " + ("met" if served else "missed"))
    return 0 if served else 1


def run_load(
    system: System,
    args: argparse.Namespace,
    admin: httpx.Client,
    tokens: list[str],
    probe_token: str,
    job: dict,
    second: int,
    spec: dict,
    running: list[str],
    *,
    rate: float,
    duration_s: float,
) -> int:
    """One load at `rate` requests/s for `duration_s` while the second demo's topography jobs run; prints its
    figures; 1 when a target is missed."""
    args = argparse.Namespace(**{**vars(args), "rate": rate, "duration": duration_s})
    api = system.api_processes()
    workers = system.worker_processes()
    rss_before, api_cpu_before, worker_cpu_before = rss_bytes(api), cpu_s(api), cpu_s(workers)
    each_before = {process.pid: cpu_s([process]) for process in serving(api)}
    load_before = os.getloadavg()
    start_at = time.time() + 3.0  # every client process started by then
    # One topography of 200 frames takes a few seconds: the keeper starts more, so that one always runs.
    keeper = TopographyKeeper(system.base_url, tokens[0], second, spec, frames=args.running_frames)
    keeper.start()
    profilers = _start_profilers(args, serving(api), duration_s=duration_s + 3.0)
    try:
        results, probed, elapsed = load(
            system.base_url, tokens, probe_token, job["id"], running, rate=args.rate,
            duration_s=args.duration, connections=args.connections, seed=args.seed, start_at=start_at,
            heavy=args.test_frames if args.mix == "heavy" else 0,
        )  # fmt: skip
        recovered_s = recovery_s(system.base_url, tokens[0], job["id"])
    finally:
        keeper.stop()
        for profiler in profilers:
            profiler.wait()
    load_after = os.getloadavg()
    api = system.api_processes()  # the same ones unless one was restarted (then the figure says so)
    serving_count = len(serving(api))
    # How evenly the kernel spread the connections: each serving process's share of the CPU time.
    each_cpu = [cpu_s([process]) - each_before.get(process.pid, 0.0) for process in serving(api)]
    rss_after, api_cpu, worker_cpu = (
        rss_bytes(api),
        cpu_s(api) - api_cpu_before,
        cpu_s(workers) - worker_cpu_before,
    )
    try:
        second_jobs = (
            admin.get("/api/v1/jobs", params={"experiment_id": second, "limit": 100}).raise_for_status().json()
        )
        states = Counter(f"{j['kind']}:{j['state']}" for j in second_jobs["items"])
        spans = {f"{j['kind']} {j['id'][:6]}": (j["started_at"], j["finished_at"])
                 for j in second_jobs["items"]}  # fmt: skip
    except httpx.HTTPError as error:  # a server still swamped after the load: say so, keep the figures
        states = Counter({f"unanswered after the load ({type(error).__name__})": 1})
        spans = {}

    outcomes = Counter(outcome for _kind, _latency, outcome, _at in results)
    answered = [latency for _kind, latency, outcome, _at in results if outcome[0].isdigit() and outcome != "503"]
    shed = [latency for _kind, latency, outcome, _at in results if outcome == "503"]
    waited = [latency for _kind, latency, _outcome, _at in results]
    probe_answered = [latency for _kind, latency, outcome, _at in probed if outcome[0].isdigit()]
    probe_outcomes = Counter(outcome for _kind, _latency, outcome, _at in probed)
    server_errors = sum(count for outcome, count in (outcomes + probe_outcomes).items()
                        if outcome.startswith("5") and outcome != "503")  # fmt: skip
    timeouts = outcomes.get("timeout", 0) + probe_outcomes.get("timeout", 0)
    failures = sum(count for outcome, count in (outcomes + probe_outcomes).items() if outcome.startswith("error"))
    p50, p99 = percentile(answered, 50), percentile(answered, 99)
    growth = (rss_after - rss_before) / rss_before
    sent_s = max(at for *_rest, at in results) - min(at for *_rest, at in results)
    print(f"load: {len(results)} requests sent over {sent_s:.1f} s ({len(results) / sent_s:.0f}/s, asked "
          f"{args.rate:.0f}/s; the last answered at {elapsed:.1f} s) "
          f"from {CLIENT_PROCESSES} client processes, at most {args.connections} connections, {len(USERS)} users; "
          f"web server: {serving_count} processes")  # fmt: skip
    print(f"answers: {json.dumps(dict(sorted(outcomes.items())))}")
    by_kind = Counter(kind for kind, _latency, _outcome, _at in results)
    print(f"mix: {json.dumps(dict(sorted(by_kind.items())))}")
    print(f"5xx: {server_errors}   timeouts: {timeouts}   connection errors: {failures}   "
          f"429: {outcomes.get('429', 0) + probe_outcomes.get('429', 0)}")  # fmt: skip
    print(f"latency of what was served (not 503): p50 {p50 * 1000:.0f} ms   p99 {p99 * 1000:.0f} ms   "
          f"max {max(answered) * 1000:.0f} ms")  # fmt: skip
    shed_p99 = percentile(shed, 99) if shed else 0.0
    print(f"shed: {len(shed)} answered 503 (busy), p99 {shed_p99 * 1000:.0f} ms; longest wait for any answer "
          f"{max(waited) * 1000:.0f} ms; after the load, served normally again within {recovered_s:.1f} s")  # fmt: skip
    for kind in sorted(by_kind):
        of_kind = [latency for k, latency, outcome, _at in results if k == kind and outcome[0].isdigit()]
        kind_p50, kind_p99 = percentile(of_kind, 50), percentile(of_kind, 99)
        print(f"  {kind:>8}: p50 {kind_p50 * 1000:4.0f} ms   p99 {kind_p99 * 1000:5.0f} ms")
    if probe_answered:
        probe_p50, probe_p99 = percentile(probe_answered, 50), percentile(probe_answered, 99)
        print(f"probe (one job every {PROBE_INTERVAL_S * 1000:.0f} ms, {len(probed)} asked): "
              f"p50 {probe_p50 * 1000:.0f} ms   p99 {probe_p99 * 1000:.0f} ms   max {max(probe_answered) * 1000:.0f} ms"
              f"   {json.dumps(dict(sorted(probe_outcomes.items())))}")  # fmt: skip
    slow_at = Counter(int(at - start_at) for _kind, latency, _outcome, at in results + probed if latency > 0.5)
    if slow_at:
        print(f"seconds of the load (from 0) with answers over 500 ms, and how many: {dict(sorted(slow_at.items()))}")
    print(f"web server RSS: {rss_before / 2**20:.0f} MiB -> {rss_after / 2**20:.0f} MiB ({growth * 100:+.1f} %)")
    per_request_ms = api_cpu / max(1, len(results) + len(probed)) * 1000
    by_process = " ".join(f"{t:.1f}" for t in each_cpu)
    print(f"CPU during the load: web server {api_cpu:.1f} s ({per_request_ms:.1f} ms per request; by process "
          f"{by_process} s), worker {worker_cpu:.1f} s")  # fmt: skip
    print(f"jobs of the demo run during the load: {dict(states)}")
    ran = []
    for kind, (begun, ended) in spans.items():
        ran.append(f"{kind} {_load_s(begun, start_at)} to {_load_s(ended, start_at)} s")
    print(f"  the load ran from 0 to {elapsed:.0f} s; the jobs: {'; '.join(ran)}")
    covered = _covered_s([span for kind, span in spans.items() if kind.startswith("topography")], start_at, elapsed)
    print(f"  a topography job ran during {covered / elapsed * 100:.0f} % of the load ({keeper.started} started by it)")
    print(f"load average (1/5/15 min): before {' '.join(f'{v:.2f}' for v in load_before)}, "
          f"after {' '.join(f'{v:.2f}' for v in load_after)}; {os.cpu_count()} CPUs")  # fmt: skip
    if args.mix == "standard":
        targets = (("0 × 5xx", server_errors == 0), ("no timeouts", timeouts == 0 and failures == 0),
                   ("p99 < 500 ms", p99 < 0.5), ("memory growth < 20 %", growth < 0.2))  # fmt: skip
    else:  # issue 26: no 5xx but 503, p99 < 1 s for what is served, 503 within 100 ms, no wait over 2 s
        targets = (("0 × 5xx but 503", server_errors == 0), ("no timeouts", timeouts == 0 and failures == 0),
                   ("p99 < 1 s", p99 < 1.0), ("503 p99 < 100 ms", shed_p99 < 0.1),
                   ("no wait > 2 s", max(waited) <= 2.0), ("serving within 5 s after", recovered_s <= 5.0))  # fmt: skip
    missed = [name for name, ok in targets if not ok]
    print("targets: all met" if not missed else f"targets missed: {', '.join(missed)}")
    return 1 if missed else 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rate", type=float, default=200.0, help="requests per second")
    parser.add_argument("--duration", type=float, default=30.0, help="seconds of load")
    parser.add_argument("--connections", type=int, default=100, help="concurrent connections at most")
    parser.add_argument("--test-frames", type=int, default=8, help="frames of the first demo's simulated test")
    parser.add_argument(
        "--running-frames",
        type=int,
        default=48,
        help="frames of the second demo's test: enough that its topography runs through the load",
    )
    parser.add_argument("--seed", type=int, default=16)
    parser.add_argument(
        "--mix",
        choices=("standard", "heavy"),
        default="standard",
        help="heavy: grids of random frames, profiles of random lines, 50-job lists (issue 26)",
    )
    parser.add_argument(
        "--then",
        action="append",
        default=[],
        metavar="RATE:SECONDS",
        help="another load after the first, on the same server (repeatable; e.g. 500:20)",
    )
    parser.add_argument("--pause", type=float, default=5.0, help="seconds between the loads")
    parser.add_argument(
        "--health-flood",
        type=int,
        default=0,
        metavar="N",
        help="at the end, N concurrent health requests, then normal requests",
    )
    parser.add_argument("--api-processes", type=int, default=2, help="web server processes")
    parser.add_argument("--api-threads", type=int, default=0, help="FRINGELAB_API_THREADS (0: the default)")
    parser.add_argument("--api-queue", type=int, default=-1, help="FRINGELAB_API_QUEUE (-1: the default)")
    parser.add_argument("--profile", metavar="DIR", help="sample the web server with py-spy during each load into DIR")
    parser.add_argument(
        "--env",
        action="append",
        default=[],
        metavar="FRINGELAB_NAME=VALUE",
        help="another setting of the system under test (repeatable), e.g. FRINGELAB_WORKER_NICE=19",
    )
    args = parser.parse_args()

    with tempfile.TemporaryDirectory(prefix="fringelab-bench-load-") as temp:
        system = System(Path(temp) / "var")
        Path(temp, "var").mkdir()
        system.env["FRINGELAB_API_PROCESSES"] = str(args.api_processes)
        if args.api_threads:
            system.env["FRINGELAB_API_THREADS"] = str(args.api_threads)
        if args.api_queue >= 0:
            system.env["FRINGELAB_API_QUEUE"] = str(args.api_queue)
        for setting in args.env:
            name, _, value = setting.partition("=")
            system.env[name] = value
        for name in (*USERS, PROBE_USER):
            flags = ["--admin"] if name in ADMINS or name == PROBE_USER else []
            cli(system.env, "user", "add", name, *flags, "--password-stdin", stdin=f"{name}-password-16\n")
        tokens = [cli(system.env, "token", "create", name, "--name", "bench") for name in USERS]
        probe_token = cli(system.env, "token", "create", PROBE_USER, "--name", "bench")
        try:
            system.start()
            setup_started = time.monotonic()
            admin = httpx.Client(base_url=system.base_url, headers={"Authorization": f"Bearer {tokens[0]}"},
                                 timeout=30)  # fmt: skip
            first = demo(admin, test_frames=args.test_frames)
            job = wait(lambda: topography_job(admin, first, finished=True), timeout_s=SETUP_TIMEOUT_S,
                       what="finished topography job of the first demo", interval_s=2)  # fmt: skip
            print(f"setup: first demo measured in {time.monotonic() - setup_started:.0f} s; web server settings: "
                  f"{' '.join(f'{k}={v}' for k, v in sorted(system.env.items()) if k.startswith('FRINGELAB_'))}",
                  flush=True)  # fmt: skip
            second = demo(admin, test_frames=args.running_frames)
            # The load starts once the second demo's topography job runs (its ingest and calibrations first).
            wait(lambda: _topography_running(admin, second), timeout_s=SETUP_TIMEOUT_S,
                 what="running topography job of the second demo", interval_s=0.5)  # fmt: skip
            spec = topography_job(admin, second, finished=False)["spec"]  # type: ignore[index]
            running = running_jobs(admin, second)
            share_with_members(admin, [first, second])
            # The first load, then each --then on the same server after a pause: one report block each.
            loads = [
                (args.rate, args.duration),
                *((float(r), float(d)) for r, _, d in (t.partition(":") for t in args.then)),
            ]
            missed = 0
            for number, (rate, duration_s) in enumerate(loads):
                if number:
                    time.sleep(args.pause)
                    print(f"\n--- then {rate:g}/s for {duration_s:g} s", flush=True)
                missed |= run_load(system, args, admin, tokens, probe_token, job, second, spec, running, rate=rate,
                                   duration_s=duration_s)  # fmt: skip
            if args.health_flood:
                missed |= health_flood(system.base_url, tokens[0], job["id"], connections=args.health_flood)
            admin.close()
        finally:
            system.stop()
    return missed


if __name__ == "__main__":
    sys.exit(main())
