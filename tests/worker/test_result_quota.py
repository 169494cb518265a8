"""The per-user quota counts what a user's jobs write, not only their uploads (issue 26, finding 6): a job reserves
its kind's expected result size (`ResultSize` in fringelab/core/job_kinds.py) against the experiment's owner when
it is queued, and once it ends its files' real sizes count instead."""

from __future__ import annotations

import pytest
import redis
from celery.contrib.testing.worker import start_worker
from fastapi.testclient import TestClient

from backend.app import create_app
from fringelab.core.accounts import create_user, issue_token
from fringelab.core.db import make_engine, make_sessionmaker
from fringelab.core.models import Experiment, Job
from fringelab.core.quota import expected_result_bytes, used_bytes
from tests.worker.conftest import wait_job
from tests.worker.test_reserve import write_topography
from worker.app import create_worker_app

pytestmark = pytest.mark.integration
MIB = 2**20


def test_queued_jobs_reserve_their_results_and_ended_ones_count_what_they_wrote(settings):
    path = settings.data_path / "results" / "jobs" / "topo-1" / "topography.h5"
    result_bytes = write_topography(path).stat().st_size
    engine = make_engine(settings.resolved_database_url)
    sessions = make_sessionmaker(engine)
    with sessions() as session:
        ada = create_user(session, "ada", "ada-password", role="member")
        token = {"Authorization": f"Bearer {issue_token(session, ada)[1]}"}
        experiment = Experiment(name="plate", owner_id=ada.id)
        session.add(experiment)
        session.flush()
        entry = {"name": "topography.h5", "path": "results/jobs/topo-1/topography.h5", "size_bytes": result_bytes,
                 "sha256": "", "media_type": "application/x-hdf5"}  # fmt: skip
        session.add(Job(id="topo-1", kind="topography", state="succeeded", files=[entry], result={"frames": [0, 5]},
                        experiment_id=experiment.id))  # fmt: skip
        session.commit()
        ada_id = ada.id
        export = {"kind": "export", "job_id": "topo-1", "format": "grid-npz"}
        expected = expected_result_bytes(session, "export", export)
        assert used_bytes(session, ada_id) == result_bytes
    assert expected == MIB + 3 * result_bytes  # the export's declaration: 1 MiB + 3 × its source

    def api(quota: int) -> TestClient:
        update = {"auth_enabled": True, "user_quota_bytes": quota}
        return TestClient(create_app(settings.model_copy(update=update)), headers=token)

    redis.Redis.from_url(settings.redis_url).flushdb()
    with api(result_bytes + expected - 1) as client:  # one byte short of the export's expected results
        refused = client.post("/api/v1/jobs", json=export)
        assert refused.status_code == 413 and refused.json()["code"] == "over_quota", refused.text
        assert f"expected to take {expected} bytes" in refused.json()["detail"]
        assert "FRINGELAB_USER_QUOTA_BYTES" in refused.json()["detail"]
    with api(result_bytes + expected) as client:
        queued = client.post("/api/v1/jobs", json=export)
        assert queued.status_code in (201, 202), queued.text
        with sessions() as session:  # queued, no worker yet: its expected results are reserved
            assert used_bytes(session, ada_id) == result_bytes + expected
        second = client.post("/api/v1/jobs", json={**export, "format": "points-csv"})
        assert second.status_code == 413 and second.json()["code"] == "over_quota", second.text
        worker = create_worker_app(settings)
        worker.loader.import_default_modules()
        with start_worker(worker, pool="threads", concurrency=1, perform_ping_check=False, shutdown_timeout=30):
            job = wait_job(client, queued.json()["id"], timeout_s=60)
    assert job["state"] == "succeeded", job
    written = sum(f["size_bytes"] for f in job["files"])
    assert 0 < written < expected
    with sessions() as session:  # settled: the file it wrote counts, not what was expected
        assert used_bytes(session, ada_id) == result_bytes + written
    engine.dispose()
