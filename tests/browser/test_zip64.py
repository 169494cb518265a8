"""The browser's folder packer (frontend/zip.js) in real Chromium: archives Python's zipfile and fringelab's own
ZIP checks read back exactly, with ZIP64 records where a plain ZIP's fields end (4 GiB, 65,535 entries)."""

from __future__ import annotations

import base64
import functools
import http.server
import io
import threading
import zipfile
import zlib
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from fringelab.formats.container_zip import inspect_zip
from fringelab.formats.recordings import open_recording
from tests.formats.recording_files import encode, stripe_frames

pytestmark = pytest.mark.browser

FRONTEND = Path(__file__).resolve().parents[2] / "frontend"

PACK = """async ([files, options]) => {
  const { storedZip } = await import("/zip.js");
  const entries = files.map(([path, b64]) => ({
    path, file: new File([Uint8Array.from(atob(b64), (c) => c.charCodeAt(0))], path.split("/").pop()) }));
  const blob = await storedZip(entries, options);
  const url = await new Promise((resolve) => { const r = new FileReader(); r.onload = () => resolve(r.result);
                                               r.readAsDataURL(blob); });
  return url.slice(url.indexOf(",") + 1);
}"""

MANY = """async (count) => {
  const { storedZip } = await import("/zip.js");
  const digits = Array.from({ length: 10 }, (_, d) => new File([String(d)], `${d}.txt`));
  const entries = Array.from({ length: count }, (_, i) => ({ path: `f/${i}.txt`, file: digits[i % 10] }));
  const blob = await storedZip(entries);
  const url = await new Promise((resolve) => { const r = new FileReader(); r.onload = () => resolve(r.result);
                                               r.readAsDataURL(blob); });
  return url.slice(url.indexOf(",") + 1);
}"""


@pytest.fixture(scope="module")
def static_page(browser) -> Iterator[object]:
    handler = functools.partial(http.server.SimpleHTTPRequestHandler, directory=str(FRONTEND))
    handler.log_message = lambda *args: None  # type: ignore[method-assign]
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    page = browser.new_page()
    page.goto(f"http://127.0.0.1:{server.server_address[1]}/zip.js")  # any page of that origin: modules import
    yield page
    page.close()
    server.shutdown()
    server.server_close()


def _pack(page, files: dict[str, bytes], **options: str) -> bytes:
    listed = [[name, base64.b64encode(data).decode()] for name, data in files.items()]
    return base64.b64decode(page.evaluate(PACK, [listed, options]))


@pytest.mark.parametrize("zip64", ["auto", "always"])
def test_packed_folder_reads_back_exactly(static_page, tmp_path, zip64):
    frames = stripe_frames(3, dtype=np.uint16)
    files = {f"shot/frame{i}.png": encode(frame, ".png") for i, frame in enumerate(frames)}
    files["shot/frames.csv"] = b"frame,time_s\n0,0\n1,0.001\n2,0.002\n"
    files["shot/名前 ü.txt"] = b"UTF-8 names"
    data = _pack(static_page, files, zip64=zip64)
    assert (b"PK\x06\x06" in data) == (zip64 == "always")  # the ZIP64 end record only where asked or needed
    with zipfile.ZipFile(io.BytesIO(data)) as archive:
        assert archive.testzip() is None  # every CRC-32 right
        assert {name: archive.read(name) for name in archive.namelist()} == files
    path = tmp_path / "shot.zip"
    path.write_bytes(data)
    contents = inspect_zip(path)  # the server's own checks (overlaps, sizes, names)
    assert contents.sidecar_names == {"frames.csv": "shot/frames.csv"}
    with open_recording(path) as source:
        for i, frame in enumerate(frames):
            np.testing.assert_array_equal(source[i], frame)


@pytest.mark.slow  # 65,537 files, each read for its CRC: about half a minute on a shared machine
def test_more_than_65535_files_use_zip64(static_page):
    count = 65_537
    data = base64.b64decode(static_page.evaluate(MANY, count))
    assert b"PK\x06\x06" in data and b"PK\x06\x07" in data
    with zipfile.ZipFile(io.BytesIO(data)) as archive:
        entries = archive.infolist()
        assert [e.filename for e in entries] == [f"f/{i}.txt" for i in range(count)]
        # every CRC-32, read in batches of small files, against the content (testzip would take a minute here)
        assert [e.CRC for e in entries] == [zlib.crc32(str(i % 10).encode()) for i in range(count)]
        assert archive.read("f/65536.txt") == b"6" and archive.read("f/0.txt") == b"0"
