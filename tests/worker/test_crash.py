"""Process behaviour with real prefork workers (`fringelab worker` subprocesses): a worker process SIGKILLed
mid-job, a hard cancel, a Redis restart mid-queue, several jobs at once. Each job ends exactly once, with a
complete result."""

from __future__ import annotations

import os
import signal
import time

import h5py
import numpy as np
import psutil
import pytest

from fringelab.core.settings import Settings
from tests.support import RedisServer, wait_for
from tests.worker.conftest import (
    datasets,
    log_messages,
    pid_of,
    sequential_topography,
    upload_virtual_experiment,
    wait_job,
)
from worker.jobs.selftest import selftest_frame

pytestmark = [pytest.mark.integration, pytest.mark.slow]


def _settings(settings: Settings, **changes: object) -> Settings:
    return settings.model_copy(update=changes)


def assert_complete_selftest(client, job: dict, tmp_path) -> None:
    """Succeeded once, and its file holds every frame once with the right content."""
    assert job["state"] == "succeeded", job["error"]
    messages = log_messages(client, job["id"])
    assert sum(m.startswith("succeeded") for m in messages) == 1, messages
    spec = job["spec"]
    path = tmp_path / f"{job['id']}.h5"
    path.write_bytes(client.get(job["files"][0]["url"]).content)
    with h5py.File(path) as result:
        assert result["frame"][:].tolist() == list(range(spec["frames"]))
        expected = [selftest_frame(f, size_px=spec["frame_size_px"])[1].encode() for f in range(spec["frames"])]
        assert result["digest"][:].tolist() == expected


def test_a_worker_process_killed_mid_chunk_is_replaced_and_the_job_ends_once_complete(
    settings, client, start_prefork_worker, tmp_path
):
    worker = start_prefork_worker(settings, concurrency=2)
    spec = {"kind": "selftest", "frames": 120, "frame_size_px": 1024, "chunk_frames": 20}
    job_id = client.post("/api/v1/jobs", json=spec).json()["id"]

    def a_running_chunk() -> dict | None:
        chunks = client.get(f"/api/v1/jobs/{job_id}").json()["chunks"]
        return next((c for c in chunks if c["state"] == "running" and c["worker"]), None)

    victim = wait_for(a_running_chunk, timeout_s=60, what="a chunk to run")
    killed = pid_of(victim["worker"])  # type: ignore[index]
    assert killed in worker.pool_pids()
    psutil.Process(killed).send_signal(signal.SIGKILL)

    job = wait_job(client, job_id, timeout_s=120)
    assert_complete_selftest(client, job, tmp_path)
    rerun = next(c for c in job["chunks"] if (c["phase"], c["index"]) == (victim["phase"], victim["index"]))  # type: ignore[index]
    assert pid_of(rerun["worker"]) != killed
    assert killed not in worker.pool_pids() and len(worker.pool_pids()) == 2


@pytest.mark.parametrize("victim", ["a measuring chunk's", "the merge's"])
def test_a_topography_whose_worker_process_is_killed_while_measuring_ends_identical_to_a_sequential_run(
    settings, client, start_prefork_worker, virtual_experiment, tmp_path, victim
):
    """Either process: one measuring a chunk, or the merge's after it measured a chunk in its turn straight into
    its file (that chunk is done and has no hand-over: the merge that runs again measures it again). With one
    worker process the merge measures every chunk in its turn (the chunk tasks wait behind it)."""
    worker = start_prefork_worker(settings, concurrency=2 if victim == "a measuring chunk's" else 1)
    ids = upload_virtual_experiment(client, virtual_experiment)

    def succeeded(spec: dict) -> dict:
        job = wait_job(client, client.post("/api/v1/jobs", json=spec).json()["id"], timeout_s=300)
        assert job["state"] == "succeeded", job["error"]
        return job

    camera = succeeded({"kind": "camera_calibration", "recording_id": ids["camera_calibration"],
                        "scale_on": ids["scale_on"]})  # fmt: skip
    projector = succeeded({"kind": "projector_calibration", "recording_id": ids["projector_calibration"],
                           "camera_calibration_id": camera["result"]["calibration_id"]})  # fmt: skip
    spec = {"kind": "topography", "recording_id": ids["test"], "chunk_frames": 2,
            "camera_calibration_id": camera["result"]["calibration_id"],
            "projector_calibration_id": projector["result"]["calibration_id"]}  # fmt: skip
    job_id = client.post("/api/v1/jobs", json=spec).json()["id"]

    def a_measuring_chunk() -> str | None:
        chunks = client.get(f"/api/v1/jobs/{job_id}").json()["chunks"]
        return next((c["worker"] for c in chunks if c["phase"] == 0 and c["state"] == "running" and c["worker"]), None)

    def the_merge_after_its_own_chunk() -> str | None:
        job = client.get(f"/api/v1/jobs/{job_id}").json()
        merged_here = any(c["state"] == "done" and c["worker"] == job["worker"] for c in job["chunks"])
        return job["worker"] if job["state"] == "running" and merged_here else None

    find = a_measuring_chunk if victim == "a measuring chunk's" else the_merge_after_its_own_chunk
    killed = pid_of(wait_for(find, timeout_s=180, what=f"{victim} process", interval_s=0.02))  # type: ignore[arg-type]
    psutil.Process(killed).send_signal(signal.SIGKILL)

    job = wait_job(client, job_id, timeout_s=300)
    assert job["state"] == "succeeded", job["error"]
    messages = log_messages(client, job_id)
    assert sum(m.startswith("succeeded") for m in messages) == 1
    if victim == "the merge's":
        assert any(m.startswith("the pass in frame order starts again") for m in messages), messages
    # Another process took the dead one's chunk over at once (its PID is gone), maybe before the pool replaced it.
    wait_for(lambda: killed not in worker.pool_pids(), timeout_s=60, what="the pool to replace the killed process")
    result = datasets(settings.data_path / "results" / "jobs" / job_id / "topography.h5")
    reference = datasets(
        sequential_topography(settings, virtual_experiment.test, camera, projector, tmp_path / "sequential.h5")
    )
    assert result.keys() == reference.keys()
    for name in result:
        np.testing.assert_array_equal(result[name], reference[name], err_msg=name)


def test_a_whole_worker_killed_mid_job_is_noticed_and_another_worker_finishes_the_job(
    settings, start_prefork_worker, tmp_path
):
    """SIGKILL of the worker and its pool (a machine that dies): its delivered messages would only come back after
    the visibility timeout (hours); the API's sweep notices the silence and re-queues what the job still needs."""
    from fastapi.testclient import TestClient

    from backend.app import create_app

    quick = _settings(settings, worker_lost_after_s=3.0, reconcile_interval_s=1.0)
    doomed = start_prefork_worker(quick, concurrency=1)
    with TestClient(create_app(quick)) as client:
        spec = {"kind": "selftest", "frames": 60, "frame_size_px": 1024, "chunk_frames": 20}
        job_id = client.post("/api/v1/jobs", json=spec).json()["id"]

        def a_running_chunk() -> bool:
            return any(c["state"] == "running" for c in client.get(f"/api/v1/jobs/{job_id}").json()["chunks"])

        wait_for(a_running_chunk, timeout_s=60, what="a chunk to run")
        os.killpg(doomed.process.pid, signal.SIGKILL)
        doomed.process.wait()
        start_prefork_worker(quick, concurrency=1, flush=False)
        job = wait_job(client, job_id, timeout_s=120)
        assert_complete_selftest(client, job, tmp_path)
        assert any("re-queued" in m for m in log_messages(client, job_id))


def test_a_cancel_terminates_a_task_that_does_not_stop_on_its_own(settings, start_prefork_worker, tmp_path):
    from fastapi.testclient import TestClient

    from backend.app import create_app

    impatient = _settings(settings, cancel_grace_s=0.0)
    worker = start_prefork_worker(impatient, concurrency=1)
    with TestClient(create_app(impatient)) as client:
        # one 4096 px frame takes about a second: the cooperative check between frames would come too late
        job_id = client.post("/api/v1/jobs", json={"kind": "selftest", "frames": 50, "frame_size_px": 4096}).json()[
            "id"
        ]

        def running_chunk_pid() -> int | None:
            chunks = client.get(f"/api/v1/jobs/{job_id}").json()["chunks"]
            return next((pid_of(c["worker"]) for c in chunks if c["state"] == "running" and c["worker"]), None)

        pid = wait_for(running_chunk_pid, timeout_s=60, what="the chunk to run")
        assert client.post(f"/api/v1/jobs/{job_id}/cancel").status_code == 200
        job = wait_job(client, job_id, timeout_s=30)
        assert job["state"] == "cancelled"
        wait_for(lambda: not psutil.pid_exists(pid) or psutil.Process(pid).status() == psutil.STATUS_ZOMBIE,
                 timeout_s=30, what=f"process {pid} to be terminated")  # fmt: skip
        assert "no worker confirmed the stop within 0 s; a process still running it was terminated" in log_messages(
            client, job_id
        )
        wait_for(lambda: len(worker.pool_pids()) == 1, timeout_s=30, what="the pool to replace the process")

        # the worker is still useful afterwards
        after = client.post("/api/v1/jobs", json={"kind": "selftest", "frames": 5, "frame_size_px": 32}).json()
        assert wait_job(client, after["id"], timeout_s=60)["state"] == "succeeded"


def test_a_redis_restart_mid_queue_loses_no_job_and_runs_none_twice(settings, start_prefork_worker, tmp_path):
    from fastapi.testclient import TestClient

    from backend.app import create_app

    server = RedisServer(tmp_path / "redis", appendonly=True)
    (tmp_path / "redis").mkdir()
    server.start()
    try:
        own = _settings(settings, redis_url=server.url)
        worker = start_prefork_worker(own, concurrency=1)
        with TestClient(create_app(own)) as client:
            ids = [
                client.post(
                    "/api/v1/jobs",
                    json={"kind": "selftest", "frames": 40 + i, "frame_size_px": 1024, "chunk_frames": 20},
                ).json()["id"]
                for i in range(3)
            ]

            def one_runs() -> bool:  # (the first can end before its state is read: any running one is mid-queue)
                return any(client.get(f"/api/v1/jobs/{job_id}").json()["state"] == "running" for job_id in ids)

            wait_for(one_runs, timeout_s=60, what="one of the jobs to run", interval_s=0.05)
            server.kill()
            time.sleep(0.5)  # as long as `fringelab up` waits before it restarts Redis
            server.start()
            jobs = [wait_job(client, job_id, timeout_s=180) for job_id in ids]
            # the worker rode it out (Celery 5.7.0's can exit in such a restart: see the pin in pyproject.toml)
            assert worker.process.poll() is None, worker.log_path.read_text()[-3000:]
            for job in jobs:
                assert_complete_selftest(client, job, tmp_path)
    finally:
        server.stop()


def test_several_jobs_at_once_use_every_worker_process(settings, client, start_prefork_worker, tmp_path):
    start_prefork_worker(settings, concurrency=2)
    ids = [
        client.post(
            "/api/v1/jobs", json={"kind": "selftest", "frames": 30 + i, "frame_size_px": 512, "chunk_frames": 10}
        ).json()["id"]
        for i in range(3)
    ]
    jobs = [wait_job(client, job_id, timeout_s=120) for job_id in ids]
    for job in jobs:
        assert_complete_selftest(client, job, tmp_path)
    processes = {pid_of(c["worker"]) for job in jobs for c in job["chunks"]}
    assert len(processes) == 2, "the chunks did not spread over both worker processes"
