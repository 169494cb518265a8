"""Upload benchmark: a GB-size recording sent to a real `fringelab api` server over loopback.

Generates a Phantom .cine recording of --size-gb in a temporary folder under /tmp (deleted afterwards, with the
server's data directory), starts redis-server and `python -m backend.cli api` as subprocesses, and uploads the
file twice: with tus (PATCH requests of --chunk-mib) and with one streamed PUT. It prints, for each, the
throughput in MB/s (10^6 bytes per second, from the first request to the last response) and the server's peak
resident memory (VmHWM of the server process, which is the peak since it started), with the server's CPU time
per GB (what the upload costs, whatever else runs on the machine). No worker runs: the ingest
job is queued and left alone, so only the upload path is measured.

    .venv/bin/python bench/bench_upload.py            # 2 GB, tus in 256 MiB PATCHes, then PUT
    .venv/bin/python bench/bench_upload.py --size-gb 0.2

Targets: at least 150 MB/s and a peak RSS under 200 MB, whatever the file size.
"""

from __future__ import annotations

import argparse
import base64
import hashlib
import os
import shutil
import struct
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from backend.supervisor import redis_server_binary  # noqa: E402
from fringelab.core.startup_checks import free_port  # noqa: E402

READ_BLOCK = 1 << 20


def write_cine(path: Path, size_bytes: int, *, width: int = 1024, height: int = 1024) -> int:
    """An uncompressed 16-bit .cine of about size_bytes (random frames, so nothing compresses); its frame count."""
    frame_bytes = width * height * 2
    count = max(1, size_bytes // (frame_bytes + 8))
    setup = bytearray(1024)
    struct.pack_into("<H", setup, 142, len(setup))
    struct.pack_into("<I", setup, 768, 10_000)
    struct.pack_into("<I", setup, 896, 12)
    off_offsets = 44 + 40 + len(setup)
    first = off_offsets + 8 * count
    offsets = np.arange(count, dtype="<u8") * (frame_bytes + 8) + first
    rng = np.random.default_rng(0)
    frames = [rng.integers(0, 4096, width * height, dtype="<u2").tobytes() for _ in range(4)]
    with path.open("wb") as out:
        out.write(struct.pack("<2sHHHiIiIIIIQ", b"CI", 44, 0, 1, 0, count, 0, count, 44, 84, off_offsets, 0))
        out.write(struct.pack("<IiiHHIIiiII", 40, width, height, 1, 16, 0, frame_bytes, 0, 0, 0, 0))
        out.write(setup)
        out.write(offsets.tobytes())
        for i in range(count):
            out.write(struct.pack("<II", 8, frame_bytes))
            out.write(frames[i % len(frames)])
    return count


def read_blocks(path: Path, offset: int, length: int) -> Iterator[bytes]:
    with path.open("rb") as handle:
        handle.seek(offset)
        while length > 0:
            block = handle.read(min(READ_BLOCK, length))
            if not block:
                return
            length -= len(block)
            yield block


def peak_rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    raise RuntimeError("no VmHWM in /proc status")


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of a process (all its threads) so far."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return 0.0


class Sampler:
    """Peak RSS of a process while something runs, sampled every 20 ms (VmHWM also covers start-up)."""

    def __init__(self, pid: int) -> None:
        self.pid, self.peak_mb, self._stop = pid, 0.0, threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.is_set():
            self.peak_mb = max(self.peak_mb, rss_mb(self.pid))
            time.sleep(0.02)

    def __enter__(self) -> Sampler:
        self._thread.start()
        return self

    def __exit__(self, *_exc: object) -> None:
        self._stop.set()
        self._thread.join()


def tus_upload(client: httpx.Client, path: Path, camera_id: int, chunk: int) -> str:
    size = path.stat().st_size
    meta = {"filename": "bench.cine", "filetype": "video/x-cine", "camera_id": str(camera_id), "kind": "test"}
    encoded = ",".join(f"{k} {base64.b64encode(v.encode()).decode()}" for k, v in meta.items())
    created = client.post("/api/v1/uploads", headers={"Tus-Resumable": "1.0.0", "Upload-Length": str(size),
                                                       "Upload-Metadata": encoded})  # fmt: skip
    created.raise_for_status()
    location = created.headers["Location"]
    offset = 0
    while offset < size:
        length = min(chunk, size - offset)
        response = client.patch(
            location,
            headers={"Tus-Resumable": "1.0.0", "Upload-Offset": str(offset), "Content-Length": str(length),
                     "Content-Type": "application/offset+octet-stream"},
            content=read_blocks(path, offset, length),
        )  # fmt: skip
        if response.status_code != 204:
            raise RuntimeError(f"PATCH answered {response.status_code}: {response.text}")
        offset = int(response.headers["Upload-Offset"])
    return response.headers["Fringelab-Recording-Id"]


def put_upload(client: httpx.Client, path: Path, camera_id: int) -> str:
    size = path.stat().st_size
    response = client.put(
        f"/api/v1/uploads/cameras/{camera_id}/bench.cine",
        params={"kind": "test"},
        headers={"Content-Length": str(size)},
        content=read_blocks(path, 0, size),
    )
    if response.status_code != 201:
        raise RuntimeError(f"PUT answered {response.status_code}: {response.text}")
    return str(response.json()["id"])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size-gb", type=float, default=2.0, help="recording size in GB (10^9 bytes)")
    parser.add_argument("--chunk-mib", type=int, default=256, help="size of one tus PATCH in MiB")
    args = parser.parse_args()

    work = Path(tempfile.mkdtemp(prefix="fringelab-bench-", dir="/tmp"))
    processes: list[subprocess.Popen[bytes]] = []
    try:
        recording = work / "bench.cine"
        started = time.monotonic()
        frames = write_cine(recording, int(args.size_gb * 1e9))
        size = recording.stat().st_size
        print(f"recording: {recording} ({size / 1e9:.2f} GB, {frames} frames of 1024 × 1024 × 16 bit), "
              f"written in {time.monotonic() - started:.1f} s")  # fmt: skip
        digest = hashlib.sha256()
        for block in read_blocks(recording, 0, size):
            digest.update(block)

        redis_port, api_port = free_port(), free_port()
        (work / "redis").mkdir()
        processes.append(subprocess.Popen(
            [redis_server_binary(), "--port", str(redis_port), "--bind", "127.0.0.1", "--save", "", "--dir",
             str(work / "redis")], stdout=subprocess.DEVNULL))  # fmt: skip
        env = {k: v for k, v in os.environ.items() if not k.startswith("FRINGELAB_")}
        env.update(FRINGELAB_DATA_DIR=str(work / "var"), FRINGELAB_REDIS_URL=f"redis://127.0.0.1:{redis_port}/0",
                   FRINGELAB_PORT=str(api_port), FRINGELAB_LOG_LEVEL="warning")  # fmt: skip
        log = (work / "api.log").open("wb")
        server = subprocess.Popen([sys.executable, "-m", "backend.cli", "api"], cwd=ROOT, env=env, stdout=log,
                                  stderr=subprocess.STDOUT)  # fmt: skip
        processes.append(server)
        base_url = f"http://127.0.0.1:{api_port}"
        deadline = time.monotonic() + 60
        while True:
            try:
                httpx.get(f"{base_url}/api/v1/experiments", timeout=2).raise_for_status()
                break
            except httpx.HTTPError:
                if time.monotonic() > deadline or server.poll() is not None:
                    raise RuntimeError(f"the API did not start:\n{(work / 'api.log').read_text()[-2000:]}") from None
                time.sleep(0.2)
        print(f"server: `fringelab api` pid {server.pid} on {base_url}, RSS at rest {rss_mb(server.pid):.0f} MB")

        with httpx.Client(base_url=base_url, timeout=600) as client:
            experiment = client.post("/api/v1/experiments", json={"name": "bench"}).json()
            camera = client.post(f"/api/v1/experiments/{experiment['id']}/cameras",
                                 json={"name": "c", "image_width_px": 1024, "image_height_px": 1024,
                                       "pixel_pitch_um": 20}).json()  # fmt: skip
            for name, upload in (
                (f"tus, {args.chunk_mib} MiB PATCHes", lambda: tus_upload(client, recording, camera["id"],
                                                                          args.chunk_mib << 20)),
                ("PUT, one streamed request", lambda: put_upload(client, recording, camera["id"])),
            ):  # fmt: skip
                cpu_before = cpu_seconds(server.pid)
                with Sampler(server.pid) as sampler:
                    started = time.monotonic()
                    recording_id = upload()
                    seconds = time.monotonic() - started
                cpu = cpu_seconds(server.pid) - cpu_before
                stored = client.get(f"/api/v1/recordings/{recording_id}").json()
                if stored["sha256"] != digest.hexdigest() or stored["size_bytes"] != size:
                    raise RuntimeError(f"{name}: the server stored something else: {stored}")
                print(
                    f"{name:30s} {size / 1e6 / seconds:5.0f} MB/s ({seconds:5.1f} s), server CPU "
                    f"{cpu / (size / 1e9):.2f} s/GB, server RSS during upload ≤ {sampler.peak_mb:.0f} MB"
                )
        print(f"server peak RSS since start (VmHWM): {peak_rss_mb(server.pid):.0f} MB")
        print(f"load average (1 min) at the end: {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs")
    finally:
        for process in reversed(processes):
            process.terminate()
            try:
                process.wait(timeout=20)
            except subprocess.TimeoutExpired:
                process.kill()
        shutil.rmtree(work, ignore_errors=True)
        print(f"removed {work}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
