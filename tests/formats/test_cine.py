"""Phantom .cine as cameras write them (tagged blocks, trigger numbering, packed pixels), read by fringelab and
cross-checked against pims, an independent reader."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from fringelab.formats.container_cine import read_cine_header
from fringelab.formats.container_common import CorruptRecording, UnsupportedRecording
from fringelab.formats.recordings import open_recording
from tests.formats.recording_files import stripe_frames, write_cine

pims = pytest.importorskip("pims")


def _frames(n: int, bits: int, *, seed: int = 1) -> list[np.ndarray]:
    """Random frames of `bits`-bit values with an asymmetric mark (rows must come out top-down)."""
    rng = np.random.default_rng(seed)
    frames = [rng.integers(0, 1 << bits, (6, 16), dtype=np.uint16 if bits > 8 else np.uint8) for _ in range(n)]
    for frame in frames:
        frame[0, :3] = 1
    return frames


@pytest.mark.parametrize(
    ("bits", "packing"), [(8, ""), (16, ""), (10, "P10"), (12, "P12L")], ids=["8-bit", "16-bit", "P10", "P12L"]
)
def test_cine_pixels_match_pims_and_the_truth(tmp_path, bits, packing):
    frames = _frames(5, bits)
    path = write_cine(tmp_path / "r.cine", frames, fps=20000, real_bpp=min(bits, 12) if bits > 8 else 8,
                      packing=packing, first_image_no=-2)  # fmt: skip
    reference = pims.Cine(str(path))
    try:
        with open_recording(path) as source:
            assert len(source) == len(reference) == 5
            for i in (0, 4, 2):
                ours = source[i]
                np.testing.assert_array_equal(ours, frames[i])  # exact: lossless container
                np.testing.assert_array_equal(ours, np.asarray(reference[i]))
    finally:
        reference.close()


def test_trigger_numbering_and_time_stamps_match_pims(tmp_path):
    # The time stamps jitter by ±1 µs around the nominal rate: the reader must use the stamps, not the rate.
    path = write_cine(tmp_path / "r.cine", stripe_frames(6), fps=10000, first_image_no=-3, jitter_s=1e-6)
    reference = pims.Cine(str(path))
    try:
        with open_recording(path) as source:
            np.testing.assert_array_equal(source.frame_numbers, [-3, -2, -1, 0, 1, 2])
            assert source.frame_names[3] == "frame 0"
            expected = [reference.get_time_to_trigger(i) for i in range(6)]
            # TIME64 resolves 2^-32 s (0.23 ns); pims goes through datetime (µs), so agree to 1 µs
            np.testing.assert_allclose(source.frame_times_s, expected, atol=1e-6)
            nominal = (np.arange(6) - 3) / 10000 + 1e-6 * (np.arange(6) % 3 - 1)
            np.testing.assert_allclose(source.frame_times_s, nominal, atol=1e-9)  # 1 ns: TIME64 resolves 0.23 ns
            assert reference.frame_rate == source.fps == 10000
    finally:
        reference.close()


def test_without_time_stamps_times_come_from_rate_and_numbers(tmp_path):
    path = write_cine(tmp_path / "r.cine", stripe_frames(3), fps=1000, first_image_no=5, time_stamps=False)
    with open_recording(path) as source:
        np.testing.assert_allclose(source.frame_times_s, [0.005, 0.006, 0.007], rtol=1e-12)
        assert any("frame rate" in note for note in source.notes)


@pytest.mark.parametrize(("code", "what"), [(1, "JPEG"), (2, "raw Bayer")])
def test_compressed_cine_is_refused_with_what_to_do(tmp_path, code, what):
    path = write_cine(tmp_path / "r.cine", stripe_frames(2), compression=code)
    with pytest.raises(UnsupportedRecording, match=f"{what}.*uncompressed"):
        open_recording(path)


@pytest.mark.parametrize("packing", ["", "P12L"])
def test_every_truncation_is_an_error_never_fewer_frames(tmp_path, packing):
    frames = _frames(4, 12) if packing else stripe_frames(4)
    path = write_cine(tmp_path / "r.cine", frames, packing=packing)
    data = path.read_bytes()
    header = read_cine_header(path)
    first_image = int(header.image_offsets[0])
    # cut inside the header, the setup, the tagged blocks, the offsets, each frame and the last byte
    for cut in (20, 60, 500, first_image - 4, first_image + 10, int(header.image_offsets[2]) + 30, len(data) - 1):
        path.write_bytes(data[:cut])
        with pytest.raises(CorruptRecording, match="truncated|damaged"):
            open_recording(path)


def test_a_damaged_tagged_block_is_refused(tmp_path):
    path = write_cine(tmp_path / "r.cine", stripe_frames(2))
    data = bytearray(path.read_bytes())
    setup_end = 84 + struct.unpack_from("<H", data, 84 + 142)[0]
    struct.pack_into("<I", data, setup_end, 1 << 30)  # the first block claims 1 GiB
    path.write_bytes(bytes(data))
    with pytest.raises(CorruptRecording, match="tagged block"):
        open_recording(path)
