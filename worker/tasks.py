"""Celery tasks: thin wrappers that load inputs by id, call `fringelab.science`, store results atomically.

Tasks are registered with `shared_task` so they bind to the app the worker process created from its settings.
"""

from __future__ import annotations

import os
import socket

from celery import shared_task


@shared_task(name="fringelab.ping")
def ping(payload: str = "pong") -> dict[str, object]:
    """A trivial end-to-end check of broker, worker and result backend."""
    return {"payload": payload, "worker_pid": os.getpid(), "host": socket.gethostname()}
