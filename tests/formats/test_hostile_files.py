"""Files made to hurt the server (issue 16): truncated containers of every format, a .cine whose frame offsets all
name one frame, a ZIP of many entries each just under the per-entry ratio check, oversized or malformed sidecars,
and the ingest budget computed from headers before anything is written."""

from __future__ import annotations

import io
import struct
import zipfile

import numpy as np
import pytest
import tifffile

from fringelab.formats.container_common import MAX_SIDECAR_BYTES, CorruptRecording, OverBudget, UnsafeArchive
from fringelab.formats.container_zip import ZipLimits, inspect_zip
from fringelab.formats.containers import check_ingest_budget, recording_layout
from fringelab.formats.recordings import open_recording
from fringelab.formats.sidecars import read_board_json, read_frames_csv, read_z_csv
from tests.formats.recording_files import stripe_frames, write_cine, write_tiff_stack, write_video, write_zip


def _cut(path, fraction: float):
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * fraction)])
    return path


@pytest.mark.parametrize("writer", ["pages", "imagej", "bigtiff"])
def test_a_truncated_multi_page_tiff_is_refused_not_read_as_its_first_page(tmp_path, writer):
    frames = stripe_frames(10)
    path = tmp_path / "stack.tif"
    if writer == "pages":
        write_tiff_stack(path, frames)
    else:
        buffer = io.BytesIO()
        tifffile.imwrite(buffer, np.stack(frames), imagej=writer == "imagej", bigtiff=writer == "bigtiff")
        path.write_bytes(buffer.getvalue())
    with open_recording(path) as whole:
        assert len(whole) == 10  # the walker reads every page of a sound file
    _cut(path, 0.3)
    with pytest.raises(CorruptRecording, match="truncated"):
        open_recording(path)
    with pytest.raises(CorruptRecording, match="truncated"):
        recording_layout(path)


@pytest.mark.parametrize("suffix", [".avi", ".mp4"])
def test_a_truncated_video_is_refused_by_its_container(tmp_path, suffix):
    path = write_video(tmp_path / f"clip{suffix}", stripe_frames(20, height=64, width=64))
    with open_recording(path) as whole:
        assert len(whole) == 20
    _cut(path, 0.6)
    with pytest.raises(CorruptRecording, match="truncated"):
        open_recording(path)


def test_a_cine_whose_offsets_name_one_frame_is_refused(tmp_path):
    """279 kB that decoded to 4,000 frames (1.08 GB of previews): offsets must step by at least a frame."""
    path = write_cine(tmp_path / "one.cine", stripe_frames(2))
    data = bytearray(path.read_bytes())
    off_offsets = struct.unpack_from("<I", data, 32)[0]
    first = struct.unpack_from("<Q", data, off_offsets)[0]
    struct.pack_into("<Q", data, off_offsets + 8, first)  # frame 1 is frame 0 again
    path.write_bytes(bytes(data))
    with pytest.raises(CorruptRecording, match="overlap"):
        open_recording(path)


def test_many_small_entries_cannot_add_up_to_a_zip_bomb(tmp_path):
    """Each entry under 1 MiB escapes the per-entry ratio; the archive's total ratio does not."""
    path = tmp_path / "bomb.zip"
    blank = np.zeros((1000, 1000), np.uint8).tobytes()  # 0.95 MiB each, deflates ~1000×
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        for i in range(20):
            archive.writestr(f"f{i}.bmp", blank)
    with pytest.raises(UnsafeArchive, match="in total"):
        inspect_zip(path)


def test_a_z_csv_over_the_cap_inside_a_zip_is_refused_before_it_is_read(tmp_path):
    rows = "frame,z_mm\n" + "0,1.0\n" * (MAX_SIDECAR_BYTES // 6 + 10)
    path = write_zip(tmp_path / "big.zip", stripe_frames(2), sidecars={"z.csv": rows}, compression=zipfile.ZIP_DEFLATED)
    with pytest.raises(ValueError, match="larger than"):
        inspect_zip(path, limits=ZipLimits(max_ratio=1e9))


@pytest.mark.parametrize(
    ("parse", "text", "message"),
    [
        (read_z_csv, "frame,z_mm\n0," + "1" * 200_000 + "\n", "not a CSV row"),  # over csv's own 128 KB limit
        (read_z_csv, "frame,z_mm\n1e23,1.0\n", "not an integer"),
        (read_z_csv, "frame,z_mm\n0," + "1" * 100 + "\n", "characters"),
        (read_z_csv, "frame,z_mm\n100000000000000000000000,1.0\n", "not a frame number"),
        (read_z_csv, "frame,z_mm\n0,1e999\n", "not finite"),
        (read_frames_csv, "frame,time_s\n0,\x00\n", "line 2"),
        (read_board_json, "[" * 100_000 + "]" * 100_000, "nested deeper"),
        (read_board_json, '{"cols": 9, "rows": 6, "square_mm": NaN}', "NaN"),
        (read_board_json, '{"cols": 9, "rows": 6, "square_mm": 1e999}', "positive number"),
    ],
)
def test_malformed_sidecars_are_value_errors_naming_the_file(parse, text, message):
    with pytest.raises(ValueError, match=message) as caught:
        parse(text)
    assert str(caught.value).startswith(("z.csv", "frames.csv", "board.json"))


def test_the_ingest_budget_comes_from_headers_and_refuses_before_writing(tmp_path):
    path = write_cine(tmp_path / "r.cine", stripe_frames(6, height=48, width=64))
    layout = recording_layout(path)
    assert (layout.format, layout.frame_count, layout.width_px, layout.height_px) == ("cine", 6, 64, 48)
    assert layout.frames_bytes == 6 * 64 * 48
    budget = dict(name="r.cine", free_bytes=10**12, reserve_bytes=0, preview_size_px=800, thumbnail_px=160)
    check_ingest_budget(layout, max_frames_bytes=layout.frames_bytes, **budget)  # exactly at the cap passes
    with pytest.raises(OverBudget, match="FRINGELAB_MAX_FRAMES_BYTES"):
        check_ingest_budget(layout, max_frames_bytes=layout.frames_bytes - 1, **budget)
    with pytest.raises(OverBudget, match="free"):
        check_ingest_budget(layout, max_frames_bytes=10**12, **{**budget, "free_bytes": 1000})
    zipped = write_zip(tmp_path / "r.zip", stripe_frames(5, height=30, width=40))
    assert recording_layout(zipped).frames_bytes == 5 * 30 * 40
    stack = write_tiff_stack(tmp_path / "r.tif", stripe_frames(4, height=30, width=40, dtype=np.uint16))
    assert recording_layout(stack).frames_bytes == 4 * 30 * 40 * 2
    avi = write_video(tmp_path / "r.avi", stripe_frames(7, height=64, width=64))
    assert recording_layout(avi).frame_count == 7
