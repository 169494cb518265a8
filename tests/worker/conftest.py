"""Fixtures of the job tests: an API client, a prefork worker subprocess, and rows a job can name."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import psutil
import pytest
import redis
from fastapi.testclient import TestClient

from backend.app import create_app
from fringelab.core.db import make_engine, make_sessionmaker
from fringelab.core.models import Calibration, Camera, Experiment, Recording
from fringelab.core.queue import create_celery
from fringelab.core.settings import Settings
from tests.support import wait_for

FINAL = ("succeeded", "failed", "cancelled")


@pytest.fixture
def client(settings: Settings) -> Iterator[TestClient]:
    with TestClient(create_app(settings)) as made:
        yield made


def wait_job(client: TestClient, job_id: str, *, until: tuple[str, ...] = FINAL, timeout_s: float = 60) -> dict:
    """The job as the API shows it once its state is one of `until` (and a cancelled one has stopped)."""

    def reached() -> dict | None:
        body = client.get(f"/api/v1/jobs/{job_id}").json()
        return body if body["state"] in until and not body["stopping"] else None

    return wait_for(reached, timeout_s=timeout_s, what=f"job {job_id} to reach {until}", interval_s=0.1)  # type: ignore[return-value]


def log_messages(client: TestClient, job_id: str) -> list[str]:
    return [line["message"] for line in client.get(f"/api/v1/jobs/{job_id}/log").json()]


class PreforkWorker:
    """`fringelab worker` (prefork, as users run it) as a subprocess, with its pool processes found by PID."""

    def __init__(self, settings: Settings, log_path: Path, *, concurrency: int = 2) -> None:
        clean = {k: v for k, v in os.environ.items() if not k.startswith("FRINGELAB_")}
        env = {
            **clean,
            "FRINGELAB_DATA_DIR": str(settings.data_path),
            "FRINGELAB_REDIS_URL": settings.redis_url,
            "FRINGELAB_WORKER_CONCURRENCY": str(concurrency),
            "FRINGELAB_CHUNK_FRAMES": str(settings.chunk_frames),
            "FRINGELAB_WORKER_LOST_AFTER_S": str(settings.worker_lost_after_s),
            "FRINGELAB_LOG_LEVEL": "info",
        }
        self.settings = settings
        self.log_path = log_path
        self._log = log_path.open("ab")
        self.process = subprocess.Popen(
            [sys.executable, "-m", "backend.cli", "worker"],
            env=env,
            stdout=self._log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        celery = create_celery(settings)
        wait_for(lambda: self._answers(celery), timeout_s=60, what="the prefork worker to answer a ping")

    def _answers(self, celery: Any) -> bool:
        if self.process.poll() is not None:
            raise RuntimeError(f"the worker exited: {self.log_path.read_text()[-2000:]}")
        replies = celery.control.ping(timeout=0.5) or []
        return any(str(self.process.pid) in name for reply in replies for name in reply)

    def pool_pids(self) -> set[int]:
        return {child.pid for child in psutil.Process(self.process.pid).children()}

    def stop(self) -> None:
        if self.process.poll() is None:
            os.killpg(self.process.pid, signal.SIGTERM)
            try:
                self.process.wait(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(self.process.pid, signal.SIGKILL)
                self.process.wait()
        self._log.close()


@pytest.fixture
def start_prefork_worker(tmp_path: Path) -> Iterator[Callable[..., PreforkWorker]]:
    started: list[PreforkWorker] = []

    def start(settings: Settings, *, concurrency: int = 2, flush: bool = True) -> PreforkWorker:
        if flush:
            redis.Redis.from_url(settings.redis_url).flushdb()
        worker = PreforkWorker(settings, tmp_path / f"worker-{len(started)}.log", concurrency=concurrency)
        started.append(worker)
        return worker

    yield start
    for worker in started:
        worker.stop()


def pid_of(worker_field: str) -> int:
    """The PID in a job's or chunk's `worker` text, `host (pid 123)`."""
    return int(worker_field.rsplit("pid ", 1)[1].rstrip(")"))


@pytest.fixture
def add_rows(settings: Settings) -> Callable[..., dict[str, int]]:
    """Insert an experiment with one camera, recordings and calibrations; returns their ids by name."""

    def add(
        *,
        recording_state: str = "ready",
        frame_count: int = 20,
        size: tuple[int, int] = (640, 480),
        calibration_size: tuple[int, int] = (640, 480),
    ) -> dict[str, int]:
        engine = make_engine(settings.resolved_database_url)
        with make_sessionmaker(engine)() as session:
            experiment = Experiment(name="plate 1")
            camera = Camera(experiment=experiment, name="left", image_width_px=size[0], image_height_px=size[1],
                            pixel_pitch_um=20.0)  # fmt: skip
            other_camera = Camera(experiment=experiment, name="right", image_width_px=size[0],
                                  image_height_px=size[1], pixel_pitch_um=20.0)  # fmt: skip
            test = Recording(camera=camera, kind="test", state=recording_state, frame_count=frame_count,
                             width_px=size[0], height_px=size[1], sha256="ab" * 32)  # fmt: skip
            session.add_all([experiment, camera, other_camera, test])
            session.flush()
            rows: dict[str, Any] = {"experiment": experiment, "camera": camera, "test": test}
            for name, kind, cam in (
                ("camera_cal", "camera", camera),
                ("projector_cal", "projector", camera),
                ("other_camera_cal", "camera", other_camera),
            ):
                width, height = calibration_size
                rows[name] = Calibration(kind=kind, camera_id=cam.id, path=f"calibrations/{name}.json",
                                         image_width_px=width, image_height_px=height)  # fmt: skip
                session.add(rows[name])
            session.commit()
            ids = {name: row.id for name, row in rows.items()}
        engine.dispose()
        return ids

    return add


# ------------------------------------------------------------------------------------------ virtual test

TEST_FRAMES = 12  # the virtual punch reaches ~60 mm and perforates (frame 9) within them


@pytest.fixture(scope="session")
def virtual_experiment(tmp_path_factory):
    from fringelab.pipelines.virtual_test import write_virtual_test

    # 4 mm projector steps over 0..80 mm: half the default's frames, still ~20 samples per table entry
    return write_virtual_test(
        tmp_path_factory.mktemp("virtual") / "kodak", "kodak", n_test_frames=TEST_FRAMES,
        calibration_z_mm=np.arange(0.0, 80.0 + 1e-9, 4.0), as_zip=True, seed=3,
    )  # fmt: skip


def upload_virtual_experiment(client, virtual) -> dict[str, Any]:
    """Experiment, camera and the three recordings through the API, as a user uploads them; waits for the ingest
    of each. Returns the recording ids by kind, and the camera's scale axis."""
    truth = json.loads(virtual.truth_json.read_text())
    experiment = client.post("/api/v1/experiments", json={"name": "virtual kodak"}).json()
    camera = client.post(f"/api/v1/experiments/{experiment['id']}/cameras", json={
        "name": "kodak", "image_width_px": 512, "image_height_px": 480,
        "pixel_pitch_um": 1000.0 / truth["camera"]["du_px_per_mm"]}).json()  # fmt: skip
    ids: dict[str, Any] = {"scale_on": truth["camera"]["scale_on"]}
    for kind in ("camera_calibration", "projector_calibration", "test"):
        path = getattr(virtual, kind)
        uploaded = client.put(f"/api/v1/uploads/cameras/{camera['id']}/{path.name}", params={"kind": kind},
                              content=path.read_bytes())  # fmt: skip
        assert uploaded.status_code == 201, uploaded.text
        ids[kind] = uploaded.json()["id"]
    for kind in ("camera_calibration", "projector_calibration", "test"):

        def ingested(recording_id: int = ids[kind]) -> dict | None:
            recording = client.get(f"/api/v1/recordings/{recording_id}").json()
            return recording if recording["state"] in ("ready", "invalid") else None

        recording = wait_for(ingested, timeout_s=300, what=f"the ingest of the {kind} recording", interval_s=0.2)
        assert recording["state"] == "ready", recording  # type: ignore[index]
    return ids


def datasets(path: Path) -> dict[str, np.ndarray]:
    found: dict[str, np.ndarray] = {}
    with h5py.File(path) as file:
        file.visititems(lambda name, item: found.update({name: item[()]}) if isinstance(item, h5py.Dataset) else None)
    return found


def sequential_topography(
    settings, recording_path: Path, camera_job: dict, projector_job: dict, out_path: Path
) -> Path:
    """`fringelab topography` on the same inputs: one pass, edges located inline, no chunks, no job."""
    from fringelab.formats.camera import read_camera_json
    from fringelab.formats.projector import read_projector_calibration
    from fringelab.formats.recordings import open_recording
    from fringelab.pipelines.topography import topography_recording

    def result(job: dict, name: str) -> Path:
        return settings.data_path / "results" / "jobs" / job["id"] / name

    topography_recording(
        open_recording(recording_path),
        read_camera_json(result(camera_job, "camera.json")),
        read_projector_calibration(result(projector_job, "projector.h5")),
        out_path=out_path,
    )
    return out_path
