"""Calibrations used in pairs and with consent (issue 27): the API offers only consistent pairs, refuses a
projector calibration built on another camera calibration and a "bad" calibration without consent with a 422
before anything is queued, names calibrations by id, camera and date, and flags bad ones in every list."""

from __future__ import annotations

from fringelab.core.db import make_engine, make_sessionmaker
from fringelab.core.models import Calibration


def add_calibrations(settings, ids: dict[str, int]) -> dict[str, int]:  # type: ignore[no-untyped-def]
    """Beside `add_rows`' camera: a good and a bad camera calibration, and a projector calibration built on each."""
    engine = make_engine(settings.resolved_database_url)
    camera_id = ids["camera"]
    with make_sessionmaker(engine)() as session:
        good = Calibration(kind="camera", camera_id=camera_id, path="c/good.json", image_width_px=640,
                           image_height_px=480, version=2, summary={"verdict": "good"})  # fmt: skip
        bad = Calibration(kind="camera", camera_id=camera_id, path="c/bad.json", image_width_px=640,
                          image_height_px=480, version=3, summary={"verdict": "bad", "rms_px": 0.357})  # fmt: skip
        session.add_all([good, bad])
        session.flush()
        on_good = Calibration(kind="projector", camera_id=camera_id, path="c/p1.h5", image_width_px=640,
                              image_height_px=480, version=2,
                              summary={"verdict": "good", "camera_calibration_id": good.id})  # fmt: skip
        on_bad = Calibration(kind="projector", camera_id=camera_id, path="c/p2.h5", image_width_px=640,
                             image_height_px=480, version=3,
                             summary={"verdict": "good", "camera_calibration_id": bad.id})  # fmt: skip
        session.add_all([on_good, on_bad])
        session.commit()
        made = {"good": good.id, "bad": bad.id, "on_good": on_good.id, "on_bad": on_bad.id}
    engine.dispose()
    return made


def test_a_mismatched_pair_or_a_bad_calibration_is_refused_before_anything_is_queued(client, add_rows, settings):
    ids = add_rows(frame_count=20)
    made = add_calibrations(settings, ids)
    spec = {"kind": "topography", "recording_id": ids["test"]}
    # The newest projector calibration, built on the bad camera calibration, with the good one: a mismatch.
    mismatch = client.post("/api/v1/jobs", json=spec | {"camera_calibration_id": made["good"],
                                                        "projector_calibration_id": made["on_bad"]})  # fmt: skip
    assert mismatch.status_code == 422 and mismatch.json()["code"] == "calibration_mismatch"
    assert mismatch.json()["field"] == "projector_calibration_id"
    detail = mismatch.json()["detail"]
    assert f"projector calibration #{made['on_bad']} (camera 'left', " in detail
    assert f"was built on camera calibration #{made['bad']}, not on camera calibration #{made['good']}" in detail
    assert "/var/" not in detail and "fingerprint" not in detail
    # The consistent pair of the bad camera calibration: refused without consent, naming what to do.
    bad_pair = spec | {"camera_calibration_id": made["bad"], "projector_calibration_id": made["on_bad"]}
    refused = client.post("/api/v1/jobs", json=bad_pair)
    assert refused.status_code == 422 and refused.json()["code"] == "bad_calibration"
    assert refused.json()["field"] == "camera_calibration_id"
    assert 'verdict is "bad"' in refused.json()["detail"] and "accept_bad_calibration" in refused.json()["detail"]
    assert client.get("/api/v1/jobs").json()["total"] == 0  # nothing queued
    # With the user's consent it is queued, and the job carries the warning.
    accepted = client.post("/api/v1/jobs", json=bad_pair | {"accept_bad_calibration": True})
    assert accepted.status_code in (200, 201, 202), accepted.text
    warnings = client.get(f"/api/v1/jobs/{accepted.json()['id']}").json()["warnings"]
    assert any(f"camera calibration #{made['bad']}" in w and "consent" in w for w in warnings)
    assert any(f"projector calibration #{made['on_bad']}" in w for w in warnings)  # built on the bad one
    # The good pair needs nothing.
    fine = client.post("/api/v1/jobs", json=spec | {"camera_calibration_id": made["good"],
                                                    "projector_calibration_id": made["on_good"]})  # fmt: skip
    assert (
        fine.status_code in (200, 201, 202) and client.get(f"/api/v1/jobs/{fine.json()['id']}").json()["warnings"] == []
    )


def test_lists_name_calibrations_flag_bad_ones_and_offer_only_consistent_pairs(client, add_rows, settings):
    ids = add_rows()
    made = add_calibrations(settings, ids)
    listed = {c["id"]: c for c in client.get("/api/v1/calibrations", params={"camera_id": ids["camera"]}).json()}
    assert listed[made["bad"]]["bad"] and listed[made["bad"]]["verdict"] == "bad"
    assert listed[made["on_bad"]]["bad"] and "built on camera calibration" in listed[made["on_bad"]]["bad_reason"]
    assert not listed[made["good"]]["bad"] and not listed[made["on_good"]]["bad"]
    assert listed[made["on_good"]]["camera_calibration_id"] == made["good"]
    assert listed[made["good"]]["label"].startswith(f"camera calibration #{made['good']} (camera 'left', ")
    # every report_url answers: a projector calibration's is its projector report
    assert listed[made["on_good"]]["report_url"].endswith(f"/calibrations/{made['on_good']}/projector-report")
    assert listed[made["good"]]["report_url"].endswith(f"/calibrations/{made['good']}/report")
    pairs = client.get("/api/v1/calibrations/pairs", params={"camera_id": ids["camera"]}).json()
    assert [(p["camera_calibration"]["id"], p["projector_calibration"]["id"], p["bad"]) for p in pairs] == [
        (made["bad"], made["on_bad"], True),
        (made["good"], made["on_good"], False),
    ]
    assert client.get("/api/v1/calibrations/pairs", params={"camera_id": 999}).json() == []
