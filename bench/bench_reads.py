"""CPU per request of the heavy read mix (issue 26) in one web server process, without and with its frame cache.

Run from the repository root:  .venv/bin/python bench/bench_reads.py [--requests 300] [--rounds 4]

The heavy mix that cost 8.2 ms of web CPU per request (issue 26): grids of random frames, profiles along random
lines over 1 to 10 random frames, and 50-job lists; sent through the whole application (Starlette's TestClient,
accounts off, gzip accepted) to a result written as the worker writes one (a 201 × 201 grid, 48 frames, one
gzip-compressed chunk per frame, with holes). The reference is the application as it was before
(FRINGELAB_FRAME_CACHE_BYTES = 0: every frame read and decompressed from the file each time; answers compressed at
gzip level 5; the rendered-answer cache on), run in the same process in alternating rounds, each round from empty
caches and with the same requests. Printed per round and as medians: CPU time per request (of this whole process:
the client's share is the same in both) and wall time per request by kind; plus the load average
(the machine is shared: figures follow it).
"""

from __future__ import annotations

import argparse
import os
import random
import statistics
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import h5py
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests.support import RedisServer  # noqa: E402

FRAMES = 48
GRID_NODES = 201
LIST_JOBS = 60


def write_result(path: Path) -> None:
    """A topography result in the stored layout: a dome rising frame by frame, noise, a hole (NaN)."""
    rng = np.random.default_rng(26)
    x_mm = np.linspace(-50.0, 50.0, GRID_NODES)
    y, x = np.meshgrid(x_mm, x_mm, indexing="ij")
    dome = np.clip(1.0 - (x**2 + y**2) / 45.0**2, 0.0, None)
    z = np.stack([10.0 * (f / FRAMES) * dome + rng.normal(0.0, 0.01, dome.shape) for f in range(FRAMES)])
    z[:, 90:110, 120:140] = np.nan
    z = z.astype(np.float32)
    with h5py.File(path, "w") as out:
        out.attrs["schema"] = "fringelab.topography"
        out.attrs["z_flat_mm"] = 0.0
        out["frames/index"] = np.arange(FRAMES)
        for name in ("time_s", "punch_displacement_mm", "force_kN"):
            out[f"frames/{name}"] = np.arange(FRAMES, dtype=float)
        out["grid/x_mm"], out["grid/y_mm"] = x_mm, x_mm
        for name, values in (("z_mm", z), ("sigma_w_mm", np.where(np.isnan(z), np.nan, 0.02).astype(np.float32))):
            out.create_dataset(f"grid/{name}", data=values, chunks=(1, *values.shape[1:]), compression="gzip")
        out["peak/w_mm"] = np.nanmax(z.reshape(FRAMES, -1), axis=1)
        out["peak/x_mm"] = out["peak/y_mm"] = np.zeros(FRAMES)
        out.create_group("summary").attrs["flat_rms_mm"] = 0.01


def heavy_request(rng: random.Random) -> tuple[str, str, list[tuple[str, object]]]:
    """(kind, path, params): as bench_load's heavy mix (35 % grids, 35 % profiles, 30 % 50-job lists)."""
    pick = rng.random()
    if pick < 0.35:
        return "grid", "/api/v1/jobs/topo-1/topography/grid", [("frame", rng.randrange(FRAMES))]
    if pick < 0.70:
        line = [(name, round(rng.uniform(-45.0, 45.0), 1)) for name in ("x0_mm", "y0_mm", "x1_mm", "y1_mm")]
        picked = rng.sample(range(FRAMES), rng.randint(1, 10))
        return "profile", "/api/v1/jobs/topo-1/topography/profile", [*line, *(("frames", f) for f in picked)]
    return "list", "/api/v1/jobs", [("limit", 50)]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--requests", type=int, default=300, help="requests per round")
    parser.add_argument("--rounds", type=int, default=4, help="rounds of each (reference and cached, alternating)")
    parser.add_argument(
        "--reference-gzip-level",
        type=int,
        default=5,
        help="the reference's gzip level (5: as before; give the current level to see the cache alone)",
    )
    parser.add_argument("--cache-mib", type=int, default=64, help="FRINGELAB_FRAME_CACHE_BYTES of the cached run")
    args = parser.parse_args()
    os.environ["FRINGELAB_ALLOWED_HOSTS"] = "testserver"

    from fastapi.testclient import TestClient

    from backend import cache
    from backend.api.results import ANSWERS
    from backend.app import create_app
    from fringelab.core.db import make_engine, make_sessionmaker, upgrade_database
    from fringelab.core.models import Job
    from fringelab.core.settings import Settings

    with tempfile.TemporaryDirectory(prefix="fringelab-bench-reads-") as temp:
        redis_server = RedisServer(Path(temp))
        redis_server.start()
        try:
            base = Settings(_env_file=None, data_dir=Path(temp) / "var", redis_url=redis_server.url,  # type: ignore[call-arg]
                            user_requests_per_s=1e6, user_request_burst=10**6)  # fmt: skip
            upgrade_database(base.resolved_database_url)
            directory = base.data_path / "results" / "jobs" / "topo-1"
            directory.mkdir(parents=True)
            write_result(directory / "topography.h5")
            engine = make_engine(base.resolved_database_url)
            with make_sessionmaker(engine)() as session:
                entry = {"name": "topography.h5", "path": "results/jobs/topo-1/topography.h5", "size_bytes": 1,
                         "sha256": "", "media_type": "application/x-hdf5"}  # fmt: skip
                session.add(Job(id="topo-1", kind="topography", state="succeeded", files=[entry]))
                for n in range(LIST_JOBS):
                    session.add(Job(id=f"other-{n}", kind="selftest", state="succeeded", spec={"frames": 4}))
                session.commit()
            engine.dispose()
            before, after = f"before (no frame cache, gzip {args.reference_gzip_level})", "after (frame cache, gzip 1)"
            variants = {
                before: base.model_copy(update={"frame_cache_bytes": 0}),
                after: base.model_copy(update={"frame_cache_bytes": args.cache_mib * 2**20}),
            }
            # Before issue 26's item 8 was finished: no frame cache and answers compressed at gzip level 5.
            gzip_levels = {before: args.reference_gzip_level, after: cache.GZIP_LEVEL}
            cpu_ms: dict[str, list[float]] = defaultdict(list)
            wall_ms: dict[tuple[str, str], list[float]] = defaultdict(list)
            load_before = os.getloadavg()
            clients = {name: TestClient(create_app(settings)) for name, settings in variants.items()}
            for client in clients.values():
                client.__enter__()
            try:
                for round_number in range(args.rounds):
                    order = list(clients) if round_number % 2 == 0 else list(reversed(clients))
                    for name in order:
                        client = clients[name]
                        ANSWERS.clear()
                        cache.GZIP_LEVEL = gzip_levels[name]
                        client.app.state.fringelab.frames.clear()  # type: ignore[attr-defined]
                        rng = random.Random(round_number)
                        requests = [heavy_request(rng) for _ in range(args.requests)]
                        started_cpu = time.process_time()
                        for kind, path, params in requests:
                            began = time.perf_counter()
                            answer = client.get(path, params=params, headers={"Accept-Encoding": "gzip"})
                            if answer.status_code != 200:
                                raise RuntimeError(f"{path} {params}: {answer.status_code} {answer.text[:300]}")
                            wall_ms[(name, kind)].append((time.perf_counter() - began) * 1000)
                        per_request = (time.process_time() - started_cpu) / len(requests) * 1000
                        cpu_ms[name].append(per_request)
                        print(f"round {round_number + 1} {name:>31}: {per_request:5.2f} ms CPU per request "
                              f"(load {os.getloadavg()[0]:.2f})", flush=True)  # fmt: skip
            finally:
                for client in clients.values():
                    client.__exit__(None, None, None)
            frames = clients[after].app.state.fringelab.frames  # type: ignore[attr-defined]
        finally:
            redis_server.stop()
    print(f"heavy mix, {args.requests} requests a round, {args.rounds} rounds each; medians:")
    for name in variants:
        by_kind = "  ".join(f"{kind} {statistics.median(wall_ms[(name, kind)]):.2f}"
                            for kind in ("grid", "profile", "list"))  # fmt: skip
        print(f"  {name:>31}: {statistics.median(cpu_ms[name]):5.2f} ms CPU per request; wall ms by kind: {by_kind}")
    print(f"frame cache of the last round: {frames.hits} hits, {frames.misses} misses, "
          f"{frames.held_bytes / 2**20:.1f} MiB held")  # fmt: skip
    print(f"load average (1/5/15 min): before {' '.join(f'{v:.2f}' for v in load_before)}, "
          f"after {' '.join(f'{v:.2f}' for v in os.getloadavg())}; {os.cpu_count()} CPUs")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
