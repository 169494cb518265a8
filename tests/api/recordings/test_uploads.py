"""Uploads against the running API (uvicorn on loopback) with a real worker: tus with interruptions and
resumes, the plain PUT, every recording format to `ready`, and every bad input to a clear 4xx."""

from __future__ import annotations

import hashlib
import socket
import threading
import zipfile
from urllib.parse import urlparse

import cv2
import numpy as np
import pytest

from fringelab.core.storage import put_dir, recording_dir, tus_dir
from tests.api.recordings.conftest import TUS, Api, serve, tus_create, tus_offset, tus_patch, tus_upload
from tests.formats.recording_files import (
    encode,
    stripe_frames,
    write_cine,
    write_mraw_zip,
    write_tiff_stack,
    write_video,
    write_zip,
)
from tests.support import wait_for

Z_CSV = "frame,z_mm\n" + "".join(f"{i},{i * 0.5}\n" for i in range(8))


def zip_bytes(tmp_path, frames, **kwargs) -> bytes:
    return write_zip(tmp_path / "upload.zip", frames, **kwargs).read_bytes()


@pytest.mark.integration
def test_tus_upload_in_chunks_becomes_a_ready_recording_with_previews_and_qa(api, celery_worker, tmp_path):
    camera_id = api.camera()
    frames = stripe_frames(8)
    data = zip_bytes(tmp_path, frames, sidecars={"z.csv": Z_CSV})
    last = tus_upload(api.client, data, camera_id=camera_id, kind="projector_calibration", chunk=len(data) // 3)
    assert last.status_code == 204, last.text
    recording_id = int(last.headers["Fringelab-Recording-Id"])
    assert last.headers["Content-Location"] == f"/api/v1/recordings/{recording_id}"

    recording = api.wait_settled(recording_id)
    assert recording["state"] == "ready", recording["error"]
    assert recording["sha256"] == hashlib.sha256(data).hexdigest()
    assert (recording["frame_count"], recording["width_px"], recording["height_px"]) == (8, 64, 48)
    assert (recording["bit_depth"], recording["format"], recording["size_bytes"]) == (8, "zip", len(data))
    assert recording["sidecars"]["z.csv"] == {"rows": 8, "z_mm_min": 0.0, "z_mm_max": 3.5}
    assert recording["warnings"] == []

    png = api.client.get(f"/api/v1/recordings/{recording_id}/frames/5")
    assert png.status_code == 200 and png.headers["content-type"] == "image/png"
    np.testing.assert_array_equal(cv2.imdecode(np.frombuffer(png.content, np.uint8), cv2.IMREAD_UNCHANGED), frames[5])
    small = cv2.imdecode(np.frombuffer(api.client.get(f"/api/v1/recordings/{recording_id}/frames/5?max_px=32").content,
                                       np.uint8), cv2.IMREAD_UNCHANGED)  # fmt: skip
    assert max(small.shape) <= 32
    assert api.client.get(f"/api/v1/recordings/{recording_id}/frames/8").json()["code"] == "frame_not_found"
    qa = api.client.get(f"/api/v1/recordings/{recording_id}/qa").json()
    assert len(qa["frames"]["contrast"]) == 8 and min(qa["frames"]["contrast"]) > 0.5
    assert qa["frames"]["board_found"] == [None] * 8
    # The upload is complete for a client that asks again, and a repeated last PATCH finds the same recording.
    found = api.client.get("/api/v1/recordings", params={"upload_id": recording["upload_id"]}).json()
    assert [r["id"] for r in found] == [recording_id]
    upload_url = f"/api/v1/uploads/{recording['upload_id']}"
    assert tus_offset(api.client, upload_url) == len(data)
    again = tus_patch(api.client, upload_url, len(data), b"")
    assert again.status_code == 204 and again.headers["Fringelab-Recording-Id"] == str(recording_id)


def raw_request(base_url: str, head: str, body: bytes, *, before_close=lambda: True) -> None:  # type: ignore[no-untyped-def]
    """Send a request's head and part of its body, then drop the connection (an upload cut off mid-way)."""
    url = urlparse(base_url)
    with socket.create_connection((url.hostname, url.port)) as connection:
        connection.sendall(head.encode() + body)
        wait_for(before_close, timeout_s=20, what="the server to receive the bytes before the cut")


def patch_head(path: str, offset: int, length: int) -> str:
    return (
        f"PATCH {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nTus-Resumable: 1.0.0\r\nUpload-Offset: {offset}\r\n"
        f"Content-Type: application/offset+octet-stream\r\nContent-Length: {length}\r\n\r\n"
    )


def in_patch(api, location: str):  # type: ignore[no-untyped-def]
    """True once the server handles a PATCH of this upload (it holds the upload's lock file)."""
    lock = tus_dir(api.settings.data_path) / ".locks" / f"{location.rsplit('/', 1)[1]}.lock"
    return lock.exists


def settled_offset(client, location: str) -> int:  # type: ignore[no-untyped-def]
    """The offset once the server is done with a cut-off PATCH, as a tus client learns it: HEAD, then an empty
    PATCH at that offset waits for the upload's lock and answers 409 if the cut-off request moved it on."""
    while True:
        offset = tus_offset(client, location)
        response = tus_patch(client, location, offset, b"")
        if response.status_code == 204:
            return offset
        assert response.status_code == 409, response.text


@pytest.mark.parametrize("cut", [0, 1, 777_777, 5_000_000, 5_999_999])
def test_tus_upload_interrupted_at_any_byte_resumes_where_it_stopped(api, tmp_path, cut):
    camera_id = api.camera()
    data = np.random.default_rng(cut).integers(0, 256, 6_000_000, dtype=np.uint8).tobytes()
    created = tus_create(api.client, len(data), filename="r.cine", filetype="video/x-cine", camera_id=camera_id,
                         kind="test")  # fmt: skip
    location = urlparse(created.headers["Location"]).path
    stored = tus_dir(api.settings.data_path) / location.rsplit("/", 1)[1]
    # The cut comes once the server is in the PATCH; past 4 MiB it writes as it receives, so wait until it
    # holds bytes before cutting the connection.
    received = 4 << 20 if cut > 4 << 20 else 0
    patching = in_patch(api, location)
    raw_request(api.base_url, patch_head(location, 0, len(data)), data[:cut],
                before_close=lambda: patching() and stored.stat().st_size >= received)  # fmt: skip
    offset = settled_offset(api.client, location)
    assert received <= offset <= cut  # what reached the server before the cut is kept; in-flight bytes may not be
    assert stored.read_bytes() == data[:offset]  # nothing beyond the offset, nothing lost before it
    stale = tus_patch(api.client, location, offset + 5, data[:10])  # a client that lost track is refused
    assert stale.status_code == 409 and stale.json()["code"] == "conflict"
    half = offset + (len(data) - offset) // 2
    assert tus_patch(api.client, location, offset, data[offset:half]).headers["Upload-Offset"] == str(half)
    part = (len(data) - half) // 2  # cut again, before the end
    raw_request(api.base_url, patch_head(location, half, len(data) - half), data[half : half + part],
                before_close=patching)  # fmt: skip
    offset = settled_offset(api.client, location)
    assert half <= offset <= half + part
    assert stored.read_bytes() == data[:offset]


@pytest.mark.integration
def test_resumed_upload_is_checksummed_as_a_whole(api, celery_worker, tmp_path):
    camera_id = api.camera()
    data = write_cine(tmp_path / "r.cine", stripe_frames(6, dtype=np.uint16), fps=2000, real_bpp=12).read_bytes()
    created = tus_create(api.client, len(data), filename="r.cine", filetype="video/x-cine", camera_id=camera_id,
                         kind="test")  # fmt: skip
    location = urlparse(created.headers["Location"]).path
    raw_request(api.base_url, patch_head(location, 0, len(data)), data[:5000], before_close=in_patch(api, location))
    offset = settled_offset(api.client, location)
    last = tus_patch(api.client, location, offset, data[offset:])
    assert last.status_code == 204, last.text
    recording = api.wait_settled(int(last.headers["Fringelab-Recording-Id"]))
    assert recording["state"] == "ready", recording["error"]
    assert recording["sha256"] == hashlib.sha256(data).hexdigest()
    assert (recording["format"], recording["fps"], recording["bit_depth"]) == ("cine", 2000, 12)


@pytest.mark.integration
def test_two_uploads_of_the_same_name_at_once_stay_apart(api, celery_worker, tmp_path):
    camera_id = api.camera()
    payloads = [write_zip(tmp_path / f"{i}.zip", stripe_frames(4, seed=i)).read_bytes() for i in range(2)]
    results: dict[int, object] = {}

    def upload(i: int) -> None:
        with httpx_client(api) as client:
            results[i] = tus_upload(client, payloads[i], camera_id=camera_id, filename="same.zip", chunk=2000)

    threads = [threading.Thread(target=upload, args=(i,)) for i in range(2)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(timeout=60)
    ids = [int(results[i].headers["Fringelab-Recording-Id"]) for i in range(2)]  # type: ignore[attr-defined]
    assert ids[0] != ids[1]
    for i, recording_id in enumerate(ids):
        recording = api.wait_settled(recording_id)
        assert recording["state"] == "ready" and recording["filename"] == "same.zip"
        assert recording["sha256"] == hashlib.sha256(payloads[i]).hexdigest()
        assert (api.settings.data_path / f"recordings/{recording_id}/recording.zip").read_bytes() == payloads[i]


def httpx_client(api):  # type: ignore[no-untyped-def]
    import httpx

    return httpx.Client(base_url=api.base_url, timeout=60)


def put(api, camera_id: int, filename: str, data: bytes, kind: str = "test"):  # type: ignore[no-untyped-def]
    return api.client.put(f"/api/v1/uploads/cameras/{camera_id}/{filename}", params={"kind": kind}, content=data)


@pytest.mark.integration
def test_every_format_uploads_with_put_and_becomes_ready(api, celery_worker, tmp_path):
    camera_id = api.camera()
    grey16 = stripe_frames(5, dtype=np.uint16)
    files = {
        "frames16.zip": (write_zip(tmp_path / "a.zip", grey16, suffix=".tif"), 16, 12),
        "frames.zip": (
            write_zip(tmp_path / "j.zip", [cv2.merge([f, f, f]) for f in stripe_frames(5)], suffix=".jpg"),
            8,
            8,
        ),  # fmt: skip
        "stack.tif": (write_tiff_stack(tmp_path / "s.tif", grey16), 16, 12),
        "clip.avi": (write_video(tmp_path / "v.avi", stripe_frames(5), fps=30), 8, 8),
        "clip.mp4": (write_video(tmp_path / "v.mp4", stripe_frames(5), fps=30), 8, 8),
        "shot8.cine": (write_cine(tmp_path / "c8.cine", stripe_frames(5), fps=1000), 8, 8),
        "shot16.cine": (write_cine(tmp_path / "c16.cine", grey16, fps=1000, real_bpp=12), 16, 12),
        "packed.cine": (write_cine(tmp_path / "p12.cine", grey16, fps=1000, packing="P12L"), 16, 12),
        "photron.zip": (write_mraw_zip(tmp_path / "m.zip", grey16, bits=12, fps=1000), 16, 12),
    }
    created = {}
    for name, (path, _stored, _bits) in files.items():
        response = put(api, camera_id, name, path.read_bytes())
        assert response.status_code == 201, (name, response.text)
        assert response.headers["Location"] == f"/api/v1/recordings/{response.json()['id']}"
        created[name] = response.json()["id"]
    for name, recording_id in created.items():
        recording = api.wait_settled(recording_id)
        assert recording["state"] == "ready", (name, recording["error"])
        assert (recording["frame_count"], recording["width_px"], recording["height_px"]) == (5, 64, 48), name
        assert recording["bit_depth"] == files[name][2], name
        png = api.client.get(f"/api/v1/recordings/{recording_id}/frames/4")
        assert png.status_code == 200 and png.content.startswith(b"\x89PNG"), name
    assert api.client.get(f"/api/v1/recordings/{created['clip.avi']}").json()["fps"] == pytest.approx(30)
    jpeg = api.client.get(f"/api/v1/recordings/{created['frames.zip']}").json()
    assert "colour frames converted to grey (ITU-R BT.601 luma)" in jpeg["notes"]
    full = api.client.get(f"/api/v1/recordings/{created['shot16.cine']}/file")
    assert full.content == files["shot16.cine"][0].read_bytes()


@pytest.mark.integration
def test_an_identical_file_is_recognised_and_stored_once(api, celery_worker, tmp_path):
    camera_id = api.camera()
    data = write_zip(tmp_path / "r.zip", stripe_frames(3)).read_bytes()
    first = put(api, camera_id, "a.zip", data).json()
    second = put(api, camera_id, "b.zip", data).json()
    assert second["duplicate_of"] == first["id"]
    paths = [api.settings.data_path / f"recordings/{r['id']}/recording.zip" for r in (first, second)]
    assert paths[0].stat().st_ino == paths[1].stat().st_ino
    settled = api.wait_settled(second["id"])
    assert f"identical to recording {first['id']} (same SHA-256); the file is stored once" in settled["notes"]
    api.wait_settled(first["id"])
    assert api.client.delete(f"/api/v1/recordings/{first['id']}").status_code == 204
    assert paths[1].read_bytes() == data  # the other recording keeps its bytes


def bad_zips(tmp_path) -> dict[str, bytes]:
    frames = stripe_frames(3)
    made = {}
    truncated = write_zip(tmp_path / "t.zip", frames).read_bytes()
    made["truncated.zip"] = truncated[: len(truncated) - 60]
    with zipfile.ZipFile(tmp_path / "trav.zip", "w") as archive:
        archive.writestr("f0.png", encode(frames[0], ".png"))
        archive.writestr("../../../../etc/cron.d/f1.png", encode(frames[1], ".png"))
    made["traversal.zip"] = (tmp_path / "trav.zip").read_bytes()
    with zipfile.ZipFile(tmp_path / "abs.zip", "w") as archive:
        archive.writestr("/tmp/f0.png", encode(frames[0], ".png"))
    made["absolute.zip"] = (tmp_path / "abs.zip").read_bytes()
    with zipfile.ZipFile(tmp_path / "bomb.zip", "w", compression=zipfile.ZIP_DEFLATED) as archive:
        for i in range(4):
            archive.writestr(f"f{i}.bmp", bytes(200 << 20))  # 800 MiB of zeros in ~800 kB
    made["bomb.zip"] = (tmp_path / "bomb.zip").read_bytes()
    made["text.zip"] = b"these are not the frames you are looking for"
    made["one.png"] = encode(frames[0], ".png")
    return made


EXPECTED = {
    "truncated.zip": (422, "corrupt_recording", "truncated"),
    "traversal.zip": (422, "unsafe_archive", "climbs out of the archive"),
    "absolute.zip": (422, "unsafe_archive", "absolute path"),
    "bomb.zip": (422, "unsafe_archive", "ZIP bomb"),
    "text.zip": (415, "unsupported_format", "not a recording format"),
    "one.png": (415, "unsupported_format", "not a recording format fringelab reads"),
}


def assert_nothing_kept(api) -> None:  # type: ignore[no-untyped-def]
    assert api.client.get("/api/v1/recordings").json() == []
    assert not list(put_dir(api.settings.data_path).glob("*"))
    assert not list((api.settings.data_path / "recordings").glob("*/recording*"))


def test_bad_files_are_refused_with_a_clear_4xx_by_put_and_by_tus(api, tmp_path):
    camera_id = api.camera()
    for name, data in bad_zips(tmp_path).items():
        status, code, words = EXPECTED[name]
        refused = put(api, camera_id, name, data)
        assert (refused.status_code, refused.json()["code"]) == (status, code), (name, refused.text)
        assert words in refused.json()["detail"], name
        if name != "one.png":  # refused by its name before the first byte with tus; see below
            last = tus_upload(api.client, data, camera_id=camera_id, filename=name, chunk=300_000)
            assert (last.status_code, last.json()["code"]) == (status, code), (name, last.text)
            assert words in last.json()["detail"]
    created = tus_create(api.client, 10, filename="one.png", filetype="image/png", camera_id=camera_id, kind="test")
    assert (created.status_code, created.json()["code"]) == (415, "unsupported_format")
    assert "zip a folder of frames" in created.json()["detail"]
    # Both 415s, by name before any byte and by content after, list the same formats: one list, declared once.
    from fringelab.formats.containers import ACCEPTED_UPLOADS

    by_content = put(api, camera_id, "text.zip", b"these are not the frames you are looking for")
    assert ACCEPTED_UPLOADS in created.json()["detail"] and ACCEPTED_UPLOADS in by_content.json()["detail"]
    assert_nothing_kept(api)
    assert not list(tus_dir(api.settings.data_path).glob("*.info"))  # refused uploads are removed


def test_bad_upload_requests_are_refused_before_any_byte(api):
    camera_id = api.camera()
    client = api.client
    cases = [
        (tus_create(client, 0, filename="a.zip", filetype="x", camera_id=camera_id, kind="test"), 400, "empty_upload"),
        (tus_create(client, -5, filename="a.zip", filetype="x", camera_id=camera_id, kind="test"), 400,
         "invalid_length"),
        (client.patch(tus_create(client, 10, filename="a.zip", filetype="x", camera_id=camera_id, kind="test")
                      .headers["Location"], content=b"x",
                      headers={"Upload-Offset": "0", "Content-Type": "application/offset+octet-stream"}), 412,
         "precondition_failed"),  # no Tus-Resumable: refused before the body is read
        (tus_create(client, 10, filename="a.zip", filetype="x", camera_id=999, kind="test"), 404, "not_found"),
        (tus_create(client, 10, filename="a.zip", filetype="x", camera_id=camera_id, kind="movie"), 422,
         "invalid_kind"),
        (tus_create(client, 10, filename="a.zip", camera_id=camera_id, kind="test"), 400, "missing_metadata"),
        (tus_create(client, 10, filename="a.txt", filetype="x", camera_id=camera_id, kind="test"), 415,
         "unsupported_format"),
        (client.post("/api/v1/uploads", headers={**TUS, "Upload-Defer-Length": "1", "Upload-Metadata": ""}), 400,
         "missing_metadata"),
        (put(api, camera_id, "a.zip", b""), 400, "empty_upload"),
        (put(api, 999, "a.zip", b"PK"), 404, "not_found"),
        (put(api, camera_id, "a.zip", b"PK", kind="movie"), 422, "invalid_input"),
        (put(api, camera_id, "a.rar", b"Rar!"), 415, "unsupported_format"),
        (tus_patch(client, "/api/v1/uploads/0123456789abcdef0123456789abcdef", 0, b"x"), 404, "not_found"),
        (client.head("/api/v1/uploads/../../etc/passwd", headers=TUS), 404, None),
    ]  # fmt: skip
    options = client.options("/api/v1/uploads")
    assert options.status_code == 204 and options.headers["Tus-Version"] == "1.0.0"
    assert "concatenation" not in options.headers["Tus-Extension"]
    assert options.headers["Tus-Max-Size"] == str(api.settings.max_upload_bytes)
    for response, status, code in cases:
        assert response.status_code == status, (response.request.url, response.text)
        if code:
            assert response.json()["code"] == code, response.text
    assert_nothing_kept(api)
    assert all(p.stat().st_size == 0 for p in tus_dir(api.settings.data_path).glob("[0-9a-f]" * 32))


def test_size_limit_and_free_disk_are_checked_before_and_while_uploading(settings, tmp_path, monkeypatch):
    from fringelab.core import storage

    data = write_zip(tmp_path / "r.zip", stripe_frames(40)).read_bytes()
    limited = settings.model_copy(update={"max_upload_bytes": len(data) - 1})
    with serve(limited) as base_url, httpx_client_at(base_url) as client:
        api = Api(base_url, client, limited)
        camera_id = api.camera()
        too_big = tus_create(client, len(data), filename="r.zip", filetype="x", camera_id=camera_id, kind="test")
        assert (too_big.status_code, too_big.json()["code"]) == (413, "upload_too_large")
        assert (put(api, camera_id, "r.zip", data).json()["code"]) == "upload_too_large"
    full = settings.model_copy(update={"min_free_disk_bytes": 10**15})  # a reserve no disk here can keep
    with serve(full) as base_url, httpx_client_at(base_url) as client:
        api = Api(base_url, client, full)
        camera_id = api.camera()
        no_room = tus_create(client, len(data), filename="r.zip", filetype="x", camera_id=camera_id, kind="test")
        assert (no_room.status_code, no_room.json()["code"]) == (413, "insufficient_storage")
        assert "not enough free space" in no_room.json()["detail"]
        assert put(api, camera_id, "r.zip", data).json()["code"] == "insufficient_storage"
    # The disk fills up between two PATCHes: the second is refused, nothing half-written stays, and the upload
    # resumes once there is room again.
    with serve(settings) as base_url, httpx_client_at(base_url) as client:
        api = Api(base_url, client, settings)
        camera_id = api.camera()
        created = tus_create(client, len(data), filename="r.zip", filetype="x", camera_id=camera_id, kind="test")
        location = urlparse(created.headers["Location"]).path
        half = len(data) // 2
        assert tus_patch(client, location, 0, data[:half]).status_code == 204
        monkeypatch.setattr(storage, "free_disk_bytes", lambda _path: 1000)
        refused = tus_patch(client, location, half, data[half:])
        assert (refused.status_code, refused.json()["code"]) == (413, "insufficient_storage")
        assert "not enough free space" in refused.json()["detail"]
        assert tus_offset(client, location) == half
        refused_put = put(api, camera_id, "r.zip", data)
        assert refused_put.json()["code"] in ("insufficient_storage",)
        monkeypatch.undo()
        last = tus_patch(client, location, half, data[half:])
        assert last.status_code == 204, last.text
        recording = client.get(f"/api/v1/recordings/{last.headers['Fringelab-Recording-Id']}").json()
        assert recording["sha256"] == hashlib.sha256(data).hexdigest()


def httpx_client_at(base_url: str):  # type: ignore[no-untyped-def]
    import httpx

    return httpx.Client(base_url=base_url, timeout=60)


def test_an_interrupted_put_leaves_nothing_behind(api, tmp_path):
    camera_id = api.camera()
    data = write_zip(tmp_path / "r.zip", stripe_frames(10)).read_bytes()
    head = (f"PUT /api/v1/uploads/cameras/{camera_id}/r.zip?kind=test HTTP/1.1\r\nHost: 127.0.0.1\r\n"
            f"Content-Length: {len(data)}\r\n\r\n")  # fmt: skip
    staged = put_dir(api.settings.data_path)
    raw_request(api.base_url, head, data[: len(data) // 2], before_close=lambda: staged.exists())
    wait_for(lambda: staged.exists() and not list(staged.glob("*")), timeout_s=10, what="the part file to go")
    assert_nothing_kept(api)


@pytest.mark.integration
def test_bad_frames_and_sidecars_make_the_recording_invalid_with_reasons_never_ready(api, celery_worker, tmp_path):
    camera_id = api.camera()
    frames = stripe_frames(8)
    png = encode(frames[3], ".png")
    with zipfile.ZipFile(tmp_path / "corrupt.zip", "w") as archive:
        for i, frame in enumerate(frames):
            archive.writestr(f"f{i}.png", png[:200] if i == 3 else encode(frame, ".png"))
    mixed = frames[:4] + stripe_frames(1, height=40, width=64) + frames[5:]
    bad_z = "frame,z_mm\n" + "".join(f"{i},{i}\n" for i in range(7)) + "20,1.5\n"
    uploads = {
        "corrupt.zip": ((tmp_path / "corrupt.zip").read_bytes(), "f3.png: the image is truncated"),
        "mixed.zip": (write_zip(tmp_path / "m.zip", mixed).read_bytes(), "frame4.png: 64 × 40 px, but frame 0 is 64"),
        "badz.zip": (write_zip(tmp_path / "z.zip", frames, sidecars={"z.csv": bad_z}).read_bytes(),
                     "z.csv: frame 20 matches no frame of the recording, which has 8 frames"),
        "words.zip": (write_zip(tmp_path / "w.zip", frames, sidecars={"frames.csv": "frame,time_s\n0,zero\n"})
                      .read_bytes(), "frames.csv line 2, column time_s: 'zero' is not a number"),
    }  # fmt: skip
    ids = {}
    for name, (data, _reason) in uploads.items():
        response = put(api, camera_id, name, data, kind="projector_calibration")
        assert response.status_code == 201, response.text
        ids[name] = response.json()["id"]
    for name, (_data, reason) in uploads.items():
        recording = api.wait_settled(ids[name])
        assert recording["state"] == "invalid", name
        assert reason in recording["error"], (name, recording["error"])
        assert api.client.get(f"/api/v1/recordings/{ids[name]}/frames/0").json()["code"] == "not_ready"
        assert not (recording_dir(api.settings.data_path, ids[name]) / "previews.h5").exists()
        job = celery_worker.AsyncResult(recording["ingest_job_id"])
        assert job is not None
    # A corrected sidecar, sent on its own, makes the recording ready.
    good_z = "frame,z_mm\n" + "".join(f"{i},{i * 0.25}\n" for i in range(8))
    fixed = api.client.put(f"/api/v1/recordings/{ids['badz.zip']}/sidecars/z.csv", content=good_z)
    assert fixed.status_code == 202 and fixed.json()["state"] == "ingesting"
    recording = api.wait_settled(ids["badz.zip"])
    assert recording["state"] == "ready", recording["error"]
    assert recording["sidecars"]["z.csv"]["z_mm_max"] == 1.75
