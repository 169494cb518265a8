"""The whole measurement through the API on a virtual test (`fringelab virtual-test`): uploads and their ingest,
camera calibration, projector calibration, topography in chunks, results and exports; and the same topography in
one chunk, in many, and by the command line's pipeline (one sequential pass without any job) gives identical files:
the job and the pipeline call the same stages (`fringelab.pipelines.topography.reference_stage`, `frame_stage`),
the job hands them over between its tasks (`TopographyReference`, `PackedFrame` records)."""

from __future__ import annotations

import io
import zipfile
from typing import Any

import numpy as np
import pytest

from tests.worker.conftest import TEST_FRAMES, datasets, sequential_topography, upload_virtual_experiment, wait_job

pytestmark = [pytest.mark.integration, pytest.mark.slow]


@pytest.fixture
def recordings(client, celery_worker, virtual_experiment) -> dict[str, Any]:
    return upload_virtual_experiment(client, virtual_experiment)


def _succeeded(client, spec: dict, *, timeout_s: float = 300) -> dict:
    created = client.post("/api/v1/jobs", json=spec)
    assert created.status_code == 201, created.text
    job = wait_job(client, created.json()["id"], timeout_s=timeout_s)
    assert job["state"] == "succeeded", job["error"]
    return job


def test_the_whole_measurement_through_the_api(
    client, celery_worker, recordings, settings, tmp_path, virtual_experiment
):
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
    # every frame measured on its own, in three chunks on any worker; only the writing in frame order
    chunks = [(c["phase"], c["first_frame"], c["stop_frame"]) for c in chunked["chunks"]]
    assert chunks == [(0, a, b) for a, b in ((0, 5), (5, 10), (10, 12))]
    assert [c["id"] for c in chunked["provenance"]["calibrations"]] == [camera_id, projector_id]
    test_recording = client.get(f"/api/v1/recordings/{recordings['test']}").json()
    assert chunked["provenance"]["inputs"] == [
        {"recording_id": test_recording["id"], "sha256": test_recording["sha256"], "frames": TEST_FRAMES}
    ]
    whole = _succeeded(client, spec | {"chunk_frames": 1000})
    assert len(whole["chunks"]) == 1

    # the chunked run, the one-chunk run and one sequential pass without any job wrote the same numbers, to the bit
    paths = [settings.data_path / "results" / "jobs" / job["id"] / "topography.h5" for job in (chunked, whole)]
    paths.append(
        sequential_topography(settings, virtual_experiment.test, camera_job, projector_job, tmp_path / "seq.h5")
    )
    first, *others = (datasets(path) for path in paths)
    assert "grid/z_mm" in first and "points/z_mm" in first
    for other in others:
        assert other.keys() == first.keys()
        for name in first:
            np.testing.assert_array_equal(first[name], other[name], err_msg=name)

    # a part of the recording: the same frames as the whole run (the order is still anchored on frame 0), and
    # only the frames written are measured
    part = _succeeded(client, spec | {"chunk_frames": 4, "frames": {"first": 4, "last": 9}})
    assert [(c["phase"], c["first_frame"], c["stop_frame"]) for c in part["chunks"]] == [(0, 4, 8), (0, 8, 10)]
    some = datasets(settings.data_path / "results" / "jobs" / part["id"] / "topography.h5")
    assert some["frames/index"].tolist() == list(range(4, 10))
    np.testing.assert_array_equal(some["grid/z_mm"], first["grid/z_mm"][4:10])

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
    line = {"x0_mm": centre[0] - 100, "y0_mm": centre[1], "x1_mm": centre[0] + 100, "y1_mm": centre[1], "n_points": 101}
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
