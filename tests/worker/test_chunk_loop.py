"""A chunk task goes on to the phase's next chunk nobody has started, in the same process (no round trip through
the queue per chunk), and takes over a chunk whose process is gone; it leaves a chunk a live process runs. The
task runs in this process on the tests' database and Redis, as a worker process runs it."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from collections.abc import Iterator

import pytest
from sqlalchemy import select

from fringelab.core.broker import CHUNK_TASK
from fringelab.core.db import make_engine, make_sessionmaker
from fringelab.core.models import Job, JobChunk, utcnow
from fringelab.core.settings import Settings
from worker.app import create_worker_app
from worker.context import JobContext
from worker.runner import run_chunk


def _gone_pid() -> int:
    """The PID of a process that has ended (and been reaped)."""
    done = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, check=True)
    return int(done.stdout)


@pytest.fixture
def sessions(settings: Settings) -> Iterator[object]:
    engine = make_engine(settings.resolved_database_url)
    yield make_sessionmaker(engine)
    engine.dispose()


def _job(sessions, running: dict[int, str], done: set[int], chunks: int = 6) -> str:
    """A running job in phase 0 with `chunks` chunks of 10 frames: `running` {index: worker} (heartbeat now),
    `done`, the rest pending; its merge sent already."""
    now = utcnow()
    with sessions() as session:
        session.add(Job(id="job-1", kind="selftest", state="running", spec={"kind": "selftest"}, phase=0,
                        merge_queued_at=now, started_at=now, heartbeat_at=now))  # fmt: skip
        for index in range(chunks):
            state = "running" if index in running else "done" if index in done else "pending"
            session.add(JobChunk(job_id="job-1", phase=0, index=index, first_frame=10 * index,
                                 stop_frame=10 * index + 10, state=state, worker=running.get(index, ""),
                                 heartbeat_at=now if index in running else None))  # fmt: skip
        session.commit()
    return "job-1"


def _measured_by(sessions) -> dict[int, tuple[str, str]]:
    with sessions() as session:
        chunks = session.scalars(select(JobChunk).where(JobChunk.job_id == "job-1").order_by(JobChunk.index))
        return {c.index: (c.state, c.worker) for c in chunks}


def _run(settings: Settings, index: int, *, redelivered: bool = False) -> list[int]:
    """Run chunk `index`'s task here; the chunks its body measured, in order."""
    app = create_worker_app(settings)
    app.loader.import_default_modules()
    task = app.tasks[CHUNK_TASK]
    measured: list[int] = []

    def body(context: JobContext, first: int, stop: int) -> None:
        assert context.chunk is not None and (first, stop) == (10 * context.chunk[1], 10 * context.chunk[1] + 10)
        measured.append(context.chunk[1])

    task.push_request(delivery_info={"redelivered": redelivered})
    try:
        run_chunk(task, "job-1", 0, index, body)
    finally:
        task.pop_request()
    return measured


def test_a_chunk_task_goes_on_to_every_chunk_nobody_runs_and_takes_over_a_gone_process(settings, sessions) -> None:
    host = socket.gethostname()
    gone, live, elsewhere = f"w@{host} (pid {_gone_pid()})", f"w@{host} (pid {os.getpid()})", "w@far (pid 1)"
    _job(sessions, running={1: gone, 3: live, 4: elsewhere}, done={5})
    assert _run(settings, 2) == [2, 0, 1]  # its own first, then in order; 1's process is gone
    after = _measured_by(sessions)
    assert all(after[i][0] == "done" and after[i][1].endswith(f"(pid {os.getpid()})") for i in (0, 1, 2))
    assert after[3] == ("running", live) and after[4] == ("running", elsewhere), "a live or unknown process's chunk"
    assert after[5][0] == "done"


def test_a_redelivered_task_takes_its_own_chunk_over_unless_a_live_process_here_runs_it(settings, sessions) -> None:
    live = f"w@{socket.gethostname()} (pid {os.getpid()})"  # took the chunk over from the task's dead first run
    _job(sessions, running={0: "w@far (pid 1)", 1: "w@far (pid 2)", 2: live}, done={3, 4, 5})
    assert _run(settings, 2, redelivered=True) == []
    assert _run(settings, 0, redelivered=True) == [
        0
    ]  # 1 is another process's, on another machine: alive for all we know
    assert _run(settings, 1) == []


def test_a_chunk_task_of_a_job_that_no_longer_runs_measures_nothing(settings, sessions) -> None:
    _job(sessions, running={}, done=set())
    with sessions() as session:
        session.get(Job, "job-1").state = "failed"
        session.commit()
    assert _run(settings, 0) == []
