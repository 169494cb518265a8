"""A Photron MRAW recording's .cih/.cihx header and its .mraw checked against each other, without decoding a pixel.

- `read_mraw_header(path)`: 8-, 12- and 16-bit mono, named by its .cih, .cihx or .mraw file; `mraw_header_from`
  the same from a header's bytes (a ZIP's entry: `container_zip.mraw_header_in_zip`); `unpack_mraw_pixels` turns
  one stored frame into an array.

Not here: reading frames one by one (`recordings`), the list of formats (`containers`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path, PurePath

import numpy as np

from fringelab.formats.container_common import CorruptRecording, UnsupportedRecording, unpack_12bit_big_endian

MRAW_HEADER_SUFFIXES = (".cihx", ".cih")
_MAX_CIH_BYTES = 4 << 20


@dataclass(frozen=True)
class MrawHeader:
    """What a reader needs of a Photron MRAW recording (the .mraw data and its .cih/.cihx header).

    bits: bits a stored pixel takes (8, 12 packed big-endian 2 pixels in 3 bytes, or 16 little-endian).
    effective_bits: significant bits of a pixel (the camera's sensor depth). start_frame: the camera's number of
    the first stored frame (the trigger frame is 0). data_path: the .mraw file.
    """

    width_px: int
    height_px: int
    frame_count: int
    bits: int
    effective_bits: int
    frame_rate_hz: float | None
    start_frame: int
    data_path: Path
    header_path: PurePath  # a file, or the entry name of a header inside a ZIP
    data_offset: int = 0  # where the frames start in data_path (non-zero for an .mraw stored inside a ZIP)

    @property
    def frame_bytes(self) -> int:
        return self.width_px * self.height_px * self.bits // 8

    @property
    def frame_numbers(self) -> np.ndarray:
        return np.arange(self.frame_count, dtype=np.int64) + self.start_frame


def mraw_paths(path: str | Path) -> tuple[Path, Path]:
    """(header, data) paths of an MRAW recording named by its .cih, .cihx or .mraw file (same stem, same folder)."""
    path = Path(path)
    data = path.with_suffix(".mraw")
    if path.suffix.lower() in MRAW_HEADER_SUFFIXES:
        return path, data
    for suffix in MRAW_HEADER_SUFFIXES:
        for candidate in (path.with_suffix(suffix), path.with_suffix(suffix.upper())):
            if candidate.is_file():
                return candidate, path
    raise UnsupportedRecording(f"{path.name}: a Photron .mraw needs its .cihx or .cih header beside it (same name)")


def _cih_fields(path: PurePath, data: bytes) -> dict[str, str]:
    """The header as {key: text}: `Key : Value` lines of a .cih, or the XML of a .cihx, under the .cih names."""
    if len(data) > _MAX_CIH_BYTES:
        raise CorruptRecording(f"{path.name}: larger than {_MAX_CIH_BYTES} bytes; not a Photron header")
    if path.suffix.lower() == ".cih":
        fields: dict[str, str] = {}
        for line in data.decode("latin-1").splitlines():
            key, sep, value = line.partition(" : ")
            if sep:
                fields[key.strip()] = value.strip()
        return fields
    start, stop = data.find(b"<cih>"), data.rfind(b"</cih>")
    if start < 0 or stop < 0:
        raise CorruptRecording(f"{path.name}: no <cih> document in the .cihx (truncated or damaged)")
    import xml.etree.ElementTree as ElementTree

    try:
        root = ElementTree.fromstring(data[start : stop + len(b"</cih>")])
    except ElementTree.ParseError as error:
        raise CorruptRecording(f"{path.name}: the .cihx XML is damaged ({error})") from None
    where = {
        "Record Rate(fps)": "recordInfo/recordRate",
        "Total Frame": "frameInfo/totalFrame",
        "Start Frame": "frameInfo/startFrame",
        "Image Width": "imageDataInfo/resolution/width",
        "Image Height": "imageDataInfo/resolution/height",
        "Color Type": "imageDataInfo/colorInfo/type",
        "Color Bit": "imageDataInfo/colorInfo/bit",
        "EffectiveBit Depth": "imageDataInfo/effectiveBit/depth",
        "EffectiveBit Side": "imageDataInfo/effectiveBit/side",
        "File Format": "imageFileInfo/fileFormat",
    }
    return {key: (root.findtext(xpath) or "").strip() for key, xpath in where.items() if root.find(xpath) is not None}


def read_mraw_header(path: str | Path) -> MrawHeader:
    """Parse a Photron .cih/.cihx header and check its .mraw against it (a truncated .mraw is refused here).

    path: the .cih, .cihx or .mraw file. Refuses colour (raw Bayer) recordings and bit depths other than 8, 12
    and 16, naming what the header says.
    """
    header_path, data_path = mraw_paths(path)
    if not header_path.is_file():
        raise UnsupportedRecording(f"{header_path.name}: the Photron header is missing")
    if not data_path.is_file():
        raise CorruptRecording(f"{header_path.name}: its data file {data_path.name} is missing")
    if header_path.stat().st_size > _MAX_CIH_BYTES:
        raise CorruptRecording(f"{header_path.name}: larger than {_MAX_CIH_BYTES} bytes; not a Photron header")
    return mraw_header_from(
        header_path, header_path.read_bytes(), data_path=data_path, data_name=data_path.name,
        data_offset=0, data_bytes=data_path.stat().st_size,
    )  # fmt: skip


def mraw_header_from(
    header_path: PurePath,
    header_bytes: bytes,
    *,
    data_path: Path,
    data_name: str,
    data_offset: int,
    data_bytes: int,
) -> MrawHeader:
    """An MRAW header from the header file's bytes, checked against the span of the data it describes
    (data_bytes from data_offset in data_path: a whole .mraw, or a stored .mraw entry of a ZIP)."""
    fields = _cih_fields(header_path, header_bytes)
    name = header_path.name

    def number(key: str, *, required: bool = True) -> float | None:
        text = fields.get(key, "")
        if not text:
            if required:
                raise CorruptRecording(f"{name}: no '{key}' in the header (truncated or damaged)")
            return None
        try:
            return float(text)
        except ValueError:
            raise CorruptRecording(f"{name}: '{key}' is {text!r}, not a number") from None

    file_format = fields.get("File Format", "MRaw")
    if file_format.lower() != "mraw":
        raise UnsupportedRecording(f"{name}: the header describes a {file_format!r} recording, not MRaw")
    colour = fields.get("Color Type", "Mono")
    if colour.lower() not in ("mono", ""):
        raise UnsupportedRecording(
            f"{name}: a {colour} (raw Bayer) MRAW cannot be measured; record or save in monochrome"
        )
    width, height, count = (int(number(k) or 0) for k in ("Image Width", "Image Height", "Total Frame"))
    bits = int(number("Color Bit") or 0)
    if bits not in (8, 12, 16):
        raise UnsupportedRecording(f"{name}: {bits}-bit pixels; fringelab reads 8-, 12- and 16-bit MRAW")
    if width <= 0 or height <= 0 or count <= 0:
        raise CorruptRecording(f"{name}: {width} × {height} px, {count} frames")
    effective = int(number("EffectiveBit Depth", required=False) or bits)
    if fields.get("EffectiveBit Side", "Lower").lower() == "higher":
        effective = bits  # the significant bits sit at the top: the values span the full range
    header = MrawHeader(
        width_px=width,
        height_px=height,
        frame_count=count,
        bits=bits,
        effective_bits=min(effective, bits),
        frame_rate_hz=number("Record Rate(fps)", required=False) or None,
        start_frame=int(number("Start Frame", required=False) or 0),
        data_path=data_path,
        header_path=header_path,
        data_offset=data_offset,
    )
    size, expected = data_bytes, header.frame_bytes * count
    if size < expected:
        raise CorruptRecording(
            f"{data_name}: {size} bytes, but {count} frames of {width} × {height} px at {bits} bits need "
            f"{expected}; the .mraw is truncated"
        )
    if size > expected:
        raise CorruptRecording(
            f"{data_name}: {size} bytes, more than the {expected} its header describes; the header does not "
            "belong to this .mraw"
        )
    return header


def unpack_mraw_pixels(data: bytes, header: MrawHeader) -> np.ndarray:
    """One MRAW frame's bytes as a (rows, cols) array: uint8, or uint16 for 12-bit (unpacked) and 16-bit data."""
    shape = (header.height_px, header.width_px)
    if header.bits == 8:
        return np.frombuffer(data, dtype=np.uint8).reshape(shape).copy()
    if header.bits == 16:
        return np.frombuffer(data, dtype="<u2").reshape(shape).astype(np.uint16)
    return unpack_12bit_big_endian(data).reshape(shape)
