"""Every operation of the OpenAPI document, as anonymous, as another member and as the owner (or an admin).

The objects are ada's: an experiment with a camera, a ready recording (really uploaded and ingested), an
unfinished tus upload, her API token; each case runs on a fresh copy of that world. For every operation:

- anonymous gets 401, except the public operations;
- bob (a member) gets 404 for anything of ada's named in the path (or in the body, where ids travel there),
  403 on admin operations, and lists that do not mention ada's objects;
- ada (the admin on admin operations) is never told 401 or 403, nor that her object is not there.

A path parameter the table cannot fill fails the test by name: a new route cannot slip through unchecked.
"""

from __future__ import annotations

import base64
import hashlib
import io
import json
import shutil
import uuid
import zipfile
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
import redis
from celery.contrib.testing.worker import start_worker
from fastapi.testclient import TestClient

from backend.app import create_app
from fringelab.core.accounts import create_user, issue_token
from fringelab.core.db import make_engine, make_sessionmaker, upgrade_database
from fringelab.core.models import Calibration, Job, JobLog, utcnow
from fringelab.core.settings import Settings
from tests.formats.recording_files import stripe_frames, write_zip
from tests.support import bearer, wait_for
from worker.app import create_worker_app

pytestmark = pytest.mark.integration

MARKER = "ada-secret"  # in the names of ada's objects: a list that shows it to bob leaks them
# Public on purpose (tests/api/lab/test_openapi.py says why).
PUBLIC = {
    ("GET", "/api/v1/health"),
    ("POST", "/api/v1/auth/login"),
    ("OPTIONS", "/api/v1/uploads"),
    ("GET", "/api/v1/docs"),
    ("GET", "/api/v1/docs/{name}"),
}
ADMIN = {
    ("GET", "/api/v1/users"),
    ("POST", "/api/v1/users"),
    ("PATCH", "/api/v1/users/{user_id}"),
    ("POST", "/api/v1/groups"),
    ("GET", "/api/v1/audit"),
}
# Operations whose object travels in the body or a header rather than the path: bob names ada's object there, and
# must get exactly the answer an id that does not exist gets (a second request names one).
BODY_REFERENCED = {("POST", "/api/v1/uploads"), ("POST", "/api/v1/jobs"), ("POST", "/api/v1/comparisons/preview")}
NOBODY_ID = 2**31 - 1
NOBODY_JOB = "00000000-0000-0000-0000-000000000000"
# 404 codes that mean "no such object" (for the owner, never about her own object).
MISSING = {
    "not_found",
    "upload_not_found",
    "job_not_found",
    "calibration_not_found",
    "recording_not_found",
    "simulation_not_found",
}
TUS = {"Tus-Resumable": "1.0.0"}


@dataclass
class World:
    data_dir: Path
    settings: Settings
    tokens: dict[str, str]
    ids: dict[str, Any]


def _b64(value: object) -> str:
    return base64.b64encode(str(value).encode()).decode()


# How to fill each path parameter with ada's object (the path template tells which object a name means).
PATH_VALUES: dict[str, Callable[[World, str], object]] = {
    "experiment_id": lambda w, _: w.ids["experiment"],
    "camera_id": lambda w, _: w.ids["camera"],
    "recording_id": lambda w, _: w.ids["recording"],
    "token_id": lambda w, _: w.ids["token"],
    "user_id": lambda w, _: w.ids["ada"],
    "uuid": lambda w, _: w.ids["upload"],
    "index": lambda w, _: 0,
    "filename": lambda w, _: "again.zip",
    "name": lambda w, path: "z.csv" if "/sidecars/" in path else "method" if "/docs/" in path else w.ids["job_file"],
    "job_id": lambda w, _: w.ids["job"],
    "other_job_id": lambda w, _: w.ids["job"],
    "calibration_id": lambda w, _: w.ids["calibration"],
    "simulation_id": lambda w, _: w.ids["simulation"],
}
# A finite-element simulation as small as one can be: a nodal CSV of 4 nodes and 2 states, zipped.
SIMULATION_CSV = "state,time_s,node,x_mm,y_mm,z_mm,ux_mm,uy_mm,uz_mm\n" + "".join(
    f"{state},{state * 1e-3},{node + 1},{10 * (node % 2)},{10 * (node // 2)},0,0,0,{state if node == 0 else 0}\n"
    for state in (0, 1)
    for node in range(4)
)


def simulation_zip() -> bytes:
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        archive.writestr("model/nodes.csv", SIMULATION_CSV)
    return buffer.getvalue()


def _request(world: World, method: str, path: str) -> dict[str, Any]:
    """What each operation is sent: a well-formed request for the owner, so that her answer means something."""
    camera = world.ids["camera"]
    zip_bytes = world.ids["zip_bytes"]
    requests: dict[tuple[str, str], dict[str, Any]] = {
        ("POST", "/api/v1/auth/login"): {"json": {"username": "ada", "password": "ada-password"}},
        ("POST", "/api/v1/auth/tokens"): {"json": {"name": "another script"}},
        ("POST", "/api/v1/users"): {"json": {"username": "dora", "password": "dora-password"}},
        ("PATCH", "/api/v1/users/{user_id}"): {"json": {"role": "member"}},
        ("POST", "/api/v1/groups"): {"json": {"name": "impact-lab", "members": ["ada"]}},
        ("POST", "/api/v1/experiments"): {"json": {"name": "plate 9"}},
        ("PATCH", "/api/v1/experiments/{experiment_id}"): {"json": {"notes": "punch 20 mm"}},
        ("POST", "/api/v1/experiments/{experiment_id}/cameras"): {
            "json": {"name": "right", "image_width_px": 64, "image_height_px": 48, "pixel_pitch_um": 20.0}
        },
        ("PATCH", "/api/v1/cameras/{camera_id}"): {"json": {"pixel_pitch_um": 28.0}},
        ("PATCH", "/api/v1/recordings/{recording_id}"): {"json": {"filename": "renamed.zip"}},
        ("PUT", "/api/v1/recordings/{recording_id}/sidecars/{name}"): {
            "content": b"frame,z_mm\n0,0\n1,2\n2,4\n",
            "headers": {"Content-Type": "text/plain"},
        },
        ("PUT", "/api/v1/uploads/cameras/{camera_id}/{filename}"): {"params": {"kind": "test"}, "content": zip_bytes},
        ("PUT", "/api/v1/experiments/{experiment_id}/simulations/{filename}"): {"content": simulation_zip()},
        ("POST", "/api/v1/uploads"): {
            "headers": {
                **TUS,
                "Upload-Length": str(len(zip_bytes)),
                "Upload-Metadata": f"filename {_b64('r.zip')},filetype {_b64('x')},camera_id {_b64(camera)},"
                f"kind {_b64('test')}",
            }
        },
        ("POST", "/api/v1/jobs"): {"json": {"kind": "export", "job_id": world.ids["job"], "format": "grid-npz"}},
        ("POST", "/api/v1/comparisons/preview"): {
            "json": {
                "spec": {"kind": "comparison", "job_id": world.ids["job"], "simulation_id": world.ids["simulation"]}
            }
        },
        ("GET", "/api/v1/jobs/{job_id}/topography/grid"): {"params": {"frame": 0}},
        ("GET", "/api/v1/jobs/{job_id}/topography/profile"): {
            "params": {"x0_mm": 0, "y0_mm": 0, "x1_mm": 10, "y1_mm": 0, "frames": [0]}
        },
        ("GET", "/api/v1/jobs/{job_id}/topography/history"): {"params": {"x_mm": 0, "y_mm": 0}},
        ("GET", "/api/v1/calibrations/pairs"): {"params": {"camera_id": world.ids["camera"]}},
        ("HEAD", "/api/v1/uploads/{uuid}"): {"headers": TUS},
        ("DELETE", "/api/v1/uploads/{uuid}"): {"headers": TUS},
        ("PATCH", "/api/v1/uploads/{uuid}"): {
            "headers": {**TUS, "Upload-Offset": "0", "Content-Type": "application/offset+octet-stream"},
            "content": zip_bytes[:10],
        },
    }
    return requests.get((method, path), {})


def _operations() -> list[tuple[str, str]]:
    settings = Settings(_env_file=None, redis_url="redis://127.0.0.1:9/0", auth_enabled=True)  # type: ignore[call-arg]
    document = create_app(settings).openapi()
    methods = ("get", "put", "post", "delete", "options", "head", "patch")
    return [(method.upper(), path) for path, item in document["paths"].items() for method in methods if method in item]


OPERATIONS = _operations()


@pytest.fixture(scope="module")
def template(tmp_path_factory: pytest.TempPathFactory, redis_server) -> Iterator[World]:  # type: ignore[no-untyped-def]
    """ada's world, built once through the API (and a real ingest), copied for every case."""
    data_dir = tmp_path_factory.mktemp("access") / "var"
    # Event streams of lists end soon (they otherwise stay open for minutes; the browser reconnects).
    settings = Settings(
        _env_file=None, data_dir=data_dir, redis_url=redis_server.url, auth_enabled=True, list_events_s=0.5
    )  # type: ignore[call-arg]
    upgrade_database(settings.resolved_database_url)
    redis.Redis.from_url(redis_server.url).flushdb()
    engine = make_engine(settings.resolved_database_url)
    tokens, ids = {}, {}
    with make_sessionmaker(engine)() as session:
        for name, role in (("admin", "admin"), ("ada", "member"), ("bob", "member")):
            user = create_user(session, name, f"{name}-password", role=role)
            ids[name] = user.id
            tokens[name] = issue_token(session, user, name=f"{MARKER} token" if name == "ada" else "tests")[1]
        session.commit()
    engine.dispose()
    zip_bytes = write_zip(tmp_path_factory.mktemp("zip") / "r.zip", stripe_frames(3)).read_bytes()
    ids["zip_bytes"] = zip_bytes
    celery = create_worker_app(settings)
    celery.loader.import_default_modules()
    ada = bearer(tokens["ada"])
    with (
        start_worker(celery, pool="threads", concurrency=1, perform_ping_check=False, shutdown_timeout=30),
        TestClient(create_app(settings)) as client,
    ):
        experiment = client.post("/api/v1/experiments", json={"name": f"{MARKER} plate"}, headers=ada).json()
        camera = client.post(
            f"/api/v1/experiments/{experiment['id']}/cameras",
            json={"name": "left", "image_width_px": 64, "image_height_px": 48, "pixel_pitch_um": 20.0},
            headers=ada,
        ).json()
        put = f"/api/v1/uploads/cameras/{camera['id']}/{MARKER}.zip"
        recording = client.put(put, params={"kind": "test"}, content=zip_bytes, headers=ada)
        assert recording.status_code == 201, recording.text

        def ready() -> bool:
            return client.get(f"/api/v1/recordings/{recording.json()['id']}", headers=ada).json()["state"] == "ready"

        wait_for(ready, timeout_s=60, what="the ingest of ada's recording")
        created = client.post(
            "/api/v1/uploads", headers={**_request_headers_for_upload(camera["id"], zip_bytes), **ada}
        )
        assert created.status_code == 201, created.text
        simulation = client.put(
            f"/api/v1/experiments/{experiment['id']}/simulations/{MARKER}.zip", content=simulation_zip(), headers=ada
        )
        assert simulation.status_code == 201, simulation.text

        def simulation_ready() -> bool:  # its check job, in the worker: a comparison takes only a ready one
            found = client.get(f"/api/v1/simulations/{simulation.json()['id']}", headers=ada).json()
            assert found["state"] != "failed", found
            return found["state"] == "ready"

        wait_for(simulation_ready, timeout_s=60, what="the check of ada's simulation")
        ids.update(
            simulation=simulation.json()["id"],
            experiment=experiment["id"],
            camera=camera["id"],
            recording=recording.json()["id"],
            upload=created.headers["Location"].rsplit("/", 1)[1],
            token=client.get("/api/v1/auth/tokens", headers=ada).json()[0]["id"],
        )
    ids.update(_finished_job_and_calibration(settings, ids))
    yield World(data_dir, settings, tokens, ids)


def _finished_job_and_calibration(settings: Settings, ids: dict[str, Any]) -> dict[str, Any]:
    """A succeeded job of ada's experiment with a result file, and a calibration of her camera (rows as the workers
    write them; the science behind them is not what this test is about)."""
    job_id = str(uuid.uuid4())
    result = settings.data_path / "results" / "jobs" / job_id / "result.txt"
    result.parent.mkdir(parents=True)
    result.write_text(f"{MARKER} result\n")
    calibration_file = settings.data_path / "results" / "jobs" / job_id / "camera.json"
    calibration_file.write_text("{}\n")
    engine = make_engine(settings.resolved_database_url)
    with make_sessionmaker(engine)() as session:
        job = Job(
            id=job_id,
            kind="topography",
            state="succeeded",
            experiment_id=ids["experiment"],
            spec={"kind": "topography", "recording_id": ids["recording"]},
            finished_at=utcnow(),
            files=[
                {
                    "name": "result.txt",
                    "path": str(result.relative_to(settings.data_path)),
                    "size_bytes": result.stat().st_size,
                    "sha256": hashlib.sha256(result.read_bytes()).hexdigest(),
                    "media_type": "text/plain",
                }
            ],
        )
        session.add(job)
        session.flush()  # the job first: the log line and the calibration refer to it
        session.add(JobLog(job_id=job_id, message=f"{MARKER} done"))
        calibration = Calibration(
            kind="camera",
            camera_id=ids["camera"],
            job_id=job_id,
            path=str(calibration_file.relative_to(settings.data_path)),
            image_width_px=64,
            image_height_px=48,
        )
        session.add(calibration)
        session.commit()
        made = {"job": job_id, "job_file": "result.txt", "calibration": calibration.id}
    engine.dispose()
    return made


def _request_headers_for_upload(camera_id: int, data: bytes) -> dict[str, str]:
    metadata = f"filename {_b64('part.zip')},filetype {_b64('x')},camera_id {_b64(camera_id)},kind {_b64('test')}"
    return {**TUS, "Upload-Length": str(len(data)), "Upload-Metadata": metadata}


@pytest.fixture
def world(template: World, tmp_path: Path) -> World:
    """A fresh copy of ada's world (an owner's DELETE must not change the next case)."""
    data_dir = tmp_path / "var"
    shutil.copytree(template.data_dir, data_dir, symlinks=True)
    settings = template.settings.model_copy(update={"data_dir": data_dir})
    redis.Redis.from_url(settings.redis_url).flushdb()  # no login failures of earlier cases
    return World(data_dir, settings, template.tokens, template.ids)


def _url(world: World, method: str, path: str) -> str:
    url = path
    for name in _path_parameters(path):
        if name not in PATH_VALUES:
            pytest.fail(
                f"{method} {path}: the access-control table cannot fill the path parameter {{{name}}}; add it to "
                "PATH_VALUES in tests/api/lab/test_access_control.py (an object of ada's), "
                "and to the world if it is new"
            )
        url = url.replace(f"{{{name}}}", str(PATH_VALUES[name](world, path)))
    return url


def _naming_nobody(world: World, request: dict[str, Any]) -> dict[str, Any]:
    """The same request with ada's ids in the body or headers replaced by ids that nobody has."""
    changed = dict(request)
    if "json" in request:
        text = json.dumps(request["json"]).replace(world.ids["job"], NOBODY_JOB)
        changed["json"] = json.loads(text)
    headers = dict(request.get("headers", {}))
    if "Upload-Metadata" in headers:
        headers["Upload-Metadata"] = headers["Upload-Metadata"].replace(_b64(world.ids["camera"]), _b64(NOBODY_ID))
    changed["headers"] = headers
    return changed


def _path_parameters(path: str) -> list[str]:
    return [part[1:-1].split(":")[0] for part in path.split("/") if part.startswith("{") and part.endswith("}")]


def _send(client: TestClient, method: str, url: str, token: str | None, request: dict[str, Any]) -> Any:
    headers = {**request.get("headers", {}), **(bearer(token) if token else {})}
    kwargs = {key: value for key, value in request.items() if key != "headers"}
    if method == "GET" and url.endswith("/events"):
        with client.stream(method, url, headers=headers, **kwargs) as response:
            response.read()  # the job has ended: the stream ends too
            return response
    return client.request(method, url, headers=headers, **kwargs)


def _code(response: Any) -> str:
    try:
        return str(response.json().get("code"))
    except ValueError:
        return ""


@pytest.mark.parametrize(("method", "path"), OPERATIONS, ids=[f"{m} {p}" for m, p in OPERATIONS])
def test_access_to_every_operation(world: World, method: str, path: str) -> None:
    url = _url(world, method, path)
    request = _request(world, method, path)
    with TestClient(create_app(world.settings)) as client:
        anonymous = _send(client, method, url, None, request)
        if (method, path) in PUBLIC:
            assert anonymous.status_code not in (401, 403), (anonymous.status_code, anonymous.text)
        else:
            assert anonymous.status_code == 401, f"anonymous: {anonymous.status_code} {anonymous.text}"

        other = _send(client, method, url, world.tokens["bob"], request)
        if (method, path) in ADMIN:
            assert other.status_code == 403, f"bob on an admin operation: {other.status_code} {other.text}"
        elif (method, path) in BODY_REFERENCED:
            nobody = _send(client, method, url, world.tokens["bob"], _naming_nobody(world, request))
            assert (other.status_code, _code(other)) == (nobody.status_code, _code(nobody)), (other.text, nobody.text)
            assert other.status_code in (404, 422) and _code(other) in MISSING, other.text
        elif _path_parameters(path) and (method, path) not in PUBLIC:
            assert other.status_code == 404, f"bob on ada's object: {other.status_code} {other.text}"
            assert method == "HEAD" or _code(other) in MISSING, other.text  # a HEAD answer has no body
            assert MARKER not in other.text
        elif (method, path) not in PUBLIC:
            assert other.status_code < 400, f"bob on his own lists: {other.status_code} {other.text}"
            assert MARKER not in other.text, f"bob sees ada's objects: {other.text[:500]}"

        owner = "admin" if (method, path) in ADMIN else "ada"
        mine = _send(client, method, url, world.tokens[owner], request)
        assert mine.status_code not in (401, 403), f"{owner}: {mine.status_code} {mine.text}"
        assert mine.status_code != 404 or _code(mine) not in MISSING, f"{owner} told her object is missing: {mine.text}"
        assert mine.status_code != 500, mine.text
