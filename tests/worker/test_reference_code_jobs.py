"""Topography jobs whose reference frame is ordered by a Gray code recorded at rest (docs/procam.md §5), through the
API with a real worker, on the virtual test's rig taken as a digital projector."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import h5py
import pytest

from fringelab.core.db import make_engine, make_sessionmaker
from fringelab.core.models import Calibration, Camera, Experiment, Recording
from fringelab.formats.camera import write_camera_json
from fringelab.formats.patterns import patterns_json_text
from fringelab.formats.projector import write_projector_calibration
from fringelab.formats.recordings import write_recording
from tests.science.procam.test_reference_code import Rig, render_rig
from tests.worker.conftest import log_messages, wait_job

pytestmark = pytest.mark.integration


@pytest.fixture(scope="module")
def rig() -> Rig:
    return render_rig(17.0, seed=43)


def add_rig_rows(settings, rig: Rig, *, patterns: str | None = None) -> dict[str, int]:
    """The test and the code at rest as ready recordings of one camera (and a coded recording of another camera),
    the camera's calibration and the projector table made from the camera–projector model."""
    data = settings.data_path
    write_recording(data / "recordings" / "test", rig.frames)
    text = patterns_json_text(rig.sequence) if patterns is None else patterns
    write_recording(data / "recordings" / "code", rig.code_frames, sidecars={"patterns.json": text})
    write_camera_json(rig.camera, data / "calibrations" / "camera.json")
    write_projector_calibration(rig.table, data / "calibrations" / "projector.h5")
    engine = make_engine(settings.resolved_database_url)
    with make_sessionmaker(engine)() as session:
        experiment = Experiment(name="plate on a DLP rig")
        cameras = [Camera(experiment=experiment, name=name, image_width_px=512, image_height_px=480,
                          pixel_pitch_um=10.0) for name in ("left", "right")]  # fmt: skip
        recordings = {
            name: Recording(camera=camera, kind=kind, state="ready", path=str(Path("recordings") / folder),
                            frame_count=n, width_px=512, height_px=480, sha256=f"{i:02d}" * 32)  # fmt: skip
            for i, (name, camera, kind, folder, n) in enumerate((
                ("test", cameras[0], "test", "test", len(rig.frames)),
                ("code", cameras[0], "coded", "code", len(rig.code_frames)),
                ("other_code", cameras[1], "coded", "code", len(rig.code_frames)),
            ))
        }  # fmt: skip
        session.add_all([experiment, *cameras, *recordings.values()])
        session.flush()
        calibrations = {
            kind: Calibration(kind=kind, camera_id=cameras[0].id, path=f"calibrations/{file}", image_width_px=512,
                              image_height_px=480)
            for kind, file in (("camera", "camera.json"), ("projector", "projector.h5"))
        }  # fmt: skip
        session.add_all(calibrations.values())
        session.commit()
        ids = {name: row.id for name, row in {**recordings, **calibrations}.items()}
    engine.dispose()
    return ids


def spec_of(ids: dict[str, int], **extra) -> dict:
    return {"kind": "topography", "recording_id": ids["test"], "camera_calibration_id": ids["camera"],
            "projector_calibration_id": ids["projector"], **extra}  # fmt: skip


def test_a_topography_job_orders_its_reference_by_the_code_at_rest(client, celery_worker, settings, rig) -> None:
    ids = add_rig_rows(settings, rig)
    job = client.post("/api/v1/jobs", json=spec_of(ids, reference_code_recording_id=ids["code"])).json()
    job = wait_job(client, job["id"], timeout_s=300)
    assert job["state"] == "succeeded", job["error"]
    assert any("reference order from the Gray code at rest" in m for m in log_messages(client, job["id"]))
    assert any("the table's match agrees on 100.0%" in m for m in log_messages(client, job["id"]))
    [path] = [p for p in settings.data_path.rglob("topography.h5") if job["id"] in str(p)]
    with h5py.File(path, "r") as file:
        summary = dict(file["summary"].attrs)
    assert summary["reference_order_from"] == "gray code at rest"
    assert summary["reference_code_agreement"] == 1.0 and summary["reference_code_points"] > 20_000
    # The code at rest is an input of the job: its provenance names it.
    stored = client.get(f"/api/v1/jobs/{job['id']}").json()
    assert any(i.get("recording_id") == ids["code"] for i in stored["provenance"]["inputs"])
    # The result's overview: every frame measured on its own, with its coverage, and where frame 0's order came from.
    topography = client.get(f"/api/v1/jobs/{job['id']}/topography").json()
    assert topography["frames"] == list(range(len(rig.frames)))
    assert all(fraction > 0.95 for fraction in topography["measured_fraction"])
    assert topography["summary"]["reference_order_from"] == "gray code at rest"


def test_a_code_of_another_camera_or_kind_is_refused_before_queueing(client, celery_worker, settings, rig) -> None:
    ids = add_rig_rows(settings, rig)
    for code, words in ((ids["other_code"], "not of the test recording's camera"),
                        (ids["test"], "is a test recording; this job needs a coded recording")):  # fmt: skip
        response = client.post("/api/v1/jobs", json=spec_of(ids, reference_code_recording_id=code))
        assert response.status_code in (409, 422), response.text
        assert "reference_code_recording_id" in response.text and words in response.text
    response = client.post("/api/v1/jobs", json=spec_of(ids, rim_circle_mm=[0.0, 0.0, -5.0]))
    assert response.status_code == 422 and "rim_circle_mm" in response.text


def test_a_code_naming_frames_it_lacks_fails_the_job_in_a_sentence(client, celery_worker, settings, rig) -> None:
    n = len(rig.code_frames)
    wrong = patterns_json_text(replace(rig.sequence, gray_frames=(*rig.sequence.gray_frames, n)))
    ids = add_rig_rows(settings, rig, patterns=wrong)
    job = client.post("/api/v1/jobs", json=spec_of(ids, reference_code_recording_id=ids["code"])).json()
    job = wait_job(client, job["id"], timeout_s=300)
    assert job["state"] == "failed"
    assert f"code: patterns.json: gray_frames names frame {n} but the recording has {n} frames" in job["error"]
    assert job["files"] == []
