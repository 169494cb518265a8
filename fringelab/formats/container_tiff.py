"""A (multi-page) TIFF's page chain, checked against the file size without decoding a pixel.

- `read_tiff_layout(path)`: every IFD and every strip or tile checked against the file size (a truncated TIFF is
  refused, not read as its first pages), and the pages' count, size and sample depth.

Not here: decoding pages (`recordings`), the list of formats (`containers`).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

from fringelab.formats.container_common import CorruptRecording, UnsupportedRecording, read_at

MAX_TIFF_PAGES = 1_000_000
_TIFF_TYPE_SIZES = {1: 1, 3: 2, 4: 4, 13: 4, 16: 8}  # the integer types _TIFF_INT_CODES reads
_TIFF_INT_CODES = {1: "B", 3: "H", 4: "I", 13: "I", 16: "Q"}
_TAG_WIDTH, _TAG_HEIGHT, _TAG_BITS, _TAG_SAMPLES = 256, 257, 258, 277
_TAG_STRIP_OFFSETS, _TAG_STRIP_BYTES, _TAG_TILE_OFFSETS, _TAG_TILE_BYTES = 273, 279, 324, 325


@dataclass(frozen=True)
class TiffLayout:
    """What the IFD chain of a TIFF says: pages and the size and sample depth of the first."""

    frame_count: int
    width_px: int
    height_px: int
    bytes_per_sample: int


def read_tiff_layout(path: str | Path) -> TiffLayout:
    """Walk the IFD chain of a classic or Big TIFF; refuse a chain or strip that runs past the end of the file.

    A truncated multi-page TIFF still opens (its first pages are whole), so the chain itself is the only
    witness: an IFD offset, or a strip's offset + byte count, beyond the file size means bytes are missing.
    """
    path = Path(path)
    size = path.stat().st_size
    with path.open("rb") as handle:
        head = handle.read(16)
        order = "<" if head[:2] == b"II" else ">"
        if len(head) < 8 or head[:2] not in (b"II", b"MM"):
            raise CorruptRecording(f"{path.name}: shorter than a TIFF header")
        version = struct.unpack_from(order + "H", head, 2)[0]
        big = version == 43
        if big and len(head) < 16:
            raise CorruptRecording(f"{path.name}: shorter than a BigTIFF header")
        count_code, offset_code, entry_size = ("Q", "Q", 20) if big else ("H", "I", 12)
        offset_size = 8 if big else 4
        next_ifd = struct.unpack_from(order + offset_code, head, 8 if big else 4)[0]
        pages = 0
        first: dict[int, list[int]] = {}
        seen: set[int] = set()
        while next_ifd:
            if next_ifd in seen:
                raise CorruptRecording(f"{path.name}: the TIFF's page chain loops back to offset {next_ifd}")
            seen.add(next_ifd)
            if pages >= MAX_TIFF_PAGES:
                raise UnsupportedRecording(f"{path.name}: more than {MAX_TIFF_PAGES} pages")
            count_bytes = struct.calcsize(count_code)
            if next_ifd + count_bytes > size:
                raise CorruptRecording(
                    f"{path.name}: page {pages + 1} starts past the end of the file ({size} bytes); the TIFF is "
                    f"truncated after {pages} pages"
                )
            entry_count = struct.unpack(order + count_code, read_at(handle, next_ifd, count_bytes))[0]
            table_end = next_ifd + count_bytes + entry_count * entry_size + offset_size
            if table_end > size:
                raise CorruptRecording(
                    f"{path.name}: the directory of page {pages + 1} runs past the end of the file; the TIFF is "
                    f"truncated after {pages} pages"
                )
            table = read_at(handle, next_ifd + count_bytes, entry_count * entry_size + offset_size)
            tags = _tiff_tags(handle, table, entry_count, order=order, big=big, size=size, name=path.name)
            _check_tiff_data(tags, page=pages, size=size, name=path.name)
            if pages == 0:
                first = tags
            pages += 1
            next_ifd = struct.unpack_from(order + offset_code, table, entry_count * entry_size)[0]
    if pages == 0 or _TAG_WIDTH not in first or _TAG_HEIGHT not in first:
        raise CorruptRecording(f"{path.name}: the TIFF has no readable page")
    bits = max(first.get(_TAG_BITS, [8]))
    samples = first.get(_TAG_SAMPLES, [1])[0]
    return TiffLayout(pages, first[_TAG_WIDTH][0], first[_TAG_HEIGHT][0], max(1, bits // 8) * max(1, samples))


def read_first_page_tags(handle: BinaryIO, *, size: int, name: str = "the TIFF") -> dict[int, list[int]]:
    """The integer tags (size, depth, strips) of a TIFF's first page from a seekable `handle` of `size` bytes,
    without reading its pixels (`frame_header` reads a frame's size from them before it is decoded)."""
    head = read_at(handle, 0, 16)
    if len(head) < 8 or head[:2] not in (b"II", b"MM"):
        raise CorruptRecording(f"{name}: shorter than a TIFF header")
    order = "<" if head[:2] == b"II" else ">"
    big = struct.unpack_from(order + "H", head, 2)[0] == 43
    if big and len(head) < 16:
        raise CorruptRecording(f"{name}: shorter than a BigTIFF header")
    count_code, offset_code, entry_size = ("Q", "Q", 20) if big else ("H", "I", 12)
    first_ifd = struct.unpack_from(order + offset_code, head, 8 if big else 4)[0]
    count_bytes = struct.calcsize(count_code)
    if not first_ifd or first_ifd + count_bytes > size:
        raise CorruptRecording(f"{name}: its first page lies past the end of the file")
    entry_count = struct.unpack(order + count_code, read_at(handle, first_ifd, count_bytes))[0]
    table_length = entry_count * entry_size
    if first_ifd + count_bytes + table_length > size:
        raise CorruptRecording(f"{name}: the directory of its first page runs past the end of the file")
    table = read_at(handle, first_ifd + count_bytes, table_length)
    return _tiff_tags(handle, table, entry_count, order=order, big=big, size=size, name=name)


def _tiff_tags(
    handle: BinaryIO, table: bytes, entry_count: int, *, order: str, big: bool, size: int, name: str
) -> dict[int, list[int]]:
    """The integer tags a layout needs (size, depth, strips and tiles) of one IFD."""
    wanted = (_TAG_WIDTH, _TAG_HEIGHT, _TAG_BITS, _TAG_SAMPLES, _TAG_STRIP_OFFSETS, _TAG_STRIP_BYTES,
              _TAG_TILE_OFFSETS, _TAG_TILE_BYTES)  # fmt: skip
    entry = struct.Struct(order + ("HHQ8s" if big else "HHI4s"))
    inline = 8 if big else 4
    tags: dict[int, list[int]] = {}
    for i in range(entry_count):
        tag, kind, count, value = entry.unpack_from(table, i * entry.size)
        if tag not in wanted or kind not in _TIFF_INT_CODES:
            continue
        length = count * _TIFF_TYPE_SIZES[kind]
        if length > inline:
            offset = struct.unpack(order + ("Q" if big else "I"), value)[0]
            if offset + length > size:
                raise CorruptRecording(f"{name}: tag {tag} lies past the end of the file; the TIFF is truncated")
            value = read_at(handle, offset, length)
        tags[tag] = list(struct.unpack_from(f"{order}{count}{_TIFF_INT_CODES[kind]}", value))
    return tags


def _check_tiff_data(tags: dict[int, list[int]], *, page: int, size: int, name: str) -> None:
    for offsets_tag, counts_tag in ((_TAG_STRIP_OFFSETS, _TAG_STRIP_BYTES), (_TAG_TILE_OFFSETS, _TAG_TILE_BYTES)):
        for offset, length in zip(tags.get(offsets_tag, []), tags.get(counts_tag, []), strict=False):
            if offset + length > size:
                raise CorruptRecording(
                    f"{name}: the pixels of page {page + 1} run past the end of the file ({size} bytes); the TIFF "
                    f"is truncated after {page} whole pages"
                )
