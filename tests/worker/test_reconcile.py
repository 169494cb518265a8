"""Start-up reconciliation of the database with the broker, and an API restart in the middle of a job."""

from __future__ import annotations

from datetime import timedelta

import pytest
from fastapi.testclient import TestClient

from backend.app import create_app
from fringelab.core.broker import BrokerTasks, Delivery
from fringelab.core.db import make_engine, make_sessionmaker
from fringelab.core.models import Job, JobChunk, utcnow
from fringelab.core.reconcile import MAX_REQUEUES, TaskToSend, is_lost
from tests.worker.conftest import log_messages, wait_job

SELFTEST = {"kind": "selftest", "frames": 12, "frame_size_px": 32, "chunk_frames": 4}
LOST_S = 65.0  # longer ago than FRINGELAB_WORKER_LOST_AFTER_S (60 s)


@pytest.fixture
def insert_job(settings):
    """Write a job row as a crash would have left it, without any message in the broker."""
    engine = make_engine(settings.resolved_database_url)
    sessions = make_sessionmaker(engine)

    def insert(*, state: str, heartbeat_age_s: float | None = None, chunks: int = 0, **columns) -> str:
        with sessions() as session:
            beat = utcnow() - timedelta(seconds=heartbeat_age_s) if heartbeat_age_s is not None else None
            job = Job(id=f"lost-{state}-{heartbeat_age_s}-{chunks}", kind="selftest", spec=SELFTEST, state=state,
                      heartbeat_at=beat, started_at=beat, created_at=utcnow() - timedelta(seconds=LOST_S),
                      **columns)  # fmt: skip
            session.add(job)
            for index in range(chunks):
                first = index * SELFTEST["chunk_frames"]
                session.add(JobChunk(job_id=job.id, phase=0, index=index, first_frame=first, stop_frame=first + 4))
            if chunks:
                job.progress_total = SELFTEST["frames"]
            session.commit()
            return job.id

    yield insert
    engine.dispose()


@pytest.mark.integration
@pytest.mark.parametrize(
    ("state", "heartbeat_age_s", "chunks"),
    [("queued", None, 0), ("running", LOST_S, 0), ("running", LOST_S, 3)],
    ids=["queued", "running-entry", "running-chunks"],
)
def test_a_job_the_broker_lost_is_requeued_at_start_up_and_finishes(
    settings, celery_worker, insert_job, state, heartbeat_age_s, chunks
):
    job_id = insert_job(state=state, heartbeat_age_s=heartbeat_age_s, chunks=chunks)
    with TestClient(create_app(settings)) as client:
        job = wait_job(client, job_id)
        assert job["state"] == "succeeded", job["error"]
        assert job["result"]["frames"] == SELFTEST["frames"]
        messages = log_messages(client, job_id)
    assert messages[0].startswith(f"the job queue no longer held this {state} job")
    assert f"re-queued {chunks or 1} task(s) (re-queue 1 of {MAX_REQUEUES})" in messages[0]
    assert sum(m.startswith("succeeded") for m in messages) == 1


def test_a_job_lost_too_often_is_failed_with_the_reason(settings, insert_job):
    job_id = insert_job(state="running", heartbeat_age_s=LOST_S, requeues=MAX_REQUEUES)
    with TestClient(create_app(settings)) as client:
        job = client.get(f"/api/v1/jobs/{job_id}").json()
    assert job["state"] == "failed"
    assert job["error"].startswith(f"the job queue lost this job {MAX_REQUEUES + 1} times")
    assert "retry it" in job["error"]


def test_a_running_job_whose_worker_reports_is_left_alone(settings, insert_job):
    job_id = insert_job(state="running", heartbeat_age_s=1.0)
    with TestClient(create_app(settings)) as client:
        job = client.get(f"/api/v1/jobs/{job_id}").json()
        assert job["state"] == "running"
        assert log_messages(client, job_id) == []


def test_a_cancelled_job_whose_worker_vanished_is_closed(settings, insert_job):
    job_id = insert_job(state="cancelled", heartbeat_age_s=LOST_S)
    with TestClient(create_app(settings)) as client:
        job = client.get(f"/api/v1/jobs/{job_id}").json()
        assert job["state"] == "cancelled" and not job["stopping"]
        assert log_messages(client, job_id) == ["closed the cancelled job: its worker is gone"]


@pytest.mark.integration
def test_the_api_restarting_mid_job_changes_nothing(settings, celery_worker):
    with TestClient(create_app(settings)) as client:
        job_id = client.post(
            "/api/v1/jobs", json=SELFTEST | {"frames": 200, "frame_size_px": 512, "chunk_frames": 50}
        ).json()["id"]
        wait_job(client, job_id, until=("running",))
    with TestClient(create_app(settings)) as client:
        job = wait_job(client, job_id)
        assert job["state"] == "succeeded"
        messages = log_messages(client, job_id)
    assert not any("re-queued" in m for m in messages)
    assert sum(m.startswith(("started", "restarted")) for m in messages) == 1


NOW = utcnow()


def _ago(seconds: float):
    return NOW - timedelta(seconds=seconds)


@pytest.mark.parametrize(
    ("where", "started", "last_sign_age_s", "held_by_a_live_worker", "lost"),
    [
        ("waiting", False, 1000, False, False),  # still in its queue, however old
        ("delivered", False, 1000, True, False),  # reserved by a busy live worker
        ("delivered", False, 1000, False, True),  # reserved by a worker that died
        ("delivered-just-now", False, 1000, False, False),  # handed out a moment ago
        ("delivered", True, 5, False, False),  # running, its worker reports
        ("delivered", True, 100, True, True),  # running, its worker went silent
        ("nowhere", True, 5, False, False),  # Redis lost it, the run goes on
        ("nowhere", False, 100, False, True),  # Redis lost it before it started
        ("nowhere", False, 5, False, False),  # just sent: between queue and worker
    ],
)
def test_which_tasks_count_as_lost(where, started, last_sign_age_s, held_by_a_live_worker, lost):
    task = TaskToSend("fringelab.selftest", ["j"], "j", started, _ago(last_sign_age_s))
    delivered_at = _ago(1.0 if where == "delivered-just-now" else 1000)
    broker = BrokerTasks(
        waiting={"j"} if where == "waiting" else set(),
        delivered={"j": Delivery("tag", delivered_at)} if where.startswith("delivered") else {},
    )
    live = {"j"} if held_by_a_live_worker else set()
    assert is_lost(task, broker, now=NOW, lost_after_s=60, live=lambda: live) is lost
