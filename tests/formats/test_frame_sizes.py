"""Sizes before bytes (issue 26): every frame's size, channels and bit depth from its header, held against a byte
budget per frame and the first frame's size before it is decoded, in every container."""

from __future__ import annotations

import zipfile

import numpy as np
import pytest
import tifffile

from fringelab.formats.container_common import CorruptRecording, OverBudget
from fringelab.formats.containers import check_ingest_budget, recording_layout
from fringelab.formats.frame_header import FrameHeader, image_header
from fringelab.formats.recordings import open_recording
from tests.formats.recording_files import deflated_tiff_bomb, encode, png_bomb, stripe_frames, write_cine

MIB = 1 << 20


def _zip(path, entries: dict[str, bytes]):
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        for name, data in entries.items():
            archive.writestr(name, data)
    return path


@pytest.mark.parametrize("ifd_last", [True, False])
def test_a_deflated_tiff_bomb_behind_a_small_png_in_a_zip_is_refused_before_decoding(tmp_path, ifd_last):
    """Finding 3: a 64 × 48 PNG and a deflated 20000² 16-bit RGB TIFF (2.3 MB in all) took a worker from 528 to
    5090 MiB. Here 3000² (54 MB decoded, 55 kB stored) against a 16 MiB budget: refused from its header, by
    name, with the budget named; the first frame reads."""
    small = encode(stripe_frames(1)[0], ".png")
    path = _zip(tmp_path / "r.zip", {"f0.png": small, "f1.tif": deflated_tiff_bomb(3000, 3000, ifd_last=ifd_last)})
    assert path.stat().st_size < 200_000
    with open_recording(path, max_frame_bytes=16 * MIB) as source:
        assert source[0].shape == (48, 64)
        with pytest.raises(OverBudget, match=r"f1\.tif: 3000 × 3000 px of 3 × 16 bits decodes to 54000000 bytes.*"
                           "FRINGELAB_MAX_FRAME_BYTES"):  # fmt: skip
            source[1]


def test_a_png_bomb_is_refused_by_bytes_not_pixels(tmp_path):
    """Finding 3: an 11000² 16-bit RGBA PNG (0.9 MB) took 1.9 GiB: the old limit counted pixels (121 M < 134 M).
    2000² 16-bit RGBA here: 32 MB decoded, refused against 16 MiB from its header, as the first frame (at
    upload, from the layout) or a later one (by the reader)."""
    bomb = png_bomb(2000, 2000)
    assert image_header(bomb) == FrameHeader(2000, 2000, 4, 2)
    first = _zip(tmp_path / "first.zip", {"a.png": bomb})
    layout = recording_layout(first)
    assert layout.bytes_per_pixel == 8
    budget = {"max_frames_bytes": 10**12, "free_bytes": 10**12, "reserve_bytes": 0, "preview_size_px": 800,
              "thumbnail_px": 160}  # fmt: skip
    with pytest.raises(OverBudget, match="limit of one frame"):
        check_ingest_budget(layout, name="first.zip", max_frame_bytes=16 * MIB, **budget)
    later = _zip(tmp_path / "later.zip", {"a.png": encode(stripe_frames(1)[0], ".png"), "b.png": bomb})
    with open_recording(later, max_frame_bytes=16 * MIB) as source, pytest.raises(OverBudget, match="b.png"):
        source[1]


def test_a_frame_unlike_the_first_is_refused_before_decoding(tmp_path):
    frames = stripe_frames(2)
    other = encode(stripe_frames(1, height=96, width=128)[0], ".png")
    path = _zip(tmp_path / "r.zip", {"f0.png": encode(frames[0], ".png"), "f1.png": other})
    with open_recording(path) as source, pytest.raises(CorruptRecording, match="128 × 96 px, but frame 0 is 64 × 48"):
        source[1]


def test_tiff_pages_and_single_file_containers_are_held_against_the_frame_budget(tmp_path):
    stack = tmp_path / "s.tif"
    tifffile.imwrite(stack, np.zeros((2, 300, 400, 3), np.uint16), photometric="rgb")
    with open_recording(stack, max_frame_bytes=400 * 300 * 3 * 2) as source:  # exactly at the budget: read
        assert source[0].shape == (300, 400)
    with open_recording(stack, max_frame_bytes=400 * 300 * 3 * 2 - 1) as source, pytest.raises(OverBudget):
        source[1]
    cine = recording_layout(write_cine(tmp_path / "r.cine", stripe_frames(2, dtype=np.uint16)))
    budget = {"max_frames_bytes": 10**12, "free_bytes": 10**12, "reserve_bytes": 0, "preview_size_px": 800,
              "thumbnail_px": 160}  # fmt: skip
    check_ingest_budget(cine, name="r.cine", max_frame_bytes=64 * 48 * 2, **budget)
    with pytest.raises(OverBudget, match="r.cine"):
        check_ingest_budget(cine, name="r.cine", max_frame_bytes=64 * 48 * 2 - 1, **budget)
