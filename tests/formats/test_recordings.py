"""Every recording format read lazily into grey frames, against the frames that were written."""

from __future__ import annotations

import zipfile

import cv2
import numpy as np
import pytest

from fringelab.formats.container_common import CorruptRecording, UnsafeArchive, UnsupportedRecording
from fringelab.formats.container_zip import ZipLimits
from fringelab.formats.recordings import open_recording
from tests.formats.recording_files import encode, stripe_frames, write_cine, write_tiff_stack, write_video, write_zip


@pytest.mark.parametrize(("suffix", "dtype"), [(".png", np.uint8), (".png", np.uint16), (".tif", np.uint16),
                                               (".bmp", np.uint8)])  # fmt: skip
def test_zip_of_frames_is_exact_in_natural_order(tmp_path, suffix, dtype):
    frames = stripe_frames(12, dtype=dtype)
    names = [f"rec/img{i}{suffix}" for i in range(12)]
    write_zip(tmp_path / "r.zip", frames, names=names, sidecars={"z.csv": "frame,z_mm\n0,1.5\n"})
    with open_recording(tmp_path / "r.zip") as source:
        assert source.format == "zip"
        assert len(source) == 12
        assert source.frame_names[:3] == ("rec/img0" + suffix, "rec/img1" + suffix, "rec/img2" + suffix)
        assert source.frame_names[10] == f"rec/img10{suffix}"  # natural, not lexical order
        for i in (0, 5, 11, -1):
            np.testing.assert_array_equal(source[i], frames[i])
        assert source[3].dtype == dtype
        assert source.sidecar_text("z.csv") == "frame,z_mm\n0,1.5\n"
        assert source.sidecar_text("frames.csv") is None


def test_folder_of_jpeg_frames_and_colour_is_converted_and_noted(tmp_path):
    folder = tmp_path / "rec"
    folder.mkdir()
    grey = stripe_frames(3)
    for i, frame in enumerate(grey):
        colour = cv2.merge([frame, frame // 2, frame])
        (folder / f"f{i}.jpg").write_bytes(encode(colour, ".jpg"))
    (folder / ".DS_Store").write_bytes(b"junk")
    source = open_recording(folder)
    assert source.format == "folder" and len(source) == 3
    frame = source[1]
    assert frame.shape == (48, 64) and frame.dtype == np.uint8
    assert source.colour_converted
    # BT.601 luma of (B=f, G=f/2, R=f) is 0.701 f; JPEG loses up to a few grey levels.
    expected = 0.114 * grey[1] + 0.587 * (grey[1] // 2) + 0.299 * grey[1]
    assert np.abs(frame.astype(float) - expected).mean() < 3


def test_multipage_tiff_16_bit_and_colour_pages(tmp_path):
    frames = stripe_frames(5, dtype=np.uint16)
    with open_recording(write_tiff_stack(tmp_path / "s.tif", frames)) as source:
        assert source.format == "tiff" and len(source) == 5 and source.bit_depth == 16
        np.testing.assert_array_equal(source[4], frames[4])
        assert not source.colour_converted
    rgb = [np.dstack([f, f, f]) for f in stripe_frames(2)]
    with open_recording(write_tiff_stack(tmp_path / "c.tif", rgb)) as source:
        np.testing.assert_array_equal(source[1], rgb[1][:, :, 0])  # equal channels: luma is the channel
        assert source.colour_converted


def test_tiff_compressed_with_a_codec_tifffile_lacks_falls_back_to_opencv(tmp_path):
    frame = stripe_frames(1, dtype=np.uint16)[0]
    cv2.imwrite(str(tmp_path / "lzw.tif"), frame)  # OpenCV writes LZW, which tifffile needs imagecodecs for
    with open_recording(tmp_path / "lzw.tif") as source:
        np.testing.assert_array_equal(source[0], frame)


@pytest.mark.parametrize("suffix", [".avi", ".mp4"])
def test_video_is_read_as_grey_with_its_frame_rate(tmp_path, suffix):
    frames = [np.full((48, 64), 20 * i + 30, np.uint8) for i in range(6)]
    with open_recording(write_video(tmp_path / f"v{suffix}", frames, fps=50)) as source:
        assert source.format == suffix[1:]
        assert len(source) == 6 and source.fps == pytest.approx(50)
        for i in (0, 3, 5, 2):  # forwards and a seek back
            frame = source[i]
            assert frame.shape == (48, 64) and frame.dtype == np.uint8
            assert abs(float(frame.mean()) - (20 * i + 30)) < 3  # lossy codecs: within 3 grey levels


@pytest.mark.parametrize(("dtype", "real_bpp"), [(np.uint8, 8), (np.uint16, 12)])
def test_cine_is_exact_with_rate_and_real_bit_depth(tmp_path, dtype, real_bpp):
    frames = stripe_frames(7, dtype=dtype, height=30, width=40)
    frames[2][0, :5] = 7  # an asymmetric mark: rows must come out top-down
    with open_recording(write_cine(tmp_path / "r.cine", frames, fps=10000, real_bpp=real_bpp)) as source:
        assert source.format == "cine"
        assert len(source) == 7 and source.fps == 10000 and source.bit_depth == real_bpp
        for i in range(7):
            np.testing.assert_array_equal(source[i], frames[i])


def test_colour_cine_is_converted(tmp_path):
    grey = stripe_frames(2)
    colour = [cv2.merge([g, g, g]) for g in grey]
    with open_recording(write_cine(tmp_path / "c.cine", colour)) as source:
        np.testing.assert_array_equal(source[1], grey[1])
        assert source.colour_converted


def test_truncated_cine_is_refused(tmp_path):
    path = write_cine(tmp_path / "r.cine", stripe_frames(4))
    data = path.read_bytes()
    path.write_bytes(data[:-100])
    with pytest.raises(CorruptRecording, match="truncated"):
        open_recording(path)


def test_a_sidecar_beside_a_single_file_recording_is_found(tmp_path):
    path = write_cine(tmp_path / "r.cine", stripe_frames(2))
    (tmp_path / "frames.csv").write_text("frame,time_s\n0,0\n1,0.001\n")
    assert open_recording(path).sidecar_text("frames.csv").startswith("frame,time_s")


def test_corrupt_and_truncated_frames_fail_on_access_naming_the_frame(tmp_path):
    frames = stripe_frames(3)
    png = encode(frames[0], ".png")
    jpg = encode(frames[0], ".jpg")
    with zipfile.ZipFile(tmp_path / "r.zip", "w") as archive:
        archive.writestr("a0.png", png)
        archive.writestr("a1.png", png[: len(png) // 2])
        archive.writestr("a2.jpg", jpg[: len(jpg) - 200])
        archive.writestr("a3.png", b"not an image at all")
    source = open_recording(tmp_path / "r.zip")
    np.testing.assert_array_equal(source[0], frames[0])
    for i, name in ((1, "a1.png"), (2, "a2.jpg"), (3, "a3.png")):
        with pytest.raises(ValueError, match=name):
            source[i]


def test_zip_path_traversal_absolute_paths_and_links_are_refused(tmp_path):
    for bad in ("../evil.png", "a/../../evil.png", "/etc/evil.png", "C:/evil.png"):
        with zipfile.ZipFile(tmp_path / "bad.zip", "w") as archive:
            archive.writestr("ok.png", encode(stripe_frames(1)[0], ".png"))
            archive.writestr(zipfile.ZipInfo(bad), b"x")
        with pytest.raises(UnsafeArchive, match="absolute path|climbs out"):
            open_recording(tmp_path / "bad.zip")
    link = zipfile.ZipInfo("link.png")
    link.external_attr = 0o120777 << 16
    with zipfile.ZipFile(tmp_path / "link.zip", "w") as archive:
        archive.writestr(link, "/etc/passwd")
    with pytest.raises(UnsafeArchive, match="symbolic link"):
        open_recording(tmp_path / "link.zip")


def test_zip_bombs_are_refused_by_ratio_and_by_total_size(tmp_path):
    with zipfile.ZipFile(tmp_path / "bomb.zip", "w", compression=zipfile.ZIP_DEFLATED) as archive:
        archive.writestr("f0.bmp", bytes(64 << 20))  # 64 MiB of zeros deflate ~1000×
    with pytest.raises(UnsafeArchive, match="ZIP bomb"):
        open_recording(tmp_path / "bomb.zip")
    write_zip(tmp_path / "big.zip", stripe_frames(4))
    with pytest.raises(UnsafeArchive, match="in total"):
        open_recording(tmp_path / "big.zip", zip_limits=ZipLimits(max_total_bytes=1000))


def test_overlapping_entries_are_refused(tmp_path):
    """A non-recursive ZIP bomb: two central-directory names pointing at the same compressed data."""
    path = write_zip(tmp_path / "r.zip", stripe_frames(2), compression=zipfile.ZIP_DEFLATED)
    with zipfile.ZipFile(path) as archive:
        first, second = archive.infolist()
    data = bytearray(path.read_bytes())
    # Point the second central-directory record at the first entry's local header.
    cd = data.rfind(b"PK\x01\x02")
    data[cd + 42 : cd + 46] = first.header_offset.to_bytes(4, "little")
    assert second.header_offset != first.header_offset
    path.write_bytes(bytes(data))
    with pytest.raises(UnsafeArchive, match="overlap"):
        open_recording(path)


def test_truncated_zip_and_other_files_are_refused_with_what_they_are(tmp_path):
    path = write_zip(tmp_path / "r.zip", stripe_frames(3))
    path.write_bytes(path.read_bytes()[:-40])
    with pytest.raises(CorruptRecording, match="truncated"):
        open_recording(path)
    (tmp_path / "one.png").write_bytes(encode(stripe_frames(1)[0], ".png"))
    with pytest.raises(UnsupportedRecording, match="single PNG image"):
        open_recording(tmp_path / "one.png")
    (tmp_path / "notes.txt").write_text("hello")
    with pytest.raises(UnsupportedRecording, match="not a recording format"):
        open_recording(tmp_path / "notes.txt")
    (tmp_path / "empty.zip").write_bytes(b"")
    with pytest.raises(CorruptRecording, match="empty"):
        open_recording(tmp_path / "empty.zip")
    with zipfile.ZipFile(tmp_path / "noframes.zip", "w") as archive:
        archive.writestr("readme.txt", "no frames here")
    with pytest.raises(UnsupportedRecording, match="no image frames"):
        open_recording(tmp_path / "noframes.zip")


def test_an_image_declaring_a_huge_size_is_refused_before_decoding(tmp_path):
    """A decompression bomb in one frame: a few kB of PNG declaring 40000 × 40000 px."""
    import struct
    import zlib

    def chunk(tag: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data))

    row = b"\x00" + bytes(40000)
    compressor = zlib.compressobj(9)
    idat = b"".join(compressor.compress(row) for _ in range(200)) + compressor.flush()
    bomb = (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", 40000, 40000, 8, 0, 0, 0, 0))
            + chunk(b"IDAT", idat) + chunk(b"IEND", b""))  # fmt: skip
    with zipfile.ZipFile(tmp_path / "r.zip", "w") as archive:
        archive.writestr("f0.png", bomb)
    with pytest.raises(ValueError, match="40000 × 40000 px of 8 bits decodes to 1600000000 bytes"):
        open_recording(tmp_path / "r.zip")[0]


def test_damaged_compressed_data_in_a_zip_names_the_frame(tmp_path):
    path = write_zip(tmp_path / "r.zip", stripe_frames(2), compression=zipfile.ZIP_DEFLATED)
    with zipfile.ZipFile(path) as archive:
        second = archive.infolist()[1]
    data = bytearray(path.read_bytes())
    start = second.header_offset + 30 + len(second.filename)
    data[start + 10 : start + 60] = bytes(50)  # scramble the deflate stream of frame1.png
    path.write_bytes(bytes(data))
    source = open_recording(path)
    source[0]
    with pytest.raises(ValueError, match="frame1.png"):
        source[1]


@pytest.mark.parametrize("keep", [0.99, 0.8, 0.75, 0.6, 0.5, 0.3])
def test_truncated_tiff_is_refused_never_fewer_pages(tmp_path, keep):
    path = write_tiff_stack(tmp_path / "a.tif", stripe_frames(5))
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * keep)])
    with pytest.raises(ValueError, match="truncated|not a readable TIFF|page"):
        source = open_recording(path)
        for i in range(len(source)):
            source[i]
        assert len(source) == 5  # reached only if every frame read: then all five must be there


def test_the_accepted_formats_sentence_names_every_upload_suffix() -> None:
    from fringelab.formats.containers import ACCEPTED_UPLOADS, UPLOAD_SUFFIXES

    for suffix in UPLOAD_SUFFIXES:
        assert f"({suffix}" in ACCEPTED_UPLOADS or f", {suffix})" in ACCEPTED_UPLOADS, suffix
