"""An uploaded simulation is read by a check job in a worker, never by the web server (issue 26, finding 4): the
upload answers at once with the simulation `checking`; a worker's check makes it `ready` or `failed` with the
reason; only a ready one can be compared; a check that dies with its worker process runs again, and one whose job
ends without a word (lost too often) leaves its simulation failed, never `checking` for ever. Real Redis and real
prefork workers (`fringelab worker`), the API in this process (so this process's memory is the web server's)."""

from __future__ import annotations

import io
import re
import signal
import uuid
import zipfile
from datetime import timedelta

import psutil
import pytest
from fastapi.testclient import TestClient

from backend.app import create_app
from fringelab.core.db import make_engine, make_sessionmaker
from fringelab.core.models import Camera, Experiment, Job, Recording, Simulation, utcnow
from fringelab.core.quota import used_bytes
from fringelab.core.reconcile import MAX_REQUEUES
from fringelab.core.storage import simulation_dir
from fringelab.formats.simulation_store import CHECKED_FILE
from tests.support import wait_for
from tests.worker.conftest import log_messages, wait_job

pytestmark = [pytest.mark.integration]
MIB = 2**20
NODES_CSV = "state,time_s,node,x_mm,y_mm,z_mm,ux_mm,uy_mm,uz_mm\n" + "".join(
    f"{s},{s * 1e-3},{n + 1},{10 * (n % 2)},{10 * (n // 2)},0,0,0,{s if n == 0 else 0}\n"
    for s in (0, 1)
    for n in range(4)
)


def ended(client: TestClient, simulation_id: int, *, timeout_s: float = 120) -> dict:
    def done() -> dict | None:
        body = client.get(f"/api/v1/simulations/{simulation_id}").json()
        return body if body["state"] != "checking" else None

    return wait_for(done, timeout_s=timeout_s, what=f"the check of simulation {simulation_id}", interval_s=0.05)  # type: ignore[return-value]


def owned_bytes(settings) -> int:  # type: ignore[no-untyped-def]
    """What the quota counts for the experiments of the local admin (accounts off)."""
    engine = make_engine(settings.resolved_database_url)
    with make_sessionmaker(engine)() as session:
        used = used_bytes(session, None)
    engine.dispose()
    return used


def a_topography_job(settings, experiment_id: int) -> str:  # type: ignore[no-untyped-def]
    """A succeeded topography job of the experiment with a result file (what a comparison names; never read here:
    the simulation is refused first)."""
    job_id = str(uuid.uuid4())
    target = settings.data_path / "results" / "jobs" / job_id / "topography.h5"
    target.parent.mkdir(parents=True)
    target.write_bytes(b"not read")
    entry = {"name": "topography.h5", "path": str(target.relative_to(settings.data_path)), "size_bytes": 8,
             "sha256": "", "media_type": "application/x-hdf5"}  # fmt: skip
    engine = make_engine(settings.resolved_database_url)
    with make_sessionmaker(engine)() as session:
        session.add(Job(id=job_id, kind="topography", state="succeeded", experiment_id=experiment_id, files=[entry],
                        spec={"kind": "topography"}, finished_at=utcnow()))  # fmt: skip
        session.commit()
    engine.dispose()
    return job_id


def test_an_upload_is_checking_until_a_worker_reads_it_and_cannot_be_compared_before(
    settings, client, start_prefork_worker
):
    experiment = client.post("/api/v1/experiments", json={"name": "plate"}).json()
    topography = a_topography_job(settings, experiment["id"])
    # no worker yet: the upload is stored and its check waits in the queue
    answer = client.put(f"/api/v1/experiments/{experiment['id']}/simulations/nodes.csv", content=NODES_CSV.encode())
    assert answer.status_code == 201, answer.text
    stored = answer.json()
    assert (stored["state"], stored["kind"], stored["n_states"]) == ("checking", "", 0), stored
    assert answer.headers["Location"] == f"/api/v1/simulations/{stored['id']}"
    assert client.get(f"/api/v1/jobs/{stored['check_job_id']}").json()["kind"] == "simulation_check"
    spec = {"kind": "comparison", "job_id": topography, "simulation_id": stored["id"]}
    for refused in (
        client.post("/api/v1/jobs", json=spec),
        client.post("/api/v1/comparisons/preview", json={"spec": spec}),
    ):
        assert refused.status_code == 409 and refused.json()["code"] == "simulation_not_ready", refused.text
        assert "still being checked" in refused.json()["detail"], refused.text
    # a ZIP of a folder is stored as received: its directory checked in the request, not a byte unpacked there
    packed = io.BytesIO()
    with zipfile.ZipFile(packed, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        archive.writestr("run/nodes.csv", NODES_CSV)
    zipped = client.put(f"/api/v1/experiments/{experiment['id']}/simulations/run.zip", content=packed.getvalue())
    assert zipped.status_code == 201 and zipped.json()["state"] == "checking", zipped.text
    model = simulation_dir(settings.data_path, zipped.json()["id"]) / "model"
    assert [p.name for p in model.iterdir()] == ["run.zip"]
    # the quota counts the store the check will write beside the upload as much again as the upload
    upload_bytes = len(NODES_CSV.encode()) + len(packed.getvalue())
    assert owned_bytes(settings) == 8 + 2 * upload_bytes  # 8: the topography job's file

    start_prefork_worker(settings, concurrency=1, flush=False)
    unpacked = ended(client, zipped.json()["id"])  # the check job unpacked it, then read it
    assert (unpacked["state"], unpacked["kind"], unpacked["n_nodes"]) == ("ready", "csv", 4), unpacked
    assert sorted(p.name for p in model.parent.iterdir()) == [CHECKED_FILE, "model"]  # nothing left of the unpacking
    assert [p.name for p in model.iterdir()] == ["nodes.csv"]
    simulation = ended(client, stored["id"])
    assert (simulation["state"], simulation["kind"], simulation["n_states"], simulation["n_nodes"]) == (
        "ready", "csv", 2, 4,
    ), simulation  # fmt: skip
    assert simulation["error"] == "" and simulation["info"]["time"] == [0.0, 0.001]
    stores = sum((simulation_dir(settings.data_path, i) / CHECKED_FILE).stat().st_size
                 for i in (stored["id"], unpacked["id"]))  # fmt: skip
    assert owned_bytes(settings) == 8 + upload_bytes + stores  # then what the stores take
    check = wait_job(client, stored["check_job_id"])  # it ends just after it made the simulation ready
    assert check["state"] == "succeeded" and check["result"]["n_nodes"] == 4, check
    peak = check["result"]["peak_rss_bytes"]
    print(f"checking process of a 4-node CSV: peak {peak / MIB:.0f} MiB")
    assert 10 * MIB < peak < 400 * MIB  # a Python with numpy: measured in the checking process, not guessed


def _exodus_declaring(path, n_nodes: int):  # type: ignore[no-untyped-def]
    """An Exodus file whose header declares `n_nodes` nodes; nothing of them is stored (16 KB)."""
    import netCDF4

    with netCDF4.Dataset(path, "w") as nc:
        for name, size in (("num_nodes", n_nodes), ("num_dim", 3), ("num_el_blk", 1), ("num_el_in_blk1", 1),
                           ("num_nod_per_el1", 4)):  # fmt: skip
            nc.createDimension(name, size)
        nc.createDimension("time_step", None)
        for axis in "xyz":
            nc.createVariable(f"coord{axis}", "f8", ("num_nodes",), fill_value=0.0, chunksizes=(1_000_000,))
        nc.createVariable("connect1", "i4", ("num_el_in_blk1", "num_nod_per_el1"))[:] = [[1, 2, 3, 4]]
        nc.createVariable("time_whole", "f8", ("time_step",))[0] = 0.0
    return path


def test_a_header_declaring_60_m_nodes_fails_its_check_and_the_web_process_does_not_grow(
    settings, client, start_prefork_worker, tmp_path
):
    """Finding 4: a 16 KB Exodus file declaring 60 M nodes took the web process from 131 to 2176 MiB. Now the web
    process stores it and answers; the worker's check refuses it from its header (60 M nodes need ~2.7 GiB of
    arrays, over the 1 GiB budget) with a sentence naming it and the setting, in a process that never allocates
    them (its peak measured there)."""
    huge = _exodus_declaring(tmp_path / "huge.exo", 60_000_000)
    assert huge.stat().st_size < 64_000
    start_prefork_worker(settings, concurrency=1)
    experiment = client.post("/api/v1/experiments", json={"name": "plate"}).json()
    web = psutil.Process()
    client.get("/api/v1/health")  # the web process warmed up: what a request loads is loaded
    before = web.memory_info().rss
    answer = client.put(f"/api/v1/experiments/{experiment['id']}/simulations/huge.exo", content=huge.read_bytes())
    assert answer.status_code == 201 and answer.json()["state"] == "checking", answer.text
    simulation = ended(client, answer.json()["id"])
    after = web.memory_info().rss
    assert simulation["state"] == "failed", simulation
    error = simulation["error"]
    assert error.startswith("huge.exo: not a simulation fringelab reads: huge.exo: declares 60000000 nodes"), error
    assert "FRINGELAB_SIMULATION_MAX_BYTES" in error and "refused before reading it" in error, error
    check = wait_job(client, simulation["check_job_id"])
    assert check["state"] == "failed" and check["error"] == error, check
    logged = next(m for m in log_messages(client, check["id"]) if "peak memory" in m)
    peak_mib = float(re.search(r"peak memory: (\d+) MiB", logged).group(1))  # type: ignore[union-attr]
    print(f"web RSS {before / MIB:.0f} -> {after / MIB:.0f} MiB; checking process peak {peak_mib:.0f} MiB")
    assert after - before < 50 * MIB, (before / MIB, after / MIB)
    assert peak_mib < 400  # 60 M nodes would be 1.4 GiB of coordinates alone: none was allocated


def test_a_check_whose_worker_process_is_killed_runs_again_and_ends_ready(settings, client, start_prefork_worker):
    worker = start_prefork_worker(settings, concurrency=1)
    experiment = client.post("/api/v1/experiments", json={"name": "plate"}).json()
    answer = client.put(f"/api/v1/experiments/{experiment['id']}/simulations/nodes.csv", content=NODES_CSV.encode())
    assert answer.status_code == 201, answer.text

    def checking_pool_process() -> psutil.Process | None:
        for pid in worker.pool_pids():
            try:
                pool = psutil.Process(pid)
                if any("fringelab.core.simulation_check" in " ".join(c.cmdline()) for c in pool.children()):
                    return pool
            except psutil.Error:
                continue
        return None

    victim = wait_for(checking_pool_process, timeout_s=60, what="the check to start", interval_s=0.005)
    victim.send_signal(signal.SIGKILL)  # type: ignore[union-attr]
    simulation = ended(client, answer.json()["id"])
    assert (simulation["state"], simulation["n_nodes"]) == ("ready", 4), simulation
    assert wait_job(client, simulation["check_job_id"])["state"] == "succeeded"
    messages = log_messages(client, simulation["check_job_id"])
    assert any(m.startswith("restarted") for m in messages), messages
    assert sum(m.startswith("succeeded") for m in messages) == 1, messages


def test_a_check_job_lost_too_often_leaves_its_upload_failed_not_busy(settings):
    """A check whose job the queue lost more than MAX_REQUEUES times (a worker dying on it each time) is failed by
    the reconciliation, and its simulation with it, saying why; so is one whose check job was deleted. Recordings
    follow the same rule (`fringelab.core.upload_checks`): one whose ingest job ended failed without saying, or
    whose job is gone, is `invalid`, never `ingesting` for ever."""
    engine = make_engine(settings.resolved_database_url)
    with make_sessionmaker(engine)() as session:
        experiment = Experiment(name="plate")
        session.add(experiment)
        session.flush()
        simulation = Simulation(experiment_id=experiment.id, filename="model.exo", path="simulations/1/model",
                                state="checking")  # fmt: skip
        session.add(simulation)
        session.flush()
        long_ago = utcnow() - timedelta(hours=1)
        job = Job(id=str(uuid.uuid4()), kind="simulation_check", spec={"simulation_id": simulation.id},
                  state="running", experiment_id=experiment.id, requeues=MAX_REQUEUES, heartbeat_at=long_ago,
                  started_at=long_ago, created_at=long_ago)  # fmt: skip
        session.add(job)
        simulation.check_job_id = job.id
        # and one whose check job was deleted (its id set to null) long ago, one just stored (its job comes next)
        orphan = Simulation(experiment_id=experiment.id, filename="b.exo", state="checking", created_at=long_ago)
        fresh = Simulation(experiment_id=experiment.id, filename="c.exo", state="checking")
        session.add_all([orphan, fresh])
        camera = Camera(experiment_id=experiment.id, name="kodak", image_width_px=64, image_height_px=48,
                        pixel_pitch_um=10.0)  # fmt: skip
        session.add(camera)
        session.flush()
        recordings = [Recording(camera_id=camera.id, kind="test", state="ingesting", filename=f"{name}.tif",
                                created_at=long_ago) for name in ("failed", "gone")]  # fmt: skip
        recordings.append(Recording(camera_id=camera.id, kind="test", state="ingesting", filename="fresh.tif"))
        session.add_all(recordings)
        session.flush()
        failed_ingest = Job(id=str(uuid.uuid4()), kind="ingest", spec={"recording_id": recordings[0].id},
                            state="failed", error="the worker was lost", experiment_id=experiment.id,
                            created_at=long_ago, finished_at=long_ago)  # fmt: skip
        session.add(failed_ingest)
        recordings[0].ingest_job_id = failed_ingest.id
        session.commit()
        ids = (simulation.id, orphan.id, fresh.id)
        recording_ids = [recording.id for recording in recordings]
    engine.dispose()
    with TestClient(create_app(settings)) as client:  # its start-up reconciles the jobs with the queue
        found, gone, waiting = (client.get(f"/api/v1/simulations/{i}").json() for i in ids)
        failed_recording, gone_recording, fresh_recording = (
            client.get(f"/api/v1/recordings/{i}").json() for i in recording_ids
        )
    assert found["state"] == "failed", found
    assert found["error"].startswith(f"the check did not finish: the job queue lost this job {MAX_REQUEUES + 1} times")
    assert (gone["state"], gone["error"]) == (
        "failed",
        "the check did not finish: its check job is gone; upload it again",
    )
    assert waiting["state"] == "checking", waiting
    assert (failed_recording["state"], failed_recording["error"]) == (
        "invalid",
        "the ingest did not finish: the worker was lost",
    )
    assert (gone_recording["state"], gone_recording["error"]) == (
        "invalid",
        "the ingest did not finish: its ingest job is gone; upload it again",
    )
    assert fresh_recording["state"] == "ingesting", fresh_recording
