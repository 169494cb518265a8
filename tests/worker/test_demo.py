"""POST /api/v1/demo: the experiment is stored at once and the demo task is queued by name (the whole path, with
a real worker, is the browser test tests/browser/test_demo_view.py)."""

from __future__ import annotations

import base64
import json
from collections.abc import Iterator

import pytest
import redis
from fastapi.testclient import TestClient

from backend.app import create_app
from fringelab.core.queue import QUEUE
from fringelab.core.settings import Settings


@pytest.fixture
def client(settings: Settings) -> Iterator[TestClient]:
    redis.Redis.from_url(settings.redis_url).flushdb()
    with TestClient(create_app(settings)) as made:
        yield made


def queued_tasks(settings: Settings) -> list[tuple[str, list]]:
    """(task name, args) of the messages waiting in the queue."""
    found = []
    for raw in redis.Redis.from_url(settings.redis_url).lrange(QUEUE, 0, -1):
        message = json.loads(raw)
        body = message["body"]
        if message["properties"].get("body_encoding") == "base64":
            body = base64.b64decode(body)
        args = json.loads(body)
        found.append((message["headers"]["task"], args))
    return found


def test_demo_stores_the_experiment_and_queues_its_task(client, settings):
    answer = client.post("/api/v1/demo", json={"cameras": ["kodak", "kodak"], "test_frames": 8})
    assert answer.status_code == 202, answer.text
    experiment_id = answer.json()["experiment_id"]
    experiment = client.get(f"/api/v1/experiments/{experiment_id}").json()
    assert experiment["name"].startswith("Demo: virtual punch test")
    assert "kodak" in experiment["notes"]
    assert client.get(f"/api/v1/experiments/{experiment_id}/cameras").json() == []  # the worker adds them
    tasks = queued_tasks(settings)
    assert len(tasks) == 1
    name, body = tasks[0]
    assert name == "fringelab.demo"
    assert body[0] == [experiment_id, ["kodak"], 8, "quasi-static"]  # each camera once


def test_demo_without_a_body_makes_both_cameras(client, settings):
    assert client.post("/api/v1/demo").status_code == 202
    (name, body), *_ = queued_tasks(settings)
    assert body[0][1:] == [["kodak", "phantom"], 20, "quasi-static"]


@pytest.mark.parametrize("scenario", ["fast", "petals", "highlight", "shadow", "hard"])
def test_demo_makes_the_hard_virtual_tests(client, settings, scenario):
    answer = client.post("/api/v1/demo", json={"cameras": ["kodak"], "test_frames": 6, "scenario": scenario})
    assert answer.status_code == 202, answer.text
    experiment = client.get(f"/api/v1/experiments/{answer.json()['experiment_id']}").json()
    assert scenario in experiment["name"] and f"--scenario {scenario}" in experiment["notes"]
    (name, body), *_ = queued_tasks(settings)
    assert body[0][1:] == [["kodak"], 6, scenario]


@pytest.mark.parametrize(
    "body, field",
    [
        ({"cameras": ["nikon"]}, "cameras"),
        ({"cameras": []}, "cameras"),
        ({"test_frames": 2}, "test_frames"),
        ({"scenario": "earthquake"}, "scenario"),
        # The fast test is a ramp and three perforated frames: 5 frames cannot hold it.
        ({"scenario": "fast", "test_frames": 5}, "the fast scenario needs at least 6 frames"),
    ],
)
def test_demo_refuses_what_it_cannot_simulate(client, settings, body, field):
    answer = client.post("/api/v1/demo", json=body)
    assert answer.status_code == 422
    assert field in answer.json()["detail"]
    assert queued_tasks(settings) == []
