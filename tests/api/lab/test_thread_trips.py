"""Trips to a worker thread per request (issue 26): each is a hand-over that, on a busy web server, waits for a
free thread and then for the GIL. A job's page polls `GET /jobs/{id}`: with a token checked moments ago, it takes
three (the access check, the route, closing the session); it took five (the principal and the response's
validation besides)."""

from __future__ import annotations

import anyio.to_thread
from fastapi.testclient import TestClient

from backend.app import create_app
from fringelab.core.db import make_engine, make_sessionmaker
from fringelab.core.models import Job
from fringelab.core.settings import Settings
from tests.support import bearer


def test_a_polled_job_takes_three_thread_trips(lab_settings: Settings, tokens: dict[str, str], monkeypatch):
    with make_sessionmaker(make_engine(lab_settings.resolved_database_url))() as session:
        session.add(Job(id="job-1", kind="selftest", state="succeeded", spec={}))
        session.commit()
    trips: list[str] = []
    run_sync = anyio.to_thread.run_sync

    async def counted(function, *args, **kwargs):  # type: ignore[no-untyped-def]
        trips.append(getattr(function, "__qualname__", repr(function)))
        return await run_sync(function, *args, **kwargs)

    with TestClient(create_app(lab_settings)) as client:
        token = bearer(tokens["admin"])
        assert client.get("/api/v1/jobs/job-1", headers=token).status_code == 200  # checks the token, leases
        monkeypatch.setattr(anyio.to_thread, "run_sync", counted)
        answer = client.get("/api/v1/jobs/job-1", headers=token)
    assert answer.status_code == 200 and answer.json()["id"] == "job-1"
    assert len(trips) == 3, trips
