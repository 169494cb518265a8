"""Benchmark of the job system: throughput of one chunked job with 1 and 2 worker processes (scaling efficiency).

Run from the repository root:  .venv/bin/python bench/bench_jobs.py [--frames 400] [--frame-size-px 512]

It starts what a lab machine runs, on a scratch data directory: its own redis-server, a migrated SQLite
database, the API (in this process) and `fringelab worker` subprocesses (prefork, as users run them, one BLAS
thread each). For each worker count it submits the same job through the API, waits for the end, and prints

  workers   worker processes (one `fringelab worker --concurrency N`)
  frames    frames of the job, in chunks of --chunk-frames
  run s     from the job's start to its end (job record: started_at .. finished_at)
  frames/s  frames / run s
  queue s   from POST /jobs to the end, as a user waits
  spread    frames computed per worker process (from the chunks' records)

and the scaling efficiency, (frames/s with N) / (N × frames/s with 1). The job is a `selftest` (synthetic
frames, an FFT each: per-frame work without any upload); set --frame-size-px to make a frame cost about what a
topography frame does. Expect an efficiency near 1 on a machine with idle cores, and less where other work
shares them (the figure says so: `os.cpu_count()` and the load average are printed).
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import redis  # noqa: E402
from fastapi.testclient import TestClient  # noqa: E402

from backend.app import create_app  # noqa: E402
from backend.db import upgrade_database  # noqa: E402
from backend.jobs import as_utc  # noqa: E402
from backend.services import free_port  # noqa: E402
from backend.settings import Settings  # noqa: E402
from backend.supervisor import redis_server_binary  # noqa: E402
from worker.celery_app import create_celery  # noqa: E402


def wait(predicate: Any, *, timeout_s: float, what: str) -> Any:
    deadline = time.monotonic() + timeout_s
    while not (value := predicate()):
        if time.monotonic() > deadline:
            raise TimeoutError(f"timed out after {timeout_s} s waiting for {what}")
        time.sleep(0.05)
    return value


class Bench:
    """A scratch fringelab: Redis, database, API client; workers started and stopped per measurement."""

    def __init__(self, root: Path, *, chunk_frames: int) -> None:
        self.root = root
        port = free_port()
        self.redis = subprocess.Popen(
            [redis_server_binary(), "--port", str(port), "--bind", "127.0.0.1", "--save", "", "--appendonly", "no",
             "--dir", str(root)],
            stdout=subprocess.DEVNULL,
        )  # fmt: skip
        self.settings = Settings(  # type: ignore[call-arg]
            _env_file=None, data_dir=root / "var", redis_url=f"redis://127.0.0.1:{port}/0", chunk_frames=chunk_frames
        )
        wait(self._redis_up, timeout_s=10, what="redis-server")
        upgrade_database(self.settings.resolved_database_url)
        self.client = TestClient(create_app(self.settings))
        self.client.__enter__()

    def _redis_up(self) -> bool:
        try:
            return bool(redis.Redis.from_url(self.settings.redis_url).ping())
        except redis.ConnectionError:
            return False

    def start_worker(self, processes: int) -> subprocess.Popen[bytes]:
        clean = {k: v for k, v in os.environ.items() if not k.startswith("FRINGELAB_")}
        env = {
            **clean,
            "FRINGELAB_DATA_DIR": str(self.settings.data_path),
            "FRINGELAB_REDIS_URL": self.settings.redis_url,
            "FRINGELAB_WORKER_CONCURRENCY": str(processes),
            "FRINGELAB_CHUNK_FRAMES": str(self.settings.chunk_frames),  # the worker that starts a job splits it
            "FRINGELAB_LOG_LEVEL": os.environ.get("BENCH_LOG_LEVEL", "warning"),
            "OMP_NUM_THREADS": "1",
            "OPENBLAS_NUM_THREADS": "1",
        }
        log = (self.root / f"worker-{processes}.log").open("ab")
        worker = subprocess.Popen(
            [sys.executable, "-m", "backend.cli", "worker"], env=env, stdout=log, stderr=subprocess.STDOUT,
            start_new_session=True, cwd=ROOT,
        )  # fmt: skip
        celery = create_celery(self.settings)
        wait(lambda: any(str(worker.pid) in n for r in celery.control.ping(timeout=0.5) or [] for n in r),
             timeout_s=60, what="the worker")  # fmt: skip
        return worker

    @staticmethod
    def stop_worker(worker: subprocess.Popen[bytes]) -> None:
        os.killpg(worker.pid, signal.SIGTERM)
        worker.wait(timeout=60)

    def run(self, spec: dict[str, Any], *, timeout_s: float) -> tuple[dict[str, Any], float]:
        start = time.perf_counter()
        created = self.client.post("/api/v1/jobs", json=spec)
        created.raise_for_status()
        job_id = created.json()["id"]

        def ended() -> dict[str, Any] | None:
            job = self.client.get(f"/api/v1/jobs/{job_id}").json()
            return job if job["state"] in ("succeeded", "failed", "cancelled") else None

        job = wait(ended, timeout_s=timeout_s, what=f"job {job_id}")
        elapsed = time.perf_counter() - start
        if job["state"] != "succeeded":
            raise RuntimeError(f"job {job_id} {job['state']}: {job['error']}")
        return job, elapsed

    def close(self) -> None:
        self.client.__exit__(None, None, None)
        self.redis.terminate()
        self.redis.wait(timeout=10)


def run_seconds(job: dict[str, Any]) -> float:
    from datetime import datetime

    started = as_utc(datetime.fromisoformat(job["started_at"]))
    finished = as_utc(datetime.fromisoformat(job["finished_at"]))
    return (finished - started).total_seconds()  # type: ignore[operator]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=400)
    parser.add_argument("--frame-size-px", type=int, default=512, help="selftest work per frame (512: ~10 ms)")
    parser.add_argument("--chunk-frames", type=int, default=25)
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2], help="worker process counts to measure")
    parser.add_argument("--keep", action="store_true", help="keep the scratch directory")
    args = parser.parse_args()

    root = Path(tempfile.mkdtemp(prefix="fringelab-bench-jobs-"))
    bench = Bench(root, chunk_frames=args.chunk_frames)
    print(f"machine: {os.cpu_count()} CPU cores, load average {os.getloadavg()[0]:.2f}; scratch {root}")
    print(f"job: selftest, {args.frames} frames of {args.frame_size_px} px, chunks of {args.chunk_frames} frames\n")
    print(f"{'workers':>7} {'frames':>7} {'run s':>8} {'frames/s':>9} {'queue s':>8}  spread")
    rates: dict[int, float] = {}
    try:
        for processes in args.workers:
            worker = bench.start_worker(processes)
            try:
                spec = {"kind": "selftest", "frames": args.frames, "frame_size_px": args.frame_size_px}
                bench.run(spec | {"frames": 2 * args.chunk_frames}, timeout_s=600)  # warm the pool processes
                job, queued_s = bench.run(spec, timeout_s=3600)
            finally:
                bench.stop_worker(worker)
            seconds = run_seconds(job)
            rates[processes] = args.frames / seconds
            spread: dict[str, int] = {}
            for chunk in job["chunks"]:
                spread[chunk["worker"]] = spread.get(chunk["worker"], 0) + chunk["stop_frame"] - chunk["first_frame"]
            shares = " ".join(str(n) for n in sorted(spread.values(), reverse=True))
            print(
                f"{processes:>7} {args.frames:>7} {seconds:>8.2f} {rates[processes]:>9.1f} {queued_s:>8.2f}  {shares}"
            )
    finally:
        bench.close()
        if not args.keep:
            shutil.rmtree(root, ignore_errors=True)
    if 1 in rates:
        for processes, rate in rates.items():
            if processes > 1:
                print(f"\nscaling efficiency with {processes} processes: {rate / (processes * rates[1]):.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
