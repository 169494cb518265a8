"""A ZIP (or folder) of frames: its safety and its entries, from the central directory, without decoding a pixel.

- `inspect_zip(path, limits=...)`: frame and sidecar names of a ZIP, refusing path traversal, symbolic links,
  encrypted or exotic entries, truncation and ZIP bombs (total size, per-entry size, compression ratio,
  overlapping entries); a Photron recording stored in a ZIP is found too (`mraw_header_in_zip`).
- `IMAGE_SUFFIXES`, `SIDECAR_NAMES`: what a frame and a sidecar are called, in a ZIP or a folder.

Not here: decoding frames (`recordings`), a frame's size from its header (`frame_header`), parsing sidecars
(`sidecars`), the list of formats (`containers`).
"""

from __future__ import annotations

import re
import stat
import struct
import zipfile
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

from fringelab.formats.container_common import (
    CorruptRecording,
    UnsafeArchive,
    UnsupportedRecording,
    check_sidecar_size,
    read_at,
)
from fringelab.formats.container_mraw import MRAW_HEADER_SUFFIXES, MrawHeader, mraw_header_from
from fringelab.science import natural_key

IMAGE_SUFFIXES = (".png", ".tif", ".tiff", ".bmp", ".jpg", ".jpeg")
SIDECAR_NAMES = ("z.csv", "frames.csv", "board.json")

GiB = 1 << 30
MiB = 1 << 20


@dataclass(frozen=True)
class ZipLimits:
    """Bounds on what a ZIP of frames may expand to; a ZIP beyond any of them is refused as a bomb.

    max_total_bytes: sum of the uncompressed sizes of all entries. max_entry_bytes: one entry (one frame).
    max_ratio: uncompressed / compressed size of one entry over 1 MiB, and of the whole archive once it
    expands to more than 1 MiB (deflate alone cannot pass ~1030, so a higher ratio means bzip2/LZMA tricks; the
    total keeps many entries each just under 1 MiB from passing one by one). max_entries: entries at most.
    """

    max_total_bytes: int = 256 * GiB
    max_entry_bytes: int = 2 * GiB
    max_ratio: float = 200.0
    max_entries: int = 100_000


@dataclass(frozen=True)
class ZipContents:
    frame_names: tuple[str, ...]  # in natural order
    sidecar_names: dict[str, str]  # sidecar base name -> entry name
    uncompressed_bytes: int
    mraw_entries: tuple[str, str] | None = None  # (.cih/.cihx entry, stored .mraw entry): a Photron recording


_SUPPORTED_COMPRESSION = (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED, zipfile.ZIP_BZIP2, zipfile.ZIP_LZMA)
_DRIVE = re.compile(r"^[A-Za-z]:")


def is_junk_entry(name: str) -> bool:
    """Files archivers add that are not frames: macOS resource forks, hidden files."""
    parts = PurePosixPath(name.replace("\\", "/")).parts
    return any(part == "__MACOSX" or part.startswith(".") for part in parts)


def unsafe_entry_reason(info: zipfile.ZipInfo) -> str:
    """Why a ZIP entry must not be trusted, or "" when it is fine."""
    name = info.filename
    if name.startswith(("/", "\\")) or _DRIVE.match(name):
        return f"entry {name!r} has an absolute path"
    if ".." in re.split(r"[\\/]", name):
        return f"entry {name!r} climbs out of the archive with '..'"
    if stat.S_ISLNK(info.external_attr >> 16):
        return f"entry {name!r} is a symbolic link"
    return ""


def inspect_zip(path: str | Path, *, limits: ZipLimits | None = None) -> ZipContents:
    """Check a ZIP of frames from its central directory and list its frames and sidecars.

    Raises UnsafeArchive, CorruptRecording or UnsupportedRecording naming the first offending entry.
    """
    path = Path(path)
    limits = limits or ZipLimits()
    size = path.stat().st_size
    try:
        with zipfile.ZipFile(path) as archive:
            infos = archive.infolist()
    except (zipfile.BadZipFile, zipfile.LargeZipFile, OSError, EOFError) as error:
        raise CorruptRecording(f"{path.name}: not a readable ZIP archive ({error})") from None
    total = check_archive(path.name, infos, limits=limits, size=size)
    frames: list[str] = []
    sidecars: dict[str, str] = {}
    for info in infos:
        if info.is_dir():
            continue
        if is_junk_entry(info.filename):
            continue
        base = PurePosixPath(info.filename).name
        if PurePosixPath(base).suffix.lower() in IMAGE_SUFFIXES:
            frames.append(info.filename)
        elif base in SIDECAR_NAMES:
            try:
                check_sidecar_size(info.file_size, name=info.filename)
            except ValueError as error:
                raise UnsafeArchive(f"{path.name}: {error}; refused") from None
            sidecars.setdefault(base, info.filename)
    if not frames:
        mraw = _mraw_entries(path.name, infos)
        if mraw is not None:
            return ZipContents((), sidecars, total, mraw_entries=mraw)
        raise UnsupportedRecording(
            f"{path.name}: no image frames in the ZIP (accepted: {', '.join(IMAGE_SUFFIXES)}, or a Photron "
            ".cihx/.cih with its .mraw)"
        )
    return ZipContents(tuple(sorted(frames, key=natural_key)), sidecars, total)


def check_archive(name: str, infos: list[zipfile.ZipInfo], *, limits: ZipLimits, size: int) -> int:
    """The one rule for every ZIP fringelab reads or unpacks (recordings and simulations alike), from its central
    directory: no unsafe, encrypted or exotic entry, no more than `limits.max_entries` entries, no entry or whole
    archive over its size or ratio limit, no entry past the end of the file (`size` bytes) and no overlapping
    entries. Raises UnsafeArchive, UnsupportedRecording or CorruptRecording naming the archive (`name`) and the
    entry; returns the bytes all entries expand to."""
    if len(infos) > limits.max_entries:
        raise UnsafeArchive(f"{name}: {len(infos)} entries, more than the {limits.max_entries} a ZIP may hold")
    total = compressed = 0
    for info in infos:
        reason = unsafe_entry_reason(info)
        if reason:
            raise UnsafeArchive(f"{name}: {reason}; refused")
        if info.is_dir():
            continue
        if info.flag_bits & 0x1:
            raise UnsupportedRecording(f"{name}: entry {info.filename!r} is encrypted")
        if info.compress_type not in _SUPPORTED_COMPRESSION:
            raise UnsupportedRecording(
                f"{name}: entry {info.filename!r} uses compression method {info.compress_type}; "
                "use stored, deflate, bzip2 or LZMA"
            )
        if info.file_size > limits.max_entry_bytes:
            raise UnsafeArchive(
                f"{name}: entry {info.filename!r} expands to {info.file_size} bytes, over the "
                f"{limits.max_entry_bytes}-byte limit of one entry"
            )
        if info.file_size > MiB and info.file_size > limits.max_ratio * max(info.compress_size, 1):
            ratio = info.file_size / max(info.compress_size, 1)
            raise UnsafeArchive(
                f"{name}: entry {info.filename!r} expands {ratio:.0f}× (limit {limits.max_ratio:.0f}×); "
                "refused as a ZIP bomb"
            )
        total += info.file_size
        compressed += info.compress_size
        if total > MiB and total > limits.max_ratio * max(compressed, 1):
            raise UnsafeArchive(
                f"{name}: its entries expand {total / max(compressed, 1):.0f}× in total (limit "
                f"{limits.max_ratio:.0f}×); refused as a ZIP bomb"
            )
        if total > limits.max_total_bytes:
            raise UnsafeArchive(
                f"{name}: expands to more than {limits.max_total_bytes} bytes in total; refused as a ZIP bomb"
            )
        if info.header_offset + info.compress_size > size:
            raise CorruptRecording(f"{name}: entry {info.filename!r} runs past the end of the file (truncated)")
    _refuse_overlapping_entries(name, infos)
    return total


def _mraw_entries(name: str, infos: list[zipfile.ZipInfo]) -> tuple[str, str] | None:
    """(header, data) entries of a Photron recording in a ZIP: one .mraw, stored (not compressed) so frames are
    read at their offsets, and its .cihx or .cih of the same stem."""
    data = [i for i in infos if not i.is_dir() and not is_junk_entry(i.filename)
            and i.filename.lower().endswith(".mraw")]  # fmt: skip
    if len(data) != 1:
        return None
    if data[0].compress_type != zipfile.ZIP_STORED:
        raise UnsupportedRecording(
            f"{name}: {data[0].filename} is compressed in the ZIP; store it uncompressed (zip -0) so its frames "
            "can be read where they lie"
        )
    stem = data[0].filename[: -len(".mraw")]
    by_name = {i.filename.lower(): i.filename for i in infos}
    for suffix in MRAW_HEADER_SUFFIXES:
        header = by_name.get((stem + suffix).lower())
        if header is not None:
            return header, data[0].filename
    raise UnsupportedRecording(f"{name}: {data[0].filename} has no .cihx or .cih of the same name in the ZIP")


def zip_entry_data_offset(path: Path, info: zipfile.ZipInfo) -> int:
    """Where a stored entry's bytes start in the ZIP file (after its local header, name and extra field)."""
    with path.open("rb") as handle:
        local = read_at(handle, info.header_offset, 30)
    if len(local) < 30 or local[:4] != b"PK\x03\x04":
        raise CorruptRecording(f"{path.name}: entry {info.filename!r} has no local header (damaged)")
    name_length, extra_length = struct.unpack_from("<HH", local, 26)
    return info.header_offset + 30 + name_length + extra_length


def _refuse_overlapping_entries(name: str, infos: list[zipfile.ZipInfo]) -> None:
    """Entries whose data overlap are the trick of non-recursive ZIP bombs (one compressed stream, many names)."""
    ordered = sorted((i for i in infos if not i.is_dir()), key=lambda i: i.header_offset)
    for previous, current in zip(ordered, ordered[1:], strict=False):
        if current.header_offset < previous.header_offset + 30 + previous.compress_size:
            raise UnsafeArchive(
                f"{name}: entries {previous.filename!r} and {current.filename!r} overlap; refused as a ZIP bomb"
            )


def mraw_header_in_zip(path: Path, entries: tuple[str, str]) -> MrawHeader:
    """The header of a Photron recording uploaded as one ZIP (`ZipContents.mraw_entries`), checked against the
    stored .mraw entry, whose frames are read where they lie in the ZIP file."""
    header_name, data_name = entries
    with zipfile.ZipFile(path) as archive:
        header_bytes = archive.read(header_name)
        data_info = archive.getinfo(data_name)
    return mraw_header_from(
        PurePosixPath(header_name), header_bytes, data_path=path, data_name=data_name,
        data_offset=zip_entry_data_offset(path, data_info), data_bytes=data_info.file_size,
    )  # fmt: skip
