"""Benchmark of the job system: topography throughput with 1 and 2 worker processes on the same recording (scaling
efficiency), and the end-to-end time from the first upload to the last frame's result.

Run from the repository root:
  .venv/bin/python bench/bench_jobs.py [--kind topography|selftest] [--frames 160] [--repeat 3]

It starts what a lab machine runs, on a scratch data directory: its own redis-server, a migrated SQLite
database, the API (in this process) and `fringelab worker` subprocesses (prefork, as users run them, one BLAS
thread each). With --kind topography it writes the virtual test (`fringelab virtual-test`, kodak preset,
512 x 480 px, as ZIPs; not timed), then times, with the most worker processes asked for: creating the experiment
and camera, uploading the three recordings and their ingest, the camera and projector calibrations, and the
topography (end to end). Then --repeat times, one round after the other: the science pipeline alone
(`topography_recording` in this process, the same recording and calibrations, all on one thread: OpenCV's, and the
writer's compression too, which the command line runs in 2 threads beside), and for each worker count the same
topography as a job, each printed as it ends:

  round       which repetition
  workers     worker processes (one `fringelab worker --concurrency N`); "pipeline" for the science alone;
              "N x pl" for N copies of it at once, each in a process of its own (the machine's ceiling: how
              much N processes with no job system between them get from its cores)
  frames      frames of the job, in chunks of --chunk-frames (default: the job's own choice, see README)
  run s       from the job's start to its end (job record: started_at .. finished_at)
  frames/s    frames / run s
  cpu s       CPU seconds (user + system) the worker processes (or this process, for the pipeline) spent on it:
              what the job costs whatever else runs on the machine
  parallel s  of which the reference (frame 0) and the fan-out ran (every frame measured on its own: edges,
              fringe order, Z, X, Y, grids of Z and σ, packed as stored; in chunks on every process), until the
              last chunk ended; the pass in frame order writes the file meanwhile
  in order s  and what the pass in frame order had left after that (the last chunk's frames, closing the file,
              its checksum)
  peak MB     the largest peak resident memory (VmHWM) of the worker processes (flat in the number of frames:
              compare --frames 40 with --frames 320)
  spread      frames each worker process measured
  load        the 1-minute load average when it ended

With --schedule, each job's chunks follow its line (the process that measured each, its start and end from the
job's start), and the CPU seconds of each worker process. Before each timed job, short topographies run until
every pool process has measured a chunk (`warm_up`), as on a worker that has run a job before.

then, per round and as the median over the rounds (ratios taken within a round, of runs seconds apart: on shared
cores the load still moves between them, and the CPU-time ratio is the steadier figure): the scaling efficiency,
(frames/s with N) / (N x frames/s with 1), and the job with one worker process against the science pipeline alone,
(job frames/s with 1) / (pipeline frames/s), by wall time and by CPU time, and the ceiling the machine sets on
the efficiency, (frames/s of N pipelines at once) / (N x frames/s of one, in a process of its own), with the
efficiency against it. --kind selftest measures the job system alone (synthetic frames, an FFT each;
--frame-size-px sets the work per frame). On a machine whose cores are shared with other work the efficiency says
so: `os.cpu_count()` and the load average are printed.
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from datetime import datetime
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import redis  # noqa: E402
from fastapi.testclient import TestClient  # noqa: E402

from backend.app import create_app  # noqa: E402
from backend.supervisor import redis_server_binary  # noqa: E402
from fringelab.core.db import upgrade_database  # noqa: E402
from fringelab.core.jobs import as_utc  # noqa: E402
from fringelab.core.queue import create_celery  # noqa: E402
from fringelab.core.settings import Settings  # noqa: E402
from fringelab.core.startup_checks import free_port  # noqa: E402


def wait(predicate: Any, *, timeout_s: float, what: str, interval_s: float = 0.05) -> Any:
    deadline = time.monotonic() + timeout_s
    while not (value := predicate()):
        if time.monotonic() > deadline:
            raise TimeoutError(f"timed out after {timeout_s} s waiting for {what}")
        time.sleep(interval_s)
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

    @staticmethod
    def cpu_s(worker: subprocess.Popen[bytes]) -> dict[int, float]:
        """CPU seconds (user + system) the worker's main process and each pool process spent so far, by PID."""
        import psutil

        main = psutil.Process(worker.pid)
        spent = {}
        for process in [main, *main.children(recursive=True)]:
            try:
                times = process.cpu_times()
            except psutil.NoSuchProcess:
                continue
            spent[process.pid] = times.user + times.system
        return spent

    @staticmethod
    def peak_rss_mb(worker: subprocess.Popen[bytes]) -> float:
        """The largest peak resident memory (VmHWM) of the worker's processes, MB."""
        import psutil

        peak = 0.0
        for process in psutil.Process(worker.pid).children(recursive=True):
            try:
                status = Path(f"/proc/{process.pid}/status").read_text()
            except OSError:
                continue
            for line in status.splitlines():
                if line.startswith("VmHWM:"):
                    peak = max(peak, int(line.split()[1]) / 1024)
        return peak

    def run(self, spec: dict[str, Any], *, timeout_s: float, poll_s: float = 0.05) -> tuple[dict[str, Any], float]:
        start = time.perf_counter()
        created = self.client.post("/api/v1/jobs", json=spec)
        created.raise_for_status()
        job_id = created.json()["id"]

        def ended() -> dict[str, Any] | None:
            job = self.client.get(f"/api/v1/jobs/{job_id}").json()
            return job if job["state"] in ("succeeded", "failed", "cancelled") else None

        job = wait(ended, timeout_s=timeout_s, what=f"job {job_id}", interval_s=poll_s)
        elapsed = time.perf_counter() - start
        if job["state"] != "succeeded":
            raise RuntimeError(f"job {job_id} {job['state']}: {job['error']}")
        return job, elapsed

    def close(self) -> None:
        self.client.__exit__(None, None, None)
        self.redis.terminate()
        self.redis.wait(timeout=10)


def _moment(text: str | None) -> datetime:
    assert text is not None
    return as_utc(datetime.fromisoformat(text))  # type: ignore[return-value]


def timings(job: dict[str, Any]) -> tuple[float, float, float]:
    """(run, parallel, in frame order) seconds of a finished chunked job: the phases' chunks from the first start
    to the last end are the parallel parts, the gaps between them (the merges) the parts in frame order."""
    started, finished = _moment(job["started_at"]), _moment(job["finished_at"])
    parallel = 0.0
    for phase in sorted({c["phase"] for c in job["chunks"]}):
        chunks = [c for c in job["chunks"] if c["phase"] == phase]
        begin = started if phase == 0 else min(_moment(c["started_at"]) for c in chunks)
        parallel += (max(_moment(c["finished_at"]) for c in chunks) - begin).total_seconds()
    run = (finished - started).total_seconds()
    return run, parallel, run - parallel


def schedule(job: dict[str, Any]) -> str:
    """A finished job's chunks, one line each: frames, the process that measured it, its start and end (s from
    the job's start)."""
    started = _moment(job["started_at"])
    lines = []
    for c in sorted(job["chunks"], key=lambda c: (c["phase"], c["index"])):
        begin = (_moment(c["started_at"]) - started).total_seconds()
        end = (_moment(c["finished_at"]) - started).total_seconds()
        lines.append(f"      chunk {c['index']:>3} frames {c['first_frame']:>5}..{c['stop_frame'] - 1:<5} "
                     f"{c['worker']:>32} {begin:6.3f} .. {end:6.3f} s")  # fmt: skip
    lines.append(f"      job ends {(_moment(job['finished_at']) - started).total_seconds():.3f} s")
    return "\n".join(lines)


def upload_virtual_experiment(bench: Bench, frames: int) -> dict[str, Any]:
    """A virtual test (`fringelab virtual-test`, kodak, as ZIPs; not timed), then timed: experiment, camera and
    the three uploads through the API, until each recording is ready (ingested)."""
    import json

    from fringelab.pipelines.virtual_test import write_virtual_test
    from fringelab.science.virtual_test import calibration_heights_mm

    virtual = write_virtual_test(
        bench.root / "virtual", "kodak", n_test_frames=frames, calibration_z_mm=calibration_heights_mm(4.0),
        as_zip=True,
    )  # fmt: skip
    truth = json.loads(virtual.truth_json.read_text())
    client = bench.client
    start = time.perf_counter()
    experiment = client.post("/api/v1/experiments", json={"name": "bench"}).json()
    camera = client.post(f"/api/v1/experiments/{experiment['id']}/cameras", json={
        "name": "kodak", "image_width_px": 512, "image_height_px": 480,
        "pixel_pitch_um": 1000.0 / truth["camera"]["du_px_per_mm"]}).json()  # fmt: skip
    ids: dict[str, Any] = {"scale_on": truth["camera"]["scale_on"]}
    for kind in ("camera_calibration", "projector_calibration", "test"):
        path = getattr(virtual, kind)
        with path.open("rb") as body:
            uploaded = client.put(f"/api/v1/uploads/cameras/{camera['id']}/{path.name}", params={"kind": kind},
                                  content=body.read())  # fmt: skip
        uploaded.raise_for_status()
        ids[kind] = uploaded.json()["id"]
    for kind in ("camera_calibration", "projector_calibration", "test"):
        recording = wait(lambda i=ids[kind]: (r := client.get(f"/api/v1/recordings/{i}").json())["state"] in
                         ("ready", "invalid") and r, timeout_s=1800, what=f"the {kind} ingest")  # fmt: skip
        if recording["state"] != "ready":
            raise RuntimeError(f"the {kind} recording is {recording['state']}: {recording['error']}")
    ids["upload_s"] = time.perf_counter() - start
    ids["test_path"] = virtual.test
    return ids


def calibrate(bench: Bench, ids: dict[str, Any]) -> tuple[dict[str, Any], float]:
    """Camera then projector calibration; the topography spec that uses them, and the seconds they took."""
    start = time.perf_counter()
    camera, _ = bench.run({"kind": "camera_calibration", "recording_id": ids["camera_calibration"],
                           "scale_on": ids["scale_on"]}, timeout_s=1800)  # fmt: skip
    projector, _ = bench.run({"kind": "projector_calibration", "recording_id": ids["projector_calibration"],
                              "camera_calibration_id": camera["result"]["calibration_id"]}, timeout_s=1800)  # fmt: skip
    spec = {"kind": "topography", "recording_id": ids["test"],
            "camera_calibration_id": camera["result"]["calibration_id"],
            "projector_calibration_id": projector["result"]["calibration_id"]}  # fmt: skip
    results = bench.settings.data_path / "results" / "jobs"
    ids["camera_json"] = results / camera["id"] / "camera.json"
    ids["projector_h5"] = results / projector["id"] / "projector.h5"
    return spec, time.perf_counter() - start


def pipeline_run(ids: dict[str, Any], out_path: Path, *, warm_up: bool, ready: Any = None) -> tuple[float, float]:
    """Seconds and CPU seconds of the science pipeline alone, in this process on one thread: the job's reference
    figure (a worker process, too, runs one frame at a time on one thread). warm_up: 4 frames first (compiled code
    loaded, tables built: as in a worker that has run a job before); ready: called just before the timing."""
    import cv2

    from fringelab.formats.camera import read_camera_json
    from fringelab.formats.projector import read_projector_calibration
    from fringelab.formats.recordings import open_recording
    from fringelab.pipelines.topography import topography_recording

    cv2.setNumThreads(1)
    camera, projector = read_camera_json(ids["camera_json"]), read_projector_calibration(ids["projector_h5"])
    if warm_up:
        topography_recording(open_recording(ids["test_path"]), camera, projector, out_path=out_path, frames=range(4),
                             writer_threads=0)  # fmt: skip
    if ready is not None:
        ready()
    start, cpu = time.perf_counter(), time.process_time()
    topography_recording(open_recording(ids["test_path"]), camera, projector, out_path=out_path, writer_threads=0)
    elapsed, cpu = time.perf_counter() - start, time.process_time() - cpu
    out_path.unlink()
    return elapsed, cpu


def _pipeline_in_a_process(ids: dict[str, Any], out_path: Path, start: Any, elapsed_s: Any) -> None:
    """One copy of `pipeline_run` in a process of its own: warmed up, then timed from when every copy is ready."""
    elapsed_s.value, _ = pipeline_run(ids, out_path, warm_up=True, ready=start.wait)


def pipelines_at_once(ids: dict[str, Any], copies: int) -> float:
    """Seconds until `copies` science pipelines, each in a process of its own on one thread, started together,
    have all ended: what the machine's cores give N independent copies (shared caches, memory bandwidth, a VM's
    neighbours), the ceiling of the job system's scaling efficiency on this machine."""
    import multiprocessing

    spawn = multiprocessing.get_context("spawn")  # this process runs threads (the API client): no fork
    start = spawn.Barrier(copies)
    elapsed = [spawn.Value("d", 0.0) for _ in range(copies)]
    parent = Path(ids["camera_json"]).parent
    processes = [
        spawn.Process(target=_pipeline_in_a_process, args=(ids, parent / f"copy-{i}.h5", start, elapsed[i]))
        for i in range(copies)
    ]
    for process in processes:
        process.start()
    for process in processes:
        process.join()
        if process.exitcode != 0:
            raise RuntimeError(f"a pipeline copy failed (exit code {process.exitcode})")
    return max(value.value for value in elapsed)


def warm_up(bench: Bench, spec: dict[str, Any], processes: int, *, tries: int = 5) -> None:
    """Short topographies until every pool process has measured a chunk (read the calibrations, built the tables,
    loaded the compiled code), as on a worker that has run a job before. Which process takes which chunk is the
    queue's choice (the merge's process measures only chunks nobody has started), so one run may not reach all."""
    measured: set[str] = set()
    for _ in range(tries):
        job, _ = bench.run(spec | {"frames": {"first": 0, "last": 4 * processes - 1}, "chunk_frames": 1},
                           timeout_s=600)  # fmt: skip
        measured |= {c["worker"] for c in job["chunks"]}
        if len(measured) >= processes:
            return
    print(f"warning: only {len(measured)} of {processes} worker processes measured a chunk in the warm-up")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--kind", choices=("topography", "selftest"), default="topography")
    parser.add_argument("--frames", type=int, default=None, help="frames of the job (topography 160, selftest 400)")
    parser.add_argument("--frame-size-px", type=int, default=512, help="selftest work per frame (512: ~10 ms)")
    parser.add_argument("--chunk-frames", type=int, default=None, help="frames per chunk (topography: the job's own)")
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2], help="worker process counts to measure")
    parser.add_argument("--repeat", type=int, default=3, help="rounds of measurements (medians are printed)")
    parser.add_argument("--keep", action="store_true", help="keep the scratch directory")
    parser.add_argument("--schedule", action="store_true", help="print each timed job's chunks: who, when")
    args = parser.parse_args()
    topography = args.kind == "topography"
    frames = args.frames or (160 if topography else 400)
    # topography: the job's own choice (FRINGELAB_CHUNK_FRAMES at its default, split for a short job) unless asked
    chunk_frames = args.chunk_frames or (0 if topography else 25)
    chunking = f"chunks of {chunk_frames} frames" if chunk_frames else "chunks of the job's choice"

    root = Path(tempfile.mkdtemp(prefix="fringelab-bench-jobs-"))
    bench = Bench(root, chunk_frames=chunk_frames or Settings.model_fields["chunk_frames"].default)
    print(f"machine: {os.cpu_count()} CPU cores, load average {os.getloadavg()[0]:.2f}; scratch {root}")
    try:
        if topography:
            print(f"job: topography of the virtual kodak experiment, {frames} frames of 512 x 480 px, {chunking}")
            worker = bench.start_worker(max(args.workers))
            try:
                ids = upload_virtual_experiment(bench, frames)
                spec, calibration_s = calibrate(bench, ids)
                if args.chunk_frames:
                    spec["chunk_frames"] = args.chunk_frames
                job, topography_s = bench.run(spec, timeout_s=3600)
            finally:
                bench.stop_worker(worker)
            total_s = ids["upload_s"] + calibration_s + topography_s
            print(f"end to end with {max(args.workers)} processes, from the first upload to the last frame's result: "
                  f"{total_s:.1f} s (uploads and ingest {ids['upload_s']:.1f} s, calibrations {calibration_s:.1f} s, "
                  f"topography {topography_s:.1f} s)\n")  # fmt: skip
        else:
            spec = {"kind": "selftest", "frames": frames, "frame_size_px": args.frame_size_px}
            print(f"job: selftest, {frames} frames of {args.frame_size_px} px, {chunking}\n")
        print(f"{'round':>5} {'workers':>8} {'frames':>6} {'run s':>7} {'frames/s':>8} {'cpu s':>7} {'parallel s':>10} "
              f"{'in order s':>10} {'peak MB':>7} {'load':>5}  spread")  # fmt: skip
        rounds: list[dict[Any, tuple[float, float]]] = []  # per round: workers (0: pipeline) -> (frames/s, cpu s)
        for round_ in range(1, args.repeat + 1):
            measured: dict[Any, tuple[float, float]] = {}
            if topography:
                pipeline_s, pipeline_cpu_s = pipeline_run(ids, Path(ids["camera_json"]).parent / "pipeline.h5",
                                                          warm_up=round_ == 1)  # fmt: skip
                measured[0] = (frames / pipeline_s, pipeline_cpu_s)
                print(f"{round_:>5} {'pipeline':>8} {frames:>6} {pipeline_s:>7.2f} {frames / pipeline_s:>8.2f} "
                      f"{pipeline_cpu_s:>7.2f} {'':>10} {'':>10} {'':>7} {os.getloadavg()[0]:>5.2f}")  # fmt: skip
                for copies in sorted({1, *args.workers}):
                    copies_s = pipelines_at_once(ids, copies)
                    measured[("copies", copies)] = (copies * frames / copies_s, 0.0)
                    print(f"{round_:>5} {f'{copies} x pl':>8} {copies * frames:>6} {copies_s:>7.2f} "
                          f"{copies * frames / copies_s:>8.2f} {'':>7} {'':>10} {'':>10} {'':>7} "
                          f"{os.getloadavg()[0]:>5.2f}")  # fmt: skip
            for processes in args.workers:
                worker = bench.start_worker(processes)
                try:  # a small job first, so every pool process has imported the science before the timing
                    bench.run({"kind": "selftest", "frames": 4 * processes, "chunk_frames": 1}, timeout_s=600)
                    if topography:  # and has read the calibrations and compiled what it runs, as after a first job
                        warm_up(bench, spec, processes)
                    cpu_before = bench.cpu_s(worker)
                    # its times come from its record: a slow poll loses nothing and takes less from the workers' cores
                    job, _ = bench.run(spec, timeout_s=3600, poll_s=0.25)
                    cpu_after = bench.cpu_s(worker)
                    cpu_by_pid = {pid: spent - cpu_before.get(pid, 0.0) for pid, spent in cpu_after.items()}
                    cpu_s = sum(cpu_by_pid.values())
                    peak_mb = bench.peak_rss_mb(worker)
                finally:
                    bench.stop_worker(worker)
                run_s, parallel_s, in_order_s = timings(job)
                measured[processes] = (frames / run_s, cpu_s)
                spread: dict[str, int] = {}
                for chunk in (c for c in job["chunks"] if c["phase"] == 0):
                    n = chunk["stop_frame"] - chunk["first_frame"]
                    spread[chunk["worker"]] = spread.get(chunk["worker"], 0) + n
                shares = " ".join(str(n) for n in sorted(spread.values(), reverse=True))
                print(f"{round_:>5} {processes:>8} {frames:>6} {run_s:>7.2f} {frames / run_s:>8.2f} {cpu_s:>7.2f} "
                      f"{parallel_s:>10.2f} {in_order_s:>10.2f} {peak_mb:>7.0f} {os.getloadavg()[0]:>5.2f}  "
                      f"{shares}")  # fmt: skip
                if args.schedule:
                    print(schedule(job))
                    print(
                        "      cpu s by process: "
                        + ", ".join(f"{pid} {v:.2f}" for pid, v in sorted(cpu_by_pid.items()))
                    )
            rounds.append(measured)
    finally:
        bench.close()
        if not args.keep:
            shutil.rmtree(root, ignore_errors=True)
    report(rounds, args.workers)
    print(f"load average at the end {os.getloadavg()[0]:.2f} (1, 5, 15 min: {os.getloadavg()})")
    return 0


def report(rounds: list[dict[Any, tuple[float, float]]], workers: list[int]) -> None:
    """The ratios of each round and their medians over the rounds."""

    def line(name: str, values: list[float]) -> None:
        if values:
            each = ", ".join(f"{v:.2f}" for v in values)
            print(f"{name}: median {statistics.median(values):.2f} (rounds: {each})")

    def efficiency(r: dict[Any, tuple[float, float]], n: int) -> float:
        return r[n][0] / (n * r[1][0])

    def ceiling(r: dict[Any, tuple[float, float]], n: int) -> float:
        return r[("copies", n)][0] / (n * r[("copies", 1)][0])

    print()
    for n in (n for n in workers if n > 1):
        line(f"scaling efficiency with {n} processes", [efficiency(r, n) for r in rounds if {1, n} <= r.keys()])
        with_ceiling = [r for r in rounds if {1, n, ("copies", 1), ("copies", n)} <= r.keys()]
        line(f"ceiling: {n} pipelines at once, each in its own process / {n} x one alone, frames/s",
             [ceiling(r, n) for r in with_ceiling])  # fmt: skip
        line(f"scaling efficiency with {n} processes / the ceiling",
             [efficiency(r, n) / ceiling(r, n) for r in with_ceiling])  # fmt: skip
    line("job with 1 worker process / science pipeline alone, frames/s",
         [r[1][0] / r[0][0] for r in rounds if 0 in r and 1 in r])  # fmt: skip
    line("science pipeline alone / job with 1 worker process, CPU s",
         [r[0][1] / r[1][1] for r in rounds if 0 in r and 1 in r])  # fmt: skip
    for processes in workers:
        line(f"frames/s with {processes} worker process(es)", [r[processes][0] for r in rounds if processes in r])
    line("science pipeline alone, frames/s", [r[0][0] for r in rounds if 0 in r])


if __name__ == "__main__":
    raise SystemExit(main())
