"""A Photron MRAW recording's .cih/.cihx header and its .mraw checked against each other.

- `read_mraw_header(path)`: 8-, 12- and 16-bit mono, named by its .cih, .cihx or .mraw file; `mraw_header_from`
  the same from a header's bytes (a ZIP's entry: `container_zip.mraw_header_in_zip`); `unpack_mraw_pixels` turns
  one stored frame into an array.

Every header field that changes the pixels or the time axis is read, and a value not understood is refused by
name: File Format, Color Type and Color Bit, EffectiveBit Depth and Side, Edge Enhance (a sharpened image is no
measurement), Record Rate, Save Step (.cihx `skipFrame`: one stored frame every N recorded ones), Start Frame,
Correct Trigger Frame and Trigger Mode. The camera numbers stored frame k as Start Frame + k × Save Step (the trigger
frame is 0), at time number / Record Rate.

Colour is decided from the camera model and the pixels, not from the header's colour type alone: PFV4 writes
`<colorInfo><type>Raw</type>` for a monochrome camera too. Photron names its monochrome models "…-M…" (e.g.
"FASTCAM Nova S16 type 1100K-M-32GB") and its colour ones "…-C…"; a Raw recording of a model that says neither is
read when its 2 × 2 pixel phases have equal means (no Bayer mosaic), and refused when they differ. Real Bayer data
is refused with what to save instead.

Not here: reading frames one by one (`recordings`), the list of formats (`containers`).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field, replace
from pathlib import Path, PurePath

import numpy as np

from fringelab.formats.container_common import CorruptRecording, UnsupportedRecording, unpack_12bit_big_endian

MRAW_HEADER_SUFFIXES = (".cihx", ".cih")
_MAX_CIH_BYTES = 4 << 20
# Trigger modes whose stored frames are one run numbered from one trigger (Start Frame says where it lies)
_ONE_RUN_TRIGGERS = ("start", "center", "centre", "end", "manual")
# Spread of the 2 × 2 pixel-phase means, relative to their mean, above which Raw data is a Bayer mosaic: a colour
# sensor's green phases see about twice the red and blue ones under white light; a mono sensor's phases agree to
# about 1 % on any scene without a 2-pixel period (the Nova S16: 1350 to 1362).
BAYER_PHASE_SPREAD = 0.05
SAVE_INSTEAD = (
    "in Photron FASTCAM Viewer (PFV) save the recording again as monochrome (Color Type Mono, 8 or 16 bit MRAW, "
    "or 16-bit TIFF); or record with a monochrome camera"
)


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
    save_step: int = 1  # one stored frame every save_step recorded frames (.cih Save Step, .cihx skipFrame)
    trigger_mode: str = ""
    camera_model: str = ""
    notes: tuple[str, ...] = field(default=())

    @property
    def frame_bytes(self) -> int:
        return self.width_px * self.height_px * self.bits // 8

    @property
    def frame_numbers(self) -> np.ndarray:
        """The camera's number of each stored frame (the trigger frame is 0): Start Frame + k × Save Step."""
        return np.arange(self.frame_count, dtype=np.int64) * self.save_step + self.start_frame

    @property
    def frame_times_s(self) -> np.ndarray | None:
        """Each stored frame's time from the trigger in s (frame number / Record Rate), or None without a rate."""
        return None if not self.frame_rate_hz else self.frame_numbers / self.frame_rate_hz


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
        "Camera Type": "deviceInfo/deviceName",
        "Record Rate(fps)": "recordInfo/recordRate",
        "Trigger Mode": "recordInfo/triggerMode",
        "Total Frame": "frameInfo/totalFrame",
        "Start Frame": "frameInfo/startFrame",
        "Save Step": "frameInfo/skipFrame",
        "Correct Trigger Frame": "frameInfo/correctTriggerFrame",
        "Edge Enhance": "imageDataInfo/edgeEnhance",
        "Image Width": "imageDataInfo/resolution/width",
        "Image Height": "imageDataInfo/resolution/height",
        "Color Type": "imageDataInfo/colorInfo/type",
        "Color Bit": "imageDataInfo/colorInfo/bit",
        "EffectiveBit Depth": "imageDataInfo/effectiveBit/depth",
        "EffectiveBit Side": "imageDataInfo/effectiveBit/side",
        "File Format": "imageFileInfo/fileFormat",
    }
    fields = {key: (root.findtext(xpath) or "").strip() for key, xpath in where.items() if root.find(xpath) is not None}
    if "Save Step" not in fields and root.find("basicInfo/skipFrame") is not None:
        fields["Save Step"] = (root.findtext("basicInfo/skipFrame") or "").strip()
    return fields


def camera_colour(model: str) -> str | None:
    """ "mono" or "colour" from a Photron model name ("…-M…": monochrome, "…-C…": colour), None when it does not say.

    >>> camera_colour("FASTCAM Nova S16 type 1100K-M-32GB"), camera_colour("FASTCAM SA5 model 775K-C2")
    ('mono', 'colour')
    """
    match = re.search(r"-([MC])(?:\d|-|$|\s)", model.strip(), re.IGNORECASE)
    if match is None:
        return None
    return "mono" if match.group(1).upper() == "M" else "colour"


def bayer_phase_spread(frame: np.ndarray) -> float:
    """(max − min) / mean of the means of the four 2 × 2 pixel phases of a frame (0 for an even mosaic-free image)."""
    phases = [float(frame[r::2, c::2].mean()) for r in (0, 1) for c in (0, 1)]
    mean = float(np.mean(phases))
    return (max(phases) - min(phases)) / mean if mean > 0 else 0.0


def read_mraw_header(path: str | Path) -> MrawHeader:
    """Parse a Photron .cih/.cihx header and check its .mraw against it (a truncated .mraw is refused here).

    path: the .cih, .cihx or .mraw file. Refuses colour recordings (RGB, or Raw from a colour sensor) and bit
    depths other than 8, 12 and 16, and any field value it does not understand, naming it.
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

    def integer(key: str, default: int) -> int:
        value = number(key, required=False)
        if value is None:
            return default
        if value != int(value):
            raise CorruptRecording(f"{name}: '{key}' is {fields[key]!r}, not a whole number")
        return int(value)

    file_format = fields.get("File Format", "MRaw")
    if file_format.lower() != "mraw":
        raise UnsupportedRecording(f"{name}: the header describes a {file_format!r} recording, not MRaw")
    model = fields.get("Camera Type", "")
    colour_type = fields.get("Color Type", "Mono")
    width, height, count = (int(number(k) or 0) for k in ("Image Width", "Image Height", "Total Frame"))
    bits = int(number("Color Bit") or 0)
    if colour_type.lower() in ("color", "colour", "rgb") or bits in (24, 36, 48):
        raise UnsupportedRecording(
            f"{name}: Color Type {colour_type!r}, {bits}-bit: a colour MRAW cannot be measured; {SAVE_INSTEAD}"
        )
    if colour_type.lower() not in ("mono", "raw", ""):
        raise UnsupportedRecording(f"{name}: Color Type {colour_type!r} is not one fringelab knows (Mono, Raw)")
    if bits not in (8, 12, 16):
        raise UnsupportedRecording(f"{name}: Color Bit {bits}: fringelab reads 8-, 12- and 16-bit MRAW")
    if width <= 0 or height <= 0 or count <= 0:
        raise CorruptRecording(f"{name}: {width} × {height} px, {count} frames")
    effective = integer("EffectiveBit Depth", bits)
    side = fields.get("EffectiveBit Side", "Lower")
    if side.lower() not in ("lower", "higher", ""):
        raise UnsupportedRecording(f"{name}: EffectiveBit Side {side!r} is not one fringelab knows (Lower, Higher)")
    if not 1 <= effective <= bits:
        raise UnsupportedRecording(f"{name}: EffectiveBit Depth {effective} with Color Bit {bits}")
    if side.lower() == "higher":
        effective = bits  # the significant bits sit at the top: the values span the full range
    edge = fields.get("Edge Enhance", "Off")
    if edge.lower() not in ("off", "0", ""):
        raise UnsupportedRecording(
            f"{name}: Edge Enhance {edge!r}: the camera software sharpened the pixels, which moves the stripes' "
            "edges; save the recording again with Edge Enhance Off"
        )
    save_step = integer("Save Step", 1)
    if save_step < 1:
        raise CorruptRecording(f"{name}: Save Step {save_step}; expected 1 or more (one frame saved every N)")
    correct_trigger = integer("Correct Trigger Frame", 0)
    if correct_trigger != 0:
        raise UnsupportedRecording(
            f"{name}: Correct Trigger Frame {correct_trigger}: fringelab does not know how it shifts the frame "
            "numbers; save the recording again from PFV without a trigger correction, or give the frames' times in "
            "frames.csv"
        )
    trigger = fields.get("Trigger Mode", "")
    if trigger and not trigger.lower().startswith(_ONE_RUN_TRIGGERS):
        raise UnsupportedRecording(
            f"{name}: Trigger Mode {trigger!r}: its frames are not one run numbered from one trigger (fringelab "
            "reads Start, Center, End and Manual); save each event as its own recording"
        )
    rate = number("Record Rate(fps)", required=False) or None
    if rate is not None and rate < 0:
        raise CorruptRecording(f"{name}: Record Rate(fps) {rate:g}")
    header = MrawHeader(
        width_px=width,
        height_px=height,
        frame_count=count,
        bits=bits,
        effective_bits=effective,
        frame_rate_hz=rate,
        start_frame=integer("Start Frame", 0),
        data_path=data_path,
        header_path=header_path,
        data_offset=data_offset,
        save_step=save_step,
        trigger_mode=trigger,
        camera_model=model,
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
    if colour_type.lower() == "raw":
        note = _raw_is_mono(header, name, model)
        header = replace(header, notes=(*header.notes, note))
    return header


def _raw_is_mono(header: MrawHeader, name: str, model: str) -> str:
    """Why a Color Type Raw recording is read as mono (the camera model, checked by the pixels), or
    UnsupportedRecording naming what shows it is a Bayer mosaic."""
    said = camera_colour(model)
    if said == "colour":
        raise UnsupportedRecording(
            f"{name}: raw Bayer data from a colour camera ({model}): its pixels are a colour mosaic, not grey "
            f"levels; {SAVE_INSTEAD}"
        )
    spread = 0.0
    with open(header.data_path, "rb") as handle:
        for index in sorted({0, header.frame_count // 2, header.frame_count - 1}):
            handle.seek(header.data_offset + index * header.frame_bytes)
            frame = unpack_mraw_pixels(handle.read(header.frame_bytes), header)
            spread = max(spread, bayer_phase_spread(frame))
    if spread > BAYER_PHASE_SPREAD:
        who = (
            f"camera {model!r} is monochrome by its name, but"
            if said == "mono"
            else "the camera model does not say whether it is colour, and"
        )
        raise UnsupportedRecording(
            f"{name}: Color Type Raw: {who} the 2 × 2 pixel phases differ by {100 * spread:.0f} % (a Bayer mosaic); "
            f"{SAVE_INSTEAD}"
        )
    reason = f"camera {model!r} is monochrome" if said == "mono" else "the camera model does not say"
    return (
        f"Color Type Raw read as mono: {reason}, and the 2 × 2 pixel phases agree within {100 * spread:.1f} % "
        "(no Bayer mosaic)"
    )


def unpack_mraw_pixels(data: bytes, header: MrawHeader) -> np.ndarray:
    """One MRAW frame's bytes as a (rows, cols) array: uint8, or uint16 for 12-bit (unpacked) and 16-bit data."""
    shape = (header.height_px, header.width_px)
    if header.bits == 8:
        return np.frombuffer(data, dtype=np.uint8).reshape(shape).copy()
    if header.bits == 16:
        return np.frombuffer(data, dtype="<u2").reshape(shape).astype(np.uint16)
    return unpack_12bit_big_endian(data).reshape(shape)
