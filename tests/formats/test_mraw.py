"""Photron MRAW (.cih/.cihx + .mraw) at 8, 12 and 16 bits, read by fringelab and cross-checked against pyMRAW."""

from __future__ import annotations

import numpy as np
import pytest

from fringelab.formats.container_common import CorruptRecording, UnsupportedRecording
from fringelab.formats.recordings import open_recording
from tests.formats.recording_files import write_mraw

pymraw = pytest.importorskip("pyMRAW")


def _frames(n: int, bits: int, *, seed: int = 3) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    frames = [rng.integers(0, 1 << bits, (6, 10), dtype=np.uint8 if bits == 8 else np.uint16) for _ in range(n)]
    for frame in frames:
        frame[0, :3] = 1  # an asymmetric mark: rows must come out top-down
    return frames


@pytest.mark.parametrize("header", ["cih", "cihx"])
@pytest.mark.parametrize("bits", [8, 12, 16])
def test_mraw_pixels_match_pymraw_and_the_truth(tmp_path, bits, header):
    frames = _frames(4, bits)
    header_path = write_mraw(tmp_path / "shot", frames, bits=bits, fps=75000, start_frame=-2, header=header)
    reference, cih = pymraw.load_video(str(header_path))
    for opened_by in (header_path, header_path.with_suffix(".mraw")):  # either file names the recording
        with open_recording(opened_by) as source:
            assert (source.format, len(source), source.fps) == ("mraw", 4, 75000)
            assert source.bit_depth == bits
            np.testing.assert_array_equal(source.frame_numbers, [-2, -1, 0, 1])
            np.testing.assert_allclose(source.frame_times_s, np.array([-2, -1, 0, 1]) / 75000, rtol=1e-12)
            for i in (3, 0, 2):
                np.testing.assert_array_equal(source[i], frames[i])  # exact: lossless container
                np.testing.assert_array_equal(source[i], np.asarray(reference[i]))
            assert source[0].dtype == (np.uint8 if bits == 8 else np.uint16)
    assert cih["Total Frame"] == 4


def test_truncated_or_oversized_mraw_is_an_error_never_fewer_frames(tmp_path):
    header_path = write_mraw(tmp_path / "shot", _frames(3, 12), bits=12)
    data_path = header_path.with_suffix(".mraw")
    data = data_path.read_bytes()
    for cut in (1, len(data) // 3, len(data) - 1):
        data_path.write_bytes(data[:cut])
        with pytest.raises(CorruptRecording, match="truncated"):
            open_recording(header_path)
    data_path.write_bytes(data + b"\0" * 90)
    with pytest.raises(CorruptRecording, match="does not belong"):
        open_recording(header_path)


def test_truncated_cihx_and_missing_files_are_named(tmp_path):
    header_path = write_mraw(tmp_path / "shot", _frames(2, 8), bits=8, header="cihx")
    text = header_path.read_bytes()
    header_path.write_bytes(text[: len(text) // 2])
    with pytest.raises(CorruptRecording, match="truncated or damaged"):
        open_recording(header_path)
    header_path.unlink()
    with pytest.raises(UnsupportedRecording, match=r"needs its \.cihx or \.cih"):
        open_recording(tmp_path / "shot.mraw")
    header_path = write_mraw(tmp_path / "other", _frames(2, 8), bits=8)
    header_path.with_suffix(".mraw").unlink()
    with pytest.raises(CorruptRecording, match="other.mraw is missing"):
        open_recording(header_path)


def test_colour_mraw_is_refused(tmp_path):
    header_path = write_mraw(tmp_path / "shot", _frames(2, 8), bits=8, colour="Color")
    with pytest.raises(UnsupportedRecording, match="monochrome"):
        open_recording(header_path)


@pytest.mark.parametrize("header", ["cih", "cihx"])
def test_mraw_uploaded_as_one_zip_reads_frames_where_they_lie(tmp_path, header):
    import zipfile

    from fringelab.formats.container_zip import inspect_zip

    frames = _frames(3, 12)
    header_path = write_mraw(tmp_path / "shot", frames, bits=12, start_frame=-1, header=header)
    archive_path = tmp_path / "shot.zip"
    with zipfile.ZipFile(archive_path, "w", zipfile.ZIP_STORED) as archive:
        archive.write(header_path, f"run 7/{header_path.name}")
        archive.write(header_path.with_suffix(".mraw"), "run 7/shot.mraw")
        archive.writestr("run 7/frames.csv", "frame,force_kN\n0,1\n")
    assert inspect_zip(archive_path).mraw_entries == (f"run 7/{header_path.name}", "run 7/shot.mraw")
    with open_recording(archive_path) as source:
        assert (source.format, len(source)) == ("mraw", 3)
        np.testing.assert_array_equal(source.frame_numbers, [-1, 0, 1])
        for i in (2, 0, 1):
            np.testing.assert_array_equal(source[i], frames[i])
    # the .mraw compressed in the ZIP cannot be read in place: refused with what to do
    with zipfile.ZipFile(tmp_path / "deflated.zip", "w", zipfile.ZIP_DEFLATED) as archive:
        archive.write(header_path, header_path.name)
        archive.write(header_path.with_suffix(".mraw"), "shot.mraw")
    with pytest.raises(UnsupportedRecording, match="store it uncompressed"):
        open_recording(tmp_path / "deflated.zip")
    # truncated inside the ZIP: the entry's size does not match the header
    with zipfile.ZipFile(tmp_path / "short.zip", "w", zipfile.ZIP_STORED) as archive:
        archive.write(header_path, header_path.name)
        archive.writestr("shot.mraw", header_path.with_suffix(".mraw").read_bytes()[:-7])
    with pytest.raises(CorruptRecording, match="truncated"):
        open_recording(tmp_path / "short.zip")
