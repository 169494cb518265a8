"""Simulations uploaded into an experiment and comparison jobs, through the API with a real Redis and worker.

The measurement is the virtual test's topography (tests/pipelines/conftest.py, `measured`: 8 frames), made
by the pipeline and registered as a succeeded topography job of the experiment; the simulation is that
experiment's true surface (`write_true_simulation`), uploaded as a ZIP of its CSV folder. When the simulation is
the truth, w_meas − w_sim is the measurement's own error: its RMS per frame must equal the RMS of w_meas − w_true
over the same nodes, within 10 % (the tolerance and its reasons are those of tests/pipelines/test_comparison.py:
the model's linear interpolation adds about 1.6 %, a mapping off by 0.1 mm or a wrong state adds far more).
"""

from __future__ import annotations

import io
import shutil
import uuid
import zipfile
from pathlib import Path

import numpy as np

from fringelab.core.db import make_engine, make_sessionmaker
from fringelab.core.models import Job, utcnow
from fringelab.formats.comparison import ComparisonResult
from fringelab.pipelines.virtual_test import write_true_simulation
from tests.pipelines.conftest import measured  # noqa: F401  (the session's measured virtual test)
from tests.support import wait_for
from tests.worker.conftest import wait_job

RMS_TOLERANCE = 0.10


def zipped(folder: Path) -> bytes:
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        for path in sorted(folder.rglob("*")):
            if path.is_file():
                archive.write(path, Path(folder.name) / path.relative_to(folder))
    return buffer.getvalue()


def add_topography_jobs(settings, experiment_id: int, result: Path) -> dict[str, str]:  # type: ignore[no-untyped-def]
    """A succeeded topography job of the experiment holding `result`, and one still running."""
    done, running = str(uuid.uuid4()), str(uuid.uuid4())
    target = settings.data_path / "results" / "jobs" / done / "topography.h5"
    target.parent.mkdir(parents=True)
    shutil.copyfile(result, target)
    entry = {"name": "topography.h5", "path": str(target.relative_to(settings.data_path)),
             "size_bytes": target.stat().st_size, "sha256": "", "media_type": "application/x-hdf5"}  # fmt: skip
    engine = make_engine(settings.resolved_database_url)
    with make_sessionmaker(engine)() as session:
        session.add(Job(id=done, kind="topography", state="succeeded", experiment_id=experiment_id, files=[entry],
                        spec={"kind": "topography"}, finished_at=utcnow()))  # fmt: skip
        session.add(Job(id=running, kind="topography", state="running", experiment_id=experiment_id,
                        spec={"kind": "topography"}))  # fmt: skip
        session.commit()
    engine.dispose()
    return {"done": done, "running": running}


def checked(client, answer) -> dict:  # type: ignore[no-untyped-def]
    """The simulation an upload's answer (201, `checking`) names, once its check job has made it ready or failed."""
    assert answer.status_code == 201, answer.text
    assert answer.json()["state"] == "checking", answer.text

    def ended() -> dict | None:
        body = client.get(f"/api/v1/simulations/{answer.json()['id']}").json()
        return body if body["state"] != "checking" else None

    return wait_for(ended, timeout_s=120, what=f"the check of simulation {answer.json()['id']}", interval_s=0.1)  # type: ignore[return-value]


def leftovers(settings) -> list[Path]:  # type: ignore[no-untyped-def]
    """Files or folders under the upload staging area and the simulations' store."""
    found: list[Path] = []
    for folder in (settings.data_path / "uploads" / "put", settings.data_path / "simulations"):
        if folder.exists():
            found += list(folder.iterdir())
    return found


def test_a_simulation_that_is_the_truth_differs_from_the_measurement_by_its_error(
    client,
    celery_worker,
    settings,
    measured,  # noqa: F811
    tmp_path,
) -> None:  # type: ignore[no-untyped-def]
    experiment = client.post("/api/v1/experiments", json={"name": "virtual kodak"}).json()
    jobs = add_topography_jobs(settings, experiment["id"], measured.result)
    base = f"/api/v1/experiments/{experiment['id']}/simulations"

    # a file that is no simulation: its check fails naming the file and what is expected; deleted, nothing is left
    refused = checked(client, client.put(f"{base}/notes.txt", content=b"this is not a model\n"))
    assert refused["state"] == "failed", refused
    assert "notes.txt" in refused["error"] and "d3plot" in refused["error"], refused
    not_a_zip = checked(client, client.put(f"{base}/broken.zip", content=b"PK\x03\x04 truncated"))
    assert not_a_zip["state"] == "failed" and "broken.zip" in not_a_zip["error"], not_a_zip
    failed_check = client.get(f"/api/v1/jobs/{refused['check_job_id']}").json()
    assert failed_check["kind"] == "simulation_check" and failed_check["state"] == "failed", failed_check
    assert "notes.txt" in failed_check["error"]
    for failed in (refused, not_a_zip):
        assert client.delete(f"/api/v1/simulations/{failed['id']}").status_code == 204
    assert client.get(base).json() == []
    assert leftovers(settings) == []

    folder = write_true_simulation(measured.truth_json, tmp_path / "fe", kind="csv")
    simulation = checked(client, client.put(f"{base}/plate-fe.zip", content=zipped(folder)))
    assert (simulation["state"], simulation["kind"], simulation["n_states"]) == ("ready", "csv", 8), simulation
    assert simulation["info"]["has_force"] and simulation["info"]["has_punch_displacement"]
    assert client.get(base).json() == [simulation]
    assert client.get(f"/api/v1/simulations/{simulation['id']}").json() == simulation

    spec = {"kind": "comparison", "simulation_id": simulation["id"], "format": "csv"}
    # the mapping form's live preview: the mapping resolved, and the profiles through the punch axis of the most
    # deflected paired frame, measured against simulated (the truth: apart by the measurement's error only)
    answer = client.post("/api/v1/comparisons/preview", json={"spec": {**spec, "job_id": jobs["done"]}})
    assert answer.status_code == 200, answer.text
    preview = answer.json()
    assert preview["mapping"]["length_unit"] == "mm" and "symmetry" in preview["mapping"]["detected"]
    peaks = np.array(preview["frames"]["peak_w_mm"], dtype=float)
    assert preview["frame"] == preview["frames"]["frame"][int(np.nanargmax(peaks))]
    for axis in ("x", "y"):
        cut = {name: np.array(values, dtype=float) for name, values in preview["profiles"][axis].items()}
        both = cut["measured_mm"] - cut["simulated_mm"]
        own_error = cut["measured_mm"] - measured.true_w_mm(preview["frame"], cut["x_mm"], cut["y_mm"])
        # the difference is the measurement's own error against the truth, up to the model's mesh and the states'
        # interpolation (0.07-0.14 mm seen). The measurement's error itself is not this test's: at the punch
        # shadow's rim it reaches 1 mm in the deepest measured frame (the edge locator's open defect, issue 29)
        assert np.count_nonzero(np.isfinite(both)) > 20 and np.nanmax(np.abs(both - own_error)) < 0.2, axis
    # a wrong choice is a 422 naming the form's setting, not a command-line option
    wrong_unit = client.post("/api/v1/comparisons/preview",
                             json={"spec": {**spec, "job_id": jobs["done"], "units": "m"}})  # fmt: skip
    assert wrong_unit.status_code == 422 and wrong_unit.json()["code"] == "mapping_not_possible", wrong_unit.text
    assert "“Units”" in wrong_unit.json()["detail"] and "--" not in wrong_unit.json()["detail"], wrong_unit.text
    no_frame = client.post("/api/v1/comparisons/preview", json={"spec": {**spec, "job_id": jobs["done"]}, "frame": 999})
    assert no_frame.status_code == 422 and no_frame.json()["code"] == "frame_not_in_result", no_frame.text
    running = client.post("/api/v1/jobs", json={**spec, "job_id": jobs["running"]})
    assert running.status_code == 409 and running.json()["code"] == "job_not_succeeded", running.text
    elsewhere = client.post("/api/v1/experiments", json={"name": "another"}).json()
    other = add_topography_jobs(settings, elsewhere["id"], measured.result)
    wrong = client.post("/api/v1/jobs", json={**spec, "job_id": other["done"]})
    assert wrong.status_code == 422 and wrong.json()["code"] == "simulation_not_found", wrong.text

    created = client.post("/api/v1/jobs", json={**spec, "job_id": jobs["done"]})
    assert created.status_code == 201, created.text
    job = wait_job(client, created.json()["id"], timeout_s=300)
    assert job["state"] == "succeeded", job["error"]
    assert {f["name"] for f in job["files"]} == {"comparison.h5", "comparison.csv"}

    overview = client.get(f"/api/v1/jobs/{job['id']}/comparison").json()
    assert overview["alignment"] == "displacement"
    assert overview["frames"]["state_lo"] == preview["frames"]["state_lo"]  # the preview pairs as the comparison
    assert overview["frames"]["reason"] == [""] * 8
    path = settings.data_path / "results" / "jobs" / job["id"] / "comparison.h5"
    with ComparisonResult(path) as comparison:
        gx, gy = np.meshgrid(comparison.grid.x_mm, comparison.grid.y_mm)
        for i, frame in enumerate(overview["frames"]["frame"]):
            error = comparison.field("w_meas_mm", i) - measured.true_w_mm(frame, gx, gy)
            used = np.isfinite(comparison.field("diff_mm", i)) & np.isfinite(error)
            expected = float(np.sqrt(np.mean(error[used] ** 2)))
            rms = overview["frames"]["rms_diff_mm"][i]
            assert abs(rms - expected) <= RMS_TOLERANCE * expected, (frame, rms, expected)
    # both curves: the simulation's punch travel at each frame is the measured one (the states are the frames)
    np.testing.assert_allclose(overview["frames"]["sim_punch_displacement_mm"],
                               overview["frames"]["punch_displacement_mm"], atol=1e-3)  # fmt: skip
    assert len(overview["simulation"]["peak_w_mm"]) == 8

    frame = overview["frames"]["frame"][5]
    cut = client.get(f"/api/v1/jobs/{job['id']}/comparison/grid", params={"frame": frame, "budget": 40}).json()
    assert cut["step"] > 1 and max(len(cut["x_mm"]), len(cut["y_mm"])) <= 40
    diff = np.array(cut["values_mm"], dtype=float)
    assert np.nanmax(np.abs(diff)) < 1.0  # the truth: differences are the measurement's noise, not millimetres
    sigma = client.get(f"/api/v1/jobs/{job['id']}/comparison/grid",
                       params={"frame": frame, "field": "sigma_w_mm", "budget": 40}).json()  # fmt: skip
    assert np.nanmin(np.array(sigma["values_mm"], dtype=float)) > 0
    profile = client.get(f"/api/v1/jobs/{job['id']}/comparison/profile", params={"frame": frame, "axis": "y"}).json()
    measured_w = np.array(profile["measured_mm"], dtype=float)
    simulated_w = np.array(profile["simulated_mm"], dtype=float)
    both = np.isfinite(measured_w) & np.isfinite(simulated_w)
    assert both.sum() > 20 and np.nanmax(simulated_w) > 5.0
    # σ_w along the profile (the ±σ band): known at the compared points but the data's very edge
    assert np.mean(np.isfinite(np.array(profile["sigma_mm"], dtype=float)[both])) > 0.8
    missing = client.get(f"/api/v1/jobs/{job['id']}/comparison/grid", params={"frame": 999})
    assert missing.status_code == 422 and missing.json()["code"] == "frame_not_in_result", missing.text
    not_comparison = client.get(f"/api/v1/jobs/{jobs['done']}/comparison")
    assert not_comparison.status_code == 404, not_comparison.text

    # exports of the comparison (the export job, as the comparison view starts them): VTK is a .pvd with its .vtu
    exported = client.post("/api/v1/jobs", json={"kind": "export", "job_id": job["id"], "format": "vtk"})
    assert exported.status_code == 201, exported.text
    export_job = wait_job(client, exported.json()["id"], timeout_s=120)
    assert export_job["state"] == "succeeded", export_job["error"]
    download = client.get(export_job["files"][0]["url"])
    with zipfile.ZipFile(io.BytesIO(download.content)) as archive:
        names = archive.namelist()
    assert "comparison.pvd" in names and sum(n.endswith(".vtu") for n in names) == 8, names
    # the profile the view shows, along Y through the punch axis: its line goes with the export
    line = [profile["x_mm"][0], profile["y_mm"][0], profile["x_mm"][-1], profile["y_mm"][-1]]
    spec = {"kind": "export", "job_id": job["id"], "format": "profile-csv", "line": line}
    profile_job = wait_job(client, client.post("/api/v1/jobs", json=spec).json()["id"], timeout_s=120)
    assert profile_job["state"] == "succeeded", profile_job["error"]
    rows = client.get(profile_job["files"][0]["url"]).text.splitlines()
    assert rows[0] == "frame,s_mm,x_mm,y_mm,w_meas_mm,w_sim_mm,diff_mm,sigma_w_mm,beyond_2sigma"
    xs = {round(float(row.split(",")[2]), 3) for row in rows[1:]}
    assert xs == {round(line[0], 3)}, xs  # along Y: x stays on the punch axis
    for source, fmt in ((job["id"], "points-csv"), (jobs["done"], "hdf5")):
        wrong_format = client.post("/api/v1/jobs", json={"kind": "export", "job_id": source, "format": fmt})
        assert wrong_format.status_code == 422 and wrong_format.json()["field"] == "format", wrong_format.text

    assert client.delete(f"/api/v1/simulations/{simulation['id']}").status_code == 204
    assert client.get(base).json() == []
    assert leftovers(settings) == []


def test_a_simulation_of_several_mib_is_uploaded_in_one_request(client, celery_worker, settings) -> None:  # type: ignore[no-untyped-def]
    """A simulation's PUT streams to disk under FRINGELAB_MAX_UPLOAD_BYTES, not the 1 MiB cap of JSON bodies."""
    experiment = client.post("/api/v1/experiments", json={"name": "plate"}).json()
    n = 120
    rows = "".join(
        f"{s},{s * 1e-3},{i * n + j + 1},{2.0 * i:.6f},{2.0 * j:.6f},0.000000,0,0,{s * 0.01 * i * j:.6f}\n"
        for s in (0, 1, 2)
        for i in range(n)
        for j in range(n)
    )
    body = ("state,time_s,node,x_mm,y_mm,z_mm,ux_mm,uy_mm,uz_mm\n" + rows).encode()
    assert len(body) > 2 * settings.max_json_bytes
    uploaded = checked(
        client, client.put(f"/api/v1/experiments/{experiment['id']}/simulations/plate.csv", content=body)
    )
    assert (uploaded["state"], uploaded["n_states"], uploaded["n_nodes"]) == ("ready", 3, n * n), uploaded
    # other request bodies keep their cap
    too_long = client.post("/api/v1/experiments", json={"name": "x", "notes": "n" * (settings.max_json_bytes + 1)})
    assert too_long.status_code == 413, too_long.text


def test_an_upload_over_the_limit_or_into_no_experiment_is_refused(settings) -> None:  # type: ignore[no-untyped-def]
    from fastapi.testclient import TestClient

    from backend.app import create_app

    limited = settings.model_copy(update={"max_upload_bytes": 100})
    with TestClient(create_app(limited)) as client:
        experiment = client.post("/api/v1/experiments", json={"name": "plate"}).json()
        too_big = client.put(f"/api/v1/experiments/{experiment['id']}/simulations/model.csv", content=b"x" * 101)
        assert too_big.status_code == 413, too_big.text
        assert "FRINGELAB_MAX_UPLOAD_BYTES" in too_big.json()["detail"]
        missing = client.put(f"/api/v1/experiments/{2**31 - 1}/simulations/model.csv", content=b"x")
        assert missing.status_code == 404, missing.text
    assert leftovers(settings) == []


def test_an_unsafe_zip_is_refused_and_a_simulation_in_use_is_not_deleted(client, celery_worker, settings) -> None:  # type: ignore[no-untyped-def]
    experiment = client.post("/api/v1/experiments", json={"name": "plate"}).json()
    base = f"/api/v1/experiments/{experiment['id']}/simulations"
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        archive.writestr("../outside.csv", "state,time_s\n")
    unsafe = client.put(f"{base}/climb.zip", content=buffer.getvalue())
    assert unsafe.status_code == 422 and unsafe.json()["code"] == "unsafe_archive", unsafe.text
    assert "climb.zip" in unsafe.json()["detail"] and "'..'" in unsafe.json()["detail"]
    assert not (settings.data_path / "uploads" / "outside.csv").exists()
    assert leftovers(settings) == []

    nodes = "state,time_s,node,x_mm,y_mm,z_mm,ux_mm,uy_mm,uz_mm\n" + "".join(
        f"{s},{s * 1e-3},{n + 1},{10 * (n % 2)},{10 * (n // 2)},0,0,0,{s if n == 0 else 0}\n"
        for s in (0, 1)
        for n in range(4)
    )
    simulation = checked(client, client.put(f"{base}/nodes.csv", content=nodes.encode()))
    assert (simulation["kind"], simulation["n_states"], simulation["n_nodes"]) == ("csv", 2, 4)
    engine = make_engine(settings.resolved_database_url)
    with make_sessionmaker(engine)() as session:
        session.add(Job(id="cmp-1", kind="comparison", state="queued", experiment_id=experiment["id"],
                        spec={"kind": "comparison", "job_id": "t", "simulation_id": simulation["id"]}))  # fmt: skip
        session.commit()
    engine.dispose()
    refused = client.delete(f"/api/v1/simulations/{simulation['id']}")
    assert refused.status_code == 409 and refused.json()["code"] == "in_use", refused.text
    assert "cmp-1" in refused.json()["detail"]
    assert client.get(f"/api/v1/simulations/{simulation['id']}").status_code == 200


def test_a_nodout_of_several_nodes_is_uploaded_and_its_punch_node_chosen_in_the_form(
    client,
    celery_worker,
    settings,
    measured,  # noqa: F811
    tmp_path,
) -> None:  # type: ignore[no-untyped-def]
    """An upload's check reads the model whatever its nodout holds; the comparison (and its preview) then needs the
    punch node when nodout lists several, and says which ones, naming the form's setting."""
    from fringelab.formats.simulation_lsdyna_ascii import read_nodout, write_nodout

    experiment = client.post("/api/v1/experiments", json={"name": "plate"}).json()
    jobs = add_topography_jobs(settings, experiment["id"], measured.result)
    folder = write_true_simulation(measured.truth_json, tmp_path / "fe", kind="vtu")
    punch = read_nodout(folder / "nodout")
    both = np.concatenate([punch.displacement, np.zeros_like(punch.displacement)], axis=1)
    write_nodout(folder / "nodout", time=punch.time, node_ids=np.array([9001, 9002]), displacement=both,
                 coordinates=np.zeros((2, 3)))  # fmt: skip
    uploaded = checked(client, client.put(f"/api/v1/experiments/{experiment['id']}/simulations/fe.zip",
                                          content=zipped(folder)))  # fmt: skip
    assert uploaded["state"] == "ready", uploaded
    # the preview reads what the check job stored (checked.h5), never the uploaded files: without them it still works
    model = settings.data_path / "simulations" / str(uploaded["id"]) / "model"
    assert (model.parent / "checked.h5").is_file()
    shutil.rmtree(model)
    spec = {"kind": "comparison", "job_id": jobs["done"], "simulation_id": uploaded["id"]}
    unchosen = client.post("/api/v1/comparisons/preview", json={"spec": spec})
    assert unchosen.status_code == 422, unchosen.text
    assert "9001, 9002" in unchosen.json()["detail"] and "“Punch node”" in unchosen.json()["detail"], unchosen.text
    chosen = client.post("/api/v1/comparisons/preview", json={"spec": {**spec, "punch_node": 9001}})
    assert chosen.status_code == 200, chosen.text
    assert chosen.json()["frames"]["reason"] == [""] * 8
