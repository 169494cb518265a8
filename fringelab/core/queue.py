"""The Celery application factory. Importing this module imports no task code and no science.

The API uses it to send tasks by name (each job kind's, in `fringelab.core.job_kinds`); a worker process
(`worker.app`) makes the same app and includes its task modules.
"""

from __future__ import annotations

from celery import Celery

from fringelab.core.settings import Settings

QUEUE = "fringelab"
# What a web server process's broker calls may take: a send or a revoke from a request thread fails (a 503 naming
# the queue) rather than hold the thread (issue 26: a broadcast ping without a timeout held every thread for good).
REQUEST_BROKER_TIMEOUT_S = 5.0
REQUEST_BROKER_CONNECT_TIMEOUT_S = 3.0


def create_celery(settings: Settings, *, include: tuple[str, ...] = (), for_requests: bool = False) -> Celery:
    """Celery app on Redis (broker and results) with the crash-safe defaults every fringelab task relies on.

    `for_requests`: the web server's, whose request threads send tasks and revoke them: every socket call is
    bounded by REQUEST_BROKER_TIMEOUT_S, a send retries for at most about a second, and the connection pool holds
    two connections per thread (a broadcast takes one connection and then a producer that takes another: with
    fewer, threads holding the first each wait for good for a second one)."""
    url = settings.redis_url
    if not url:
        raise ValueError("no Redis URL: set FRINGELAB_REDIS_URL or start the system with `fringelab up`")
    app = Celery("fringelab", broker=url, backend=url, include=list(include), set_as_current=False)
    transport_options: dict[str, float] = {
        # Redelivery of a task whose whole worker vanished waits for this; it must outlast the longest job.
        "visibility_timeout": settings.visibility_timeout_s,
        # Sweep for such tasks every 10 s instead of kombu's default 10 s x 10.
        "unacked_restore_interval": 10,
        "unacked_restore_throttle": 1,
    }
    if for_requests:
        transport_options |= {
            "socket_timeout": REQUEST_BROKER_TIMEOUT_S,
            "socket_connect_timeout": REQUEST_BROKER_CONNECT_TIMEOUT_S,
        }
        app.conf.update(
            broker_pool_limit=2 * settings.resolved_api_threads + 10,
            broker_connection_timeout=REQUEST_BROKER_CONNECT_TIMEOUT_S,
            task_publish_retry_policy={
                "max_retries": 2,
                "interval_start": 0,
                "interval_step": 0.5,
                "interval_max": 0.5,
            },  # fmt: skip
            redis_socket_timeout=REQUEST_BROKER_TIMEOUT_S,
            redis_socket_connect_timeout=REQUEST_BROKER_CONNECT_TIMEOUT_S,
        )
    app.conf.update(
        task_default_queue=QUEUE,
        task_serializer="json",
        result_serializer="json",
        accept_content=["json"],
        task_acks_late=True,
        task_reject_on_worker_lost=True,
        task_track_started=True,
        task_time_limit=settings.job_time_limit_s,
        worker_prefetch_multiplier=1,
        # On a broker connection loss a running task finishes its work (its job row records the end); its message,
        # unacknowledgeable now, comes back after the visibility timeout and finds the job ended (see worker.runner).
        worker_cancel_long_running_tasks_on_connection_loss=False,
        broker_transport_options=transport_options,
        result_backend_transport_options=transport_options,
        broker_connection_retry_on_startup=True,
        result_expires=7 * 24 * 3600,
        worker_send_task_events=False,
    )
    app.fringelab_settings = settings
    return app
