"""Writers of real recording files in every lab format, for the tests: ZIP or folder of frames, multi-page
TIFF, AVI/MP4 and Phantom .cine (a small writer of the uncompressed layout), plus synthetic frames."""

from __future__ import annotations

import struct
import zipfile
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np
import tifffile


def stripe_frames(n: int, *, height: int = 48, width: int = 64, dtype: type = np.uint8, seed: int = 0) -> list:
    """Frames of vertical black/white stripes (period 8 px) with a little noise, distinct per frame."""
    rng = np.random.default_rng(seed)
    top = 255 if dtype == np.uint8 else 4095  # 16-bit frames carry 12-bit data, as a lab camera writes them
    columns = (np.arange(width) // 4) % 2
    frames = []
    for i in range(n):
        base = np.where(columns, 0.8, 0.15)[None, :] * np.ones((height, 1))
        noisy = base * top + rng.normal(0, top * 0.01, (height, width)) + i
        frames.append(np.clip(noisy, 0, top).astype(dtype))
    return frames


def encode(frame: np.ndarray, suffix: str) -> bytes:
    ok, data = cv2.imencode(suffix, frame)
    assert ok, f"cannot encode {frame.dtype} as {suffix}"
    return data.tobytes()


def write_zip(
    path: Path,
    frames: Sequence[np.ndarray],
    *,
    suffix: str = ".png",
    names: Sequence[str] | None = None,
    sidecars: dict[str, str] | None = None,
    compression: int = zipfile.ZIP_STORED,
) -> Path:
    names = names or [f"frame{i}{suffix}" for i in range(len(frames))]
    with zipfile.ZipFile(path, "w", compression=compression) as archive:
        for name, frame in zip(names, frames, strict=True):
            archive.writestr(name, encode(frame, Path(name).suffix))
        for name, text in (sidecars or {}).items():
            archive.writestr(name, text)
    return path


def write_tiff_stack(path: Path, frames: Sequence[np.ndarray]) -> Path:
    with tifffile.TiffWriter(path) as tiff:
        for frame in frames:
            tiff.write(frame, photometric="rgb" if frame.ndim == 3 else "minisblack", contiguous=False)
    return path


def write_video(path: Path, frames: Sequence[np.ndarray], *, fps: float = 25.0) -> Path:
    fourcc = cv2.VideoWriter_fourcc(*("MJPG" if path.suffix == ".avi" else "mp4v"))
    height, width = frames[0].shape[:2]
    writer = cv2.VideoWriter(str(path), fourcc, fps, (width, height), frames[0].ndim == 3)
    assert writer.isOpened(), f"OpenCV cannot write {path.suffix}"
    for frame in frames:
        writer.write(frame)
    writer.release()
    return path


CINE_SETUP_BYTES = 7240  # SETUP as Phantom software 7xx writes it (all fields up to cine_name)
CINE_TRIGGER_TIME_S = 1_700_000_000.25  # an arbitrary trigger time (s since 1970), exact in TIME64


def time64(seconds: float) -> int:
    """Phantom TIME64: whole seconds in the high 32 bits, the fraction of a second in the low 32 bits."""
    whole = int(seconds // 1)
    return (whole << 32) + round((seconds - whole) * 2**32)


def pack_bits(frame: np.ndarray, bits: int) -> bytes:
    """Big-endian bit stream of `bits`-bit pixels (P10: 4 pixels in 5 bytes, P12L: 2 in 3), as Phantom packs."""
    values = frame.astype(np.uint64).ravel()
    group = 4 if bits == 10 else 2
    words = np.zeros(len(values) // group, dtype=np.uint64)
    for k in range(group):
        words = (words << np.uint64(bits)) | values[k::group]
    n_bytes = bits * group // 8
    out = np.zeros((len(words), n_bytes), dtype=np.uint8)
    for k in range(n_bytes):
        out[:, k] = (words >> np.uint64(8 * (n_bytes - 1 - k))) & np.uint64(0xFF)
    return out.tobytes()


def write_cine(
    path: Path,
    frames: Sequence[np.ndarray],
    *,
    fps: int = 5000,
    real_bpp: int | None = None,
    packing: str = "",
    first_image_no: int = 0,
    time_stamps: bool = True,
    jitter_s: float = 0.0,
    compression: int = 0,
    stamp_fps: float | None = None,
) -> Path:
    """A Phantom .cine laid out as a camera writes it: CINEFILEHEADER, BITMAPINFOHEADER, a full SETUP, tagged
    blocks (1002 frame time stamps, 1003 exposures), the frame offsets, then per frame an annotation block
    (size, annotation bytes, image size) and the image.

    Unpacked frames are stored bottom-up as Phantom writes them; colour frames (rows, cols, 3) as BGR, 24 or 48
    bits; packed frames ("P10", "P12L"; uint16 frames of 10/12-bit values) top-down as a bit stream.
    first_image_no: the camera's number of the first stored frame (trigger frame 0). Frame i is stamped at
    trigger + (first_image_no + i) / fps + jitter_s * (i % 3 - 1); at stamp_fps instead of fps where given (a
    header whose rate disagrees with its stamps).
    """
    frame0 = frames[0]
    height, width = frame0.shape[:2]
    channels = 3 if frame0.ndim == 3 else 1
    bits = {"": 0, "P10": 10, "P12L": 12}[packing]
    depth = 16 if frame0.dtype == np.uint16 else 8
    bit_count = depth * channels
    bi_compression = {"": 0, "P10": 256, "P12L": 1024}[packing]
    frame_bytes = width * height * bits // 8 if bits else width * height * channels * depth // 8
    setup = bytearray(CINE_SETUP_BYTES)
    struct.pack_into("<H", setup, 0, min(fps, 65535))
    struct.pack_into("<H", setup, 142, len(setup))
    struct.pack_into("<I", setup, 768, fps)
    struct.pack_into("<I", setup, 800, 780)  # software version: every SETUP field present
    struct.pack_into("<I", setup, 896, real_bpp or bits or depth)
    n = len(frames)
    after_trigger_s = (first_image_no + np.arange(n)) / (stamp_fps or fps) + jitter_s * (np.arange(n) % 3 - 1)
    blocks = b""
    if time_stamps:
        ticks = [time64(CINE_TRIGGER_TIME_S) + round(t * 2**32) for t in after_trigger_s]
        stamps = np.asarray(ticks, dtype="<u8").tobytes()
        exposures = np.full(n, int(0.5 / fps * 2**32), dtype="<u4").tobytes()
        blocks += struct.pack("<IHH", 8 + len(stamps), 1002, 1) + stamps
        blocks += struct.pack("<IHH", 8 + len(exposures), 1003, 0) + exposures
    off_bitmap, off_setup = 44, 84
    off_offsets = off_setup + len(setup) + len(blocks)
    first_image = off_offsets + 8 * n
    annotation = b"\x00" * 16  # a camera's annotation bytes (content unused)
    block = 4 + len(annotation) + 4
    offsets = [first_image + i * (block + frame_bytes) for i in range(n)]
    with path.open("wb") as out:
        out.write(struct.pack("<2sHHHiIiIIIIQ", b"CI", 44, compression, 1, first_image_no, n, first_image_no, n,
                              off_bitmap, off_setup, off_offsets, time64(CINE_TRIGGER_TIME_S)))  # fmt: skip
        out.write(struct.pack("<IiiHHIIiiII", 40, width, height, 1, bit_count, bi_compression, frame_bytes, 0, 0, 0, 0))
        out.write(setup)
        out.write(blocks)
        out.write(np.asarray(offsets, dtype="<u8").tobytes())
        for frame in frames:
            out.write(struct.pack("<I", block) + annotation + struct.pack("<I", frame_bytes))
            if bits:
                out.write(pack_bits(frame, bits))
            else:
                out.write(np.ascontiguousarray(frame[::-1]).astype(frame.dtype.newbyteorder("<")).tobytes())
    return path


def write_mraw(
    path: Path,
    frames: Sequence[np.ndarray],
    *,
    bits: int,
    fps: float = 50000,
    start_frame: int = 0,
    header: str = "cih",
    effective_bits: int | None = None,
    colour: str = "Mono",
    camera: str | None = None,
    save_step: int = 1,
    trigger_mode: str = "Start",
    fields: dict[str, object] | None = None,
) -> Path:
    """A Photron MRAW as the camera software saves it: `<stem>.mraw` (frames back to back: 8-bit, 12-bit packed
    big-endian 2 pixels in 3 bytes, or 16-bit little-endian) and `<stem>.cih` (text, PFV 3) or `<stem>.cihx` (binary
    preamble + XML, PFV 4). Returns the header path. save_step: PFV's Save Step (.cihx frameInfo/skipFrame and
    basicInfo/skipFrame); fields: further or replaced `.cih` lines."""
    height, width = frames[0].shape
    with path.with_suffix(".mraw").open("wb") as out:
        for frame in frames:
            if bits == 12:
                out.write(pack_bits(frame, 12))
            else:
                out.write(frame.astype(np.uint8 if bits == 8 else "<u2").tobytes())
    effective = effective_bits or bits
    if header == "cih":
        lines = {"Date": "2026/11/23", "Camera Type": camera or "FASTCAM SA-Z type 2100K-M-64GB",
                 "Record Rate(fps)": f"{fps:g}", "Shutter Speed(s)": "1/100000", "Trigger Mode": trigger_mode,
                 "Original Total Frame": len(frames) * save_step, "Save Step": save_step, "Total Frame": len(frames),
                 "Start Frame": start_frame, "Correct Trigger Frame": 0, "Image Width": width, "Image Height": height,
                 "Color Type": colour, "Color Bit": bits, "File Format": "MRaw", "EffectiveBit Depth": effective,
                 "EffectiveBit Side": "Lower", "Comment Text": "", "Edge Enhance": "Off", **(fields or {})}  # fmt: skip
        text = "#Camera Information Header\n" + "".join(f"{k} : {v}\n" for k, v in lines.items()) + "\nEND\n"
        target = path.with_suffix(".cih")
        target.write_bytes(text.encode("ascii"))
        return target
    xml = f"""<cih>
<fileInfo><date>2026/11/23</date><time>04:40</time></fileInfo>
<deviceInfo><deviceName>{camera or "FASTCAM Nova S12 type 1000K-M-32GB"}</deviceName></deviceInfo>
<recordInfo><recordRate>{fps:g}</recordRate><shutterSpeed>0.00001</shutterSpeed>
<triggerMode>{trigger_mode}</triggerMode></recordInfo>
<frameInfo><recordedFrame>{len(frames) * save_step}</recordedFrame><totalFrame>{len(frames)}</totalFrame>
<startFrame>{start_frame}</startFrame><skipFrame>{save_step}</skipFrame></frameInfo>
<imageDataInfo><resolution><width>{width}</width><height>{height}</height></resolution>
<colorInfo><type>{colour}</type><bit>{bits}</bit></colorInfo>
<effectiveBit><depth>{effective}</depth><side>Lower</side></effectiveBit></imageDataInfo>
<imageFileInfo><fileFormat>MRaw</fileFormat></imageFileInfo>
<basicInfo><skipFrame>{save_step}</skipFrame><comment>test</comment></basicInfo>
</cih>
"""
    target = path.with_suffix(".cihx")
    target.write_bytes(b"\x00\x01\x02\x03cihx binary preamble\n" + xml.encode("utf-8"))
    return target


def write_mraw_zip(path: Path, frames: Sequence[np.ndarray], *, bits: int, **options: object) -> Path:
    """A Photron recording as one upload: its .cih and .mraw stored (uncompressed) in a ZIP."""
    folder = path.parent / f"{path.stem}_mraw"
    folder.mkdir(exist_ok=True)
    header = write_mraw(folder / "shot", frames, bits=bits, **options)  # type: ignore[arg-type]
    with zipfile.ZipFile(path, "w", zipfile.ZIP_STORED) as archive:
        archive.write(header, header.name)
        archive.write(header.with_suffix(".mraw"), "shot.mraw")
    return path


def _zeros_deflated(size: int) -> bytes:
    """`size` zero bytes, zlib-compressed, made in chunks (never `size` bytes in memory): ~1/1000 of the size."""
    import zlib

    packer = zlib.compressobj(9)
    chunk = bytes(1 << 22)
    parts = [packer.compress(chunk) for _ in range(size // len(chunk))]
    parts.append(packer.compress(bytes(size % len(chunk))))
    return b"".join(parts) + packer.flush()


def deflated_tiff_bomb(width: int, height: int, *, samples: int = 3, bits: int = 16, ifd_last: bool = True) -> bytes:
    """A TIFF of one strip, deflate-compressed (TIFF compression 8), of `width` × `height` px of `samples` ×
    `bits`: a few kB to MB on disk that decode to width × height × samples × bits / 8 bytes. `ifd_last`: the
    directory after the pixels (where most writers put it), so that a reader must seek to find the size."""
    strip = _zeros_deflated(width * height * samples * bits // 8)
    photometric = 2 if samples >= 3 else 1
    tags = [(256, 4, 1, width), (257, 4, 1, height), (258, 3, 1, bits), (259, 3, 1, 8), (262, 3, 1, photometric),
            (273, 4, 1, 0), (277, 3, 1, samples), (278, 4, 1, height), (279, 4, 1, len(strip))]  # fmt: skip
    ifd_offset = 8 + len(strip) if ifd_last else 8
    strip_offset = 8 if ifd_last else 8 + 2 + 12 * len(tags) + 4
    if ifd_last and (8 + len(strip)) % 2:
        strip += b"\x00"
        ifd_offset += 1
    entries = b"".join(
        struct.pack("<HHII", tag, kind, count, strip_offset if tag == 273 else value)
        if kind == 4
        else struct.pack("<HHIHH", tag, kind, count, value, 0)
        for tag, kind, count, value in tags
    )
    ifd = struct.pack("<H", len(tags)) + entries + struct.pack("<I", 0)
    header = b"II*\x00" + struct.pack("<I", ifd_offset)
    return header + strip + ifd if ifd_last else header + ifd + strip


def png_bomb(width: int, height: int, *, bits: int = 16, colour_type: int = 6) -> bytes:
    """A PNG of `width` × `height` px (16-bit RGBA by default) whose rows are all zero: ~1/1000 of its decoded
    size on disk."""
    import zlib

    channels = {0: 1, 2: 3, 4: 2, 6: 4}[colour_type]
    row = b"\x00" * (1 + width * channels * bits // 8)  # filter byte + zero samples
    packer = zlib.compressobj(9)
    parts, rows_per_chunk = [], max(1, (1 << 22) // len(row))
    for start in range(0, height, rows_per_chunk):
        parts.append(packer.compress(row * min(rows_per_chunk, height - start)))
    data = b"".join(parts) + packer.flush()

    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    ihdr = struct.pack(">IIBBBBB", width, height, bits, colour_type, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", data) + chunk(b"IEND", b"")
