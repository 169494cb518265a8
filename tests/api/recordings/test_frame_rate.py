"""The recording's frame rate through the API: from the frame times where they exist, the header's beside it."""

from __future__ import annotations

import numpy as np
import pytest

from tests.formats.recording_files import stripe_frames, write_cine, write_mraw_zip


@pytest.mark.integration
def test_frame_rate_from_the_frame_times_with_the_header_beside(api, celery_worker, tmp_path):  # type: ignore[no-untyped-def]
    camera_id = api.camera()
    files = {
        "stamps.cine": write_cine(tmp_path / "c.cine", stripe_frames(4), fps=90000, stamp_fps=9000),
        "step.zip": write_mraw_zip(
            tmp_path / "m.zip", stripe_frames(4, dtype=np.uint16), bits=12, fps=60000, save_step=36, start_frame=49300
        ),  # fmt: skip
        "plain.cine": write_cine(tmp_path / "p.cine", stripe_frames(4), fps=1000),
    }
    ids = {}
    for name, path in files.items():
        response = api.client.put(f"/api/v1/uploads/cameras/{camera_id}/{name}", params={"kind": "test"},
                                  content=path.read_bytes())  # fmt: skip
        assert response.status_code == 201, (name, response.text)
        ids[name] = response.json()["id"]
    rates = {}
    for name, recording_id in ids.items():
        recording = api.wait_settled(recording_id)
        assert recording["state"] == "ready", (name, recording["error"])
        rates[name] = (recording["fps"], recording["fps_header"])
    assert rates["stamps.cine"][0] == pytest.approx(9000, rel=1e-6) and rates["stamps.cine"][1] == 90000
    assert rates["step.zip"][0] == pytest.approx(60000 / 36) and rates["step.zip"][1] == 60000
    assert rates["plain.cine"] == (1000, None)  # stamps and header agree: one rate
    notes = api.client.get(f"/api/v1/recordings/{ids['step.zip']}").json()["notes"]
    assert any("one frame saved every 36" in note for note in notes), notes
