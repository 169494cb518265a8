"""The whole measurement through the API on a virtual experiment (`fringelab simulate`): camera calibration,
projector calibration, topography in chunks, results and exports; and the same topography in one chunk and in
many gives identical files."""

from __future__ import annotations

import io
import json
import zipfile
from pathlib import Path

import h5py
import numpy as np
import pytest

from backend.db import make_engine, make_sessionmaker
from backend.models import Camera, Experiment, Recording
from tests.jobs.conftest import wait_job

pytestmark = [pytest.mark.integration, pytest.mark.slow]
pytest.importorskip("worker.measurement.topography", reason="the topography science (branch topo) is not merged yet")
TEST_FRAMES = 12  # the punch reaches ~60 mm and perforates (frame 9) within them


@pytest.fixture(scope="module")
def virtual_experiment(tmp_path_factory):
    from worker.measurement.simulate import simulate_experiment

    # 4 mm projector steps over 0..80 mm: half the default's frames, still ~20 samples per table entry
    return simulate_experiment(
        tmp_path_factory.mktemp("virtual") / "kodak", "kodak", n_test_frames=TEST_FRAMES,
        calibration_z_mm=np.arange(0.0, 80.0 + 1e-9, 4.0), seed=3,
    )  # fmt: skip


@pytest.fixture
def recordings(settings, virtual_experiment) -> dict[str, int]:
    """The three recordings of the virtual camera, ready (as after their ingest), inside the data directory."""
    truth = json.loads(virtual_experiment.truth_json.read_text())
    engine = make_engine(settings.resolved_database_url)
    ids = {}
    with make_sessionmaker(engine)() as session:
        experiment = Experiment(name="virtual kodak")
        camera = Camera(experiment=experiment, name="kodak", image_width_px=512, image_height_px=480,
                        pixel_pitch_um=1000.0 / truth["camera"]["du_px_per_mm"])  # fmt: skip
        session.add_all([experiment, camera])
        for kind, source in (
            ("camera_calibration", virtual_experiment.camera_calibration),
            ("projector_calibration", virtual_experiment.projector_calibration),
            ("test", virtual_experiment.test),
        ):
            relative = Path("recordings") / kind
            (settings.data_path / "recordings").mkdir(parents=True, exist_ok=True)
            (settings.data_path / relative).symlink_to(source)
            count = len(list(Path(source).glob("*.png")))
            row = Recording(camera=camera, kind=kind, state="ready", path=str(relative), frame_count=count,
                            width_px=512, height_px=480, sha256=kind[:2] * 32)  # fmt: skip
            session.add(row)
            session.flush()
            ids[kind] = row.id
        session.commit()
    engine.dispose()
    ids["scale_on"] = truth["camera"]["scale_on"]  # type: ignore[assignment]
    return ids


def _succeeded(client, spec: dict, *, timeout_s: float = 300) -> dict:
    created = client.post("/api/v1/jobs", json=spec)
    assert created.status_code == 201, created.text
    job = wait_job(client, created.json()["id"], timeout_s=timeout_s)
    assert job["state"] == "succeeded", job["error"]
    return job


def _datasets(path: Path) -> dict[str, np.ndarray]:
    found: dict[str, np.ndarray] = {}
    with h5py.File(path) as file:
        file.visititems(lambda name, item: found.update({name: item[()]}) if isinstance(item, h5py.Dataset) else None)
    return found


def _sequential_run(settings, camera_job: dict, projector_job: dict, out_path: Path) -> Path:
    """`fringelab topography` on the same inputs: one pass, edges located inline, no chunks, no job."""
    from worker.measurement.camera_files import read_camera_json
    from worker.measurement.readers import open_recording
    from worker.measurement.topography import topography_recording
    from worker.measurement.topography_files import read_projector_calibration

    def result(job: dict, name: str) -> Path:
        return settings.data_path / "results" / "jobs" / job["id"] / name

    topography_recording(
        open_recording(settings.data_path / "recordings" / "test"),
        read_camera_json(result(camera_job, "camera.json")),
        read_projector_calibration(result(projector_job, "projector.h5")),
        out_path=out_path,
    )
    return out_path


def test_the_whole_measurement_through_the_api(client, celery_worker, recordings, settings, tmp_path):
    camera_job = _succeeded(client, {"kind": "camera_calibration", "recording_id": recordings["camera_calibration"],
                                     "scale_on": recordings["scale_on"]})  # fmt: skip
    camera_id = camera_job["result"]["calibration_id"]
    projector_job = _succeeded(client, {"kind": "projector_calibration", "camera_calibration_id": camera_id,
                                        "recording_id": recordings["projector_calibration"]})  # fmt: skip
    projector_id = projector_job["result"]["calibration_id"]
    table = client.get(f"/api/v1/calibrations/{projector_id}/table").json()
    assert table["n_edges"] == projector_job["result"]["n_edges"] and len(table["z_mm"]) == 21
    assert len(table["curves"]) == table["n_edges"]

    spec = {"kind": "topography", "recording_id": recordings["test"], "camera_calibration_id": camera_id,
            "projector_calibration_id": projector_id}  # fmt: skip
    chunked = _succeeded(client, spec | {"chunk_frames": 5})
    assert [(c["first_frame"], c["stop_frame"]) for c in chunked["chunks"]] == [(0, 5), (5, 10), (10, 12)]
    assert [c["id"] for c in chunked["provenance"]["calibrations"]] == [camera_id, projector_id]
    whole = _succeeded(client, spec | {"chunk_frames": 1000})
    assert len(whole["chunks"]) == 1

    # the chunked run, the one-chunk run and one sequential pass without any job wrote the same numbers, to the bit
    paths = [settings.data_path / "results" / "jobs" / job["id"] / "topography.h5" for job in (chunked, whole)]
    paths.append(_sequential_run(settings, camera_job, projector_job, tmp_path / "sequential.h5"))
    first, *others = (_datasets(path) for path in paths)
    assert "grid/z_mm" in first and "points/z_mm" in first
    for other in others:
        assert other.keys() == first.keys()
        for name in first:
            np.testing.assert_array_equal(first[name], other[name], err_msg=name)

    # results as the dashboard reads them
    overview = client.get(f"/api/v1/jobs/{chunked['id']}/topography").json()
    assert overview["frames"] == list(range(TEST_FRAMES))
    assert overview["punch_displacement_mm"][1] > 0
    peak = np.array([np.nan if w is None else w for w in overview["peak_w_mm"]])
    assert abs(peak[0]) < 0.5  # the flat first frame
    assert 40 < np.nanmax(peak) < 70  # the virtual punch pushes the plate ~60 mm
    grid = client.get(f"/api/v1/jobs/{chunked['id']}/topography/grid", params={"frame": 8}).json()
    assert len(grid["x_mm"]) <= 250 and len(grid["y_mm"]) <= 250
    centre = overview["summary"]["punch_axis_x_mm"], overview["summary"]["punch_axis_y_mm"]
    history = client.get(f"/api/v1/jobs/{chunked['id']}/topography/history",
                         params={"x_mm": centre[0] + 40, "y_mm": centre[1]}).json()  # fmt: skip
    assert history["w_mm"][8] > history["w_mm"][2] > history["w_mm"][0] - 0.5  # it rises with the punch
    line = {"x0": centre[0] - 100, "y0": centre[1], "x1": centre[0] + 100, "y1": centre[1], "n_points": 101}
    profile = client.get(f"/api/v1/jobs/{chunked['id']}/topography/profile", params=line | {"frames": [8]}).json()
    w = np.array([np.nan if v is None else v for v in profile["profiles"][0]["w_mm"]])
    assert np.nanargmax(w) in range(40, 61)  # highest near the punch axis

    # exports, downloaded
    mat = _succeeded(client, {"kind": "export", "job_id": chunked["id"], "format": "mat"})
    download = client.get(mat["files"][0]["url"])
    assert download.status_code == 200 and download.content.startswith(b"MATLAB")
    vtk = _succeeded(client, {"kind": "export", "job_id": chunked["id"], "format": "vtk"})
    names = zipfile.ZipFile(io.BytesIO(client.get(vtk["files"][0]["url"]).content)).namelist()
    assert "topography.pvd" in names and sum(n.endswith(".vtu") for n in names) == TEST_FRAMES
