"""Disk rules of uploads without a server (issue 26): reservations lapse, crashed PUT leftovers are swept, and
error texts show no server path or memory address."""

from __future__ import annotations

import json
import os
import time

from backend.uploads import PUT_PART_STALE_S, reserved_upload_bytes, sweep_put_parts
from fringelab.core.storage import put_dir, tus_dir
from fringelab.core.text import public_text


def test_a_reservation_is_its_owners_and_lapses_hours_after_its_last_byte(settings):
    directory = tus_dir(settings.data_path)
    directory.mkdir(parents=True, exist_ok=True)
    uid = "a" * 32
    (directory / f"{uid}.info").write_text(json.dumps({"size": 1000, "offset": 100, "owner": 7, "metadata": {}}))
    (directory / uid).write_bytes(bytes(100))
    assert reserved_upload_bytes(settings, 7) == 900
    assert reserved_upload_bytes(settings, 8) == 0  # another user's reservation is not theirs to keep room for
    later = time.time() + settings.upload_reservation_h * 3600 + 60
    assert reserved_upload_bytes(settings, 7, now=later) == 0


def test_the_part_file_of_a_dead_put_is_swept_and_a_live_one_kept(settings):
    parts = put_dir(settings.data_path)
    parts.mkdir(parents=True, exist_ok=True)
    dead, live = parts / "dead.part", parts / "live.part"
    dead.write_bytes(b"x")
    live.write_bytes(b"y")
    past = time.time() - PUT_PART_STALE_S - 60
    os.utime(dead, (past, past))
    assert sweep_put_parts(settings) == 1
    assert not dead.exists() and live.exists()


def test_error_texts_show_no_server_path_or_memory_address():
    assert public_text("cannot write /srv/fringelab/var/results/jobs/ab/topography.h5: [Errno 28] No space left") == (
        "cannot write topography.h5: [Errno 28] No space left"
    )
    assert public_text("<h5py File object at 0x7f3a2b1c9d30> is closed") == "<h5py File object at 0x…> is closed"
    kept = "frame 3 of r.zip: 64 × 48 px; see https://example.org/a/b and 2026/11/27; z.csv line 2"
    assert public_text(kept) == kept


def test_a_demo_below_the_disk_reserve_is_refused_saying_why_and_makes_no_experiment(settings):
    """Finding 6: a demo started below the reserve left an empty experiment, its error only in the worker log."""
    from fastapi.testclient import TestClient

    from backend.app import create_app
    from fringelab.core.storage import free_disk_bytes

    full = settings.model_copy(update={"min_free_disk_bytes": free_disk_bytes(settings.data_path) + 2**40})
    with TestClient(create_app(full)) as client:
        answer = client.post("/api/v1/demo", json={})
        assert answer.status_code == 413 and answer.json()["code"] == "insufficient_storage", answer.text
        assert "the demo cannot be made" in answer.json()["detail"]
        assert client.get("/api/v1/experiments").json() == []
