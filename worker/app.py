"""The worker process: the Celery app with fringelab's tasks, and `python -m worker` (what `fringelab worker` runs)."""

from __future__ import annotations

import os
import sys
from collections.abc import Sequence

from celery import Celery, bootsteps
from celery.signals import worker_process_init

from fringelab.core.liveness import Heartbeat
from fringelab.core.queue import create_celery
from fringelab.core.settings import Settings, SettingsError, load_settings
from fringelab.core.startup_checks import ServiceError, check_redis

TASK_MODULES = ("worker.tasks",)


def create_worker_app(settings: Settings) -> Celery:
    """The Celery app of a worker process: the shared queue settings plus every task."""
    app = create_celery(settings, include=TASK_MODULES)
    app.steps["consumer"].add(HeartbeatStep)
    return app


@worker_process_init.connect
def one_thread_per_process(**_: object) -> None:
    """OpenCV's thread pool, one thread: the worker's processes are its parallelism (one per core); a pool per
    process on top would put more threads than cores on the machine (`worker.__main__` does the same for BLAS)."""
    import cv2

    cv2.setNumThreads(1)


class HeartbeatStep(bootsteps.StartStopStep):
    """Once the worker consumes tasks, its main process beats in Redis (`fringelab.core.liveness`): what
    `/api/v1/health` counts, instead of a broadcast ping from a request thread. A consumer step, so that every
    way of running the worker (the CLI, the tests' in-process worker) beats."""

    requires = ("celery.worker.consumer.tasks:Tasks",)

    def __init__(self, parent: object, **kwargs: object) -> None:
        super().__init__(parent, **kwargs)
        self.heartbeat: Heartbeat | None = None

    def start(self, parent: object) -> None:
        settings = getattr(getattr(parent, "app", None), "fringelab_settings", None)
        if settings is None or not settings.redis_url or self.heartbeat is not None:
            return
        self.heartbeat = Heartbeat(settings.redis_url, str(getattr(parent, "hostname", os.getpid())))
        self.heartbeat.start()

    def shutdown(self, parent: object) -> None:
        if self.heartbeat is not None:
            self.heartbeat.stop()
            self.heartbeat = None


def lower_priority(nice: int) -> None:
    """Run this process and its pool processes (they inherit it) at niceness `nice` (FRINGELAB_WORKER_NICE): on
    one machine, a topography job using every core then yields the CPU to the web server's requests. Only ever
    lowers the priority (raising it needs privileges)."""
    if hasattr(os, "setpriority"):
        current = os.getpriority(os.PRIO_PROCESS, 0)
        if nice > current:
            os.setpriority(os.PRIO_PROCESS, 0, nice)


def main(argv: Sequence[str] | None = None) -> int:
    """Start a prefork worker, one process per core (FRINGELAB_WORKER_CONCURRENCY); exit 2 on a start-up fault."""
    try:
        settings = load_settings()
        if not settings.redis_url:
            raise ServiceError("FRINGELAB_REDIS_URL is not set; a worker needs the queue of a running fringelab")
        check_redis(settings.redis_url, wait_s=settings.worker_redis_wait_s)
    except (SettingsError, ServiceError) as error:
        print(f"fringelab worker: {error}", file=sys.stderr)
        return 2
    lower_priority(settings.worker_nice)
    create_worker_app(settings).worker_main(
        [
            "worker",
            "--pool=prefork",
            f"--concurrency={settings.resolved_worker_concurrency}",
            f"--loglevel={settings.log_level.upper()}",
            f"--hostname=fringelab-{os.getpid()}@%h",
            "--without-mingle",
            "--without-gossip",
            *(argv or ()),
        ]
    )
    return 0
