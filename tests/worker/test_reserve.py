"""Workers keep the disk's reserve while they write (issue 26: a topography wrote until 45 MiB were free)."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
from celery.contrib.testing.worker import start_worker
from fastapi.testclient import TestClient

from backend.app import create_app
from fringelab.core.db import make_engine, make_sessionmaker
from fringelab.core.models import Job
from fringelab.core.storage import free_disk_bytes
from fringelab.formats.topography import TopographyWriter
from fringelab.science.fields import Peak
from tests.worker.conftest import wait_job
from tests.worker.test_calibration_jobs import Z_MM, add_recording
from worker.app import create_worker_app
from worker.context import JobContext, run_guarded
from worker.jobs.export import keeping_reserve
from worker.reserve import BelowReserve, require_reserve


def test_a_job_stops_in_words_below_the_reserve(settings):
    settings.data_path.mkdir(parents=True, exist_ok=True)
    require_reserve(settings, what="writing frames 0 to 9")  # the tests' disk is above the default reserve
    full = settings.model_copy(update={"min_free_disk_bytes": free_disk_bytes(settings.data_path) + 2**40})
    with pytest.raises(BelowReserve, match="stopped before writing frames 0 to 9: not enough free space") as error:
        require_reserve(full, what="writing frames 0 to 9")
    assert "FRINGELAB_MIN_FREE_DISK_BYTES" in str(error.value) and isinstance(error.value, ValueError)


# ------------------------------------------------------------------------- every job kind that writes files


def write_topography(path: Path) -> Path:
    """A topography result (6 frames on a 21 × 11 grid) written by the result writer."""
    from tests.formats.test_topography_writer import GRID, frame

    path.parent.mkdir(parents=True, exist_ok=True)
    peak = Peak(w_mm=1.0, x_mm=0.0, y_mm=0.0, centre_x_mm=0.0, centre_y_mm=0.0)
    with TopographyWriter(path, grid=GRID, max_edge_mm=6.0, z_flat_mm=0.0, axis="rows", attrs={},
                          calibration_attrs={}, threads=0) as writer:  # fmt: skip
        for i in range(6):
            measurement, z, sigma = frame(i, 50)
            writer.append(measurement, z, peak, log=(0.0, 0.0, 0.0), sigma_grid_mm=sigma)
        writer.close({})
    return path


def _topography_job(settings) -> str:
    """A succeeded topography job with its result (`write_topography`)."""
    write_topography(settings.data_path / "results" / "jobs" / "topo-1" / "topography.h5")
    engine = make_engine(settings.resolved_database_url)
    with make_sessionmaker(engine)() as session:
        entry = {"name": "topography.h5", "path": "results/jobs/topo-1/topography.h5", "size_bytes": 1,
                 "sha256": "", "media_type": "application/x-hdf5"}  # fmt: skip
        session.add(Job(id="topo-1", kind="topography", state="succeeded", files=[entry], result={"frames": [0, 5]}))
        session.commit()
    engine.dispose()
    return "topo-1"


@contextmanager
def api_and_worker(settings) -> Iterator[TestClient]:
    """The API and a real worker (threads, the tests' Redis) of `settings`."""
    import redis

    redis.Redis.from_url(settings.redis_url).flushdb()
    app = create_worker_app(settings)
    app.loader.import_default_modules()
    with (
        start_worker(app, pool="threads", concurrency=1, perform_ping_check=False, shutdown_timeout=30),
        TestClient(create_app(settings)) as client,
    ):
        yield client


def _assert_clean_refusal(job: dict, settings, what: str) -> None:
    assert job["state"] == "failed", job
    assert f"stopped before {what}: not enough free space on the data volume" in job["error"], job["error"]
    assert "FRINGELAB_MIN_FREE_DISK_BYTES" in job["error"] and "free some space and retry the job" in job["error"]
    assert str(settings.data_path) not in job["error"] and "0x" not in job["error"] and "/" not in job["error"]
    assert job["files"] == []
    directory = settings.data_path / "results" / "jobs" / job["id"]
    assert not directory.exists() or not any(directory.rglob("*")), sorted(directory.rglob("*"))


@pytest.mark.integration
def test_an_export_below_the_reserve_fails_in_words_and_leaves_no_file(settings):
    """Issue 26: workers ignored the reserve in every job but topography. An export asked below it fails saying
    why, names no server path, and leaves nothing; the same export above it succeeds (the test can fail)."""
    source = _topography_job(settings)
    full = settings.model_copy(update={"min_free_disk_bytes": free_disk_bytes(settings.data_path) + 2**40})
    spec = {"kind": "export", "job_id": source, "format": "grid-npz"}
    with api_and_worker(full) as client:
        job = wait_job(client, client.post("/api/v1/jobs", json=spec).json()["id"], timeout_s=60)
    _assert_clean_refusal(job, settings, "starting the job")
    with api_and_worker(settings) as client:
        job = wait_job(client, client.post("/api/v1/jobs", json=spec).json()["id"], timeout_s=60)
    assert job["state"] == "succeeded" and [f["name"] for f in job["files"]] == ["topography.npz"], job


@pytest.fixture(scope="module")
def zstack_frames():
    from fringelab.science.synthetic import reference_camera, render_zstack_frames, zstack_board

    camera = reference_camera("512x480")
    board = zstack_board(camera)
    return camera, board, render_zstack_frames(camera, board, Z_MM, rng=np.random.default_rng(5))


@pytest.mark.integration
def test_a_camera_calibration_below_the_reserve_fails_in_words_and_makes_no_calibration(settings, zstack_frames):
    recording = add_recording(settings, zstack_frames)
    full = settings.model_copy(update={"min_free_disk_bytes": free_disk_bytes(settings.data_path) + 2**40})
    with api_and_worker(full) as client:
        spec = {"kind": "camera_calibration", "recording_id": recording["recording"]}
        job = wait_job(client, client.post("/api/v1/jobs", json=spec).json()["id"], timeout_s=60)
        _assert_clean_refusal(job, settings, "starting the job")
        assert client.get("/api/v1/calibrations").json() == []


def test_a_file_that_takes_the_volume_below_the_reserve_is_removed_not_published(settings):
    """While a job writes: a file written as the volume fell below the reserve (here the reserve raised while it
    was written, as another writer would take the room) is removed, not renamed into place nor listed."""
    context = JobContext(job_id="job-1", spec=None, settings=settings, sessions=None)  # type: ignore[arg-type]
    refused = r"stopped before keeping camera\.json \(removed\): not enough free"
    with (
        pytest.raises(BelowReserve, match=refused),
        context.output("camera.json", media_type="application/json") as partial,
    ):
        partial.write_text("{}")
        context.settings = settings.model_copy(
            update={"min_free_disk_bytes": free_disk_bytes(settings.data_path) + 2**40}
        )
    assert context.files == {} and not any(context.directory.iterdir())
    with pytest.raises(BelowReserve, match=r"stopped before writing frame 3 of 9 of out\.npz: not enough free"):
        keeping_reserve(context, "out.npz")(2, 9, "exporting")


def test_a_job_stopped_by_the_reserve_keeps_none_of_the_files_it_had_published(settings):
    """A job that wrote one file and then met the reserve at the next fails, and the first file goes too: a failed
    job lists no file, and a full disk gets back what it wrote."""
    engine = make_engine(settings.resolved_database_url)
    sessions = make_sessionmaker(engine)
    with sessions() as session:
        session.add(Job(id="job-1", kind="comparison", state="running"))
        session.commit()
    context = JobContext(job_id="job-1", spec=None, settings=settings, sessions=sessions)  # type: ignore[arg-type]

    def body() -> dict:
        with context.output("comparison.h5") as partial:
            partial.write_bytes(b"complete")
        context.settings = settings.model_copy(
            update={"min_free_disk_bytes": free_disk_bytes(settings.data_path) + 2**40}
        )
        with context.output("comparison.csv") as partial:
            partial.write_text("never")
        return {}

    assert run_guarded(context, body) == (False, None)
    with sessions() as session:
        job = session.get(Job, "job-1")
        assert job.state == "failed" and job.files == [], (job.state, job.files)  # type: ignore[union-attr]
        assert job.error.startswith("stopped before writing comparison.csv: not enough free space")  # type: ignore[union-attr]
    assert not any(context.directory.iterdir())
    engine.dispose()
