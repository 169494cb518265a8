"""Fixtures of the job tests: an API client, a prefork worker subprocess, and rows a job can name."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import psutil
import pytest
import redis
from fastapi.testclient import TestClient

from backend.app import create_app
from backend.db import make_engine, make_sessionmaker
from backend.models import Calibration, Camera, Experiment, Recording
from backend.settings import Settings
from tests.support import wait_for
from worker.celery_app import create_celery

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
