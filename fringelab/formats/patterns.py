"""The `patterns.json` sidecar of a coded sequence: its one parser and writer (docs/file-formats.md "patterns.json").

Belongs here: turning the sidecar's text into a `graycode.PatternSequence`, with errors that name the file and the
key, and checking its frame numbers against the recording's frame count; writing the same document back. Not here:
what the sequence means (`science/graycode.py`).

Document (frames numbered from 0 in the recording's order):
  {"axis": "columns" | "rows", "projector_size_px": [width, height], "gray_frames": [...] (most significant first),
   "band_px": projector pixels per code value,
   "threshold": {"white": i, "black": j} | {"inverse_frames": [...]} | {"mean_of": [...]},
   "phase": {"frames": [...], "period_px": p, "offset_px": x (optional)} (optional)}
"""

from __future__ import annotations

import json
import math
from typing import Any

from fringelab.science.graycode import (
    CODE_AXES,
    InverseFrames,
    MeanOf,
    PatternSequence,
    PhaseFrames,
    WhiteBlack,
)

PATTERNS_JSON = "patterns.json"
PATTERNS_EXAMPLE = (
    '{"axis": "columns", "projector_size_px": [1824, 1140], "gray_frames": [2, 3, 4, 5], "band_px": 2.0, '
    '"threshold": {"white": 0, "black": 1}}'
)
_KEYS = {"axis", "projector_size_px", "gray_frames", "band_px", "threshold", "phase"}


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def _frames(value: Any, *, name: str, key: str, at_least: int = 1) -> tuple[int, ...]:
    if not (isinstance(value, list) and len(value) >= at_least and all(_is_int(v) and v >= 0 for v in value)):
        raise ValueError(f"{name}: {key} must be a list of at least {at_least} frame numbers ≥ 0, got {value!r}")
    return tuple(value)


def read_patterns_json(text: str, *, name: str = PATTERNS_JSON, n_frames: int | None = None) -> PatternSequence:
    """Parse a patterns.json; with `n_frames`, every frame it names must be in the recording (0..n_frames − 1).
    ValueError naming the file and the key otherwise."""
    try:
        raw = json.loads(text, parse_constant=lambda constant: (_ for _ in ()).throw(ValueError(constant)))
    except ValueError as error:
        raise ValueError(f"{name}: not valid JSON ({error})") from None
    if not isinstance(raw, dict):
        raise ValueError(f"{name}: expected a JSON object like {PATTERNS_EXAMPLE}")
    missing = [key for key in ("axis", "projector_size_px", "gray_frames", "band_px", "threshold") if key not in raw]
    if missing:
        raise ValueError(f"{name}: missing {', '.join(missing)} (expected e.g. {PATTERNS_EXAMPLE})")
    unknown = sorted(set(raw) - _KEYS)
    if unknown:
        raise ValueError(f"{name}: unknown keys {unknown} (known: {sorted(_KEYS)})")
    axis = raw["axis"]
    if axis not in CODE_AXES:
        raise ValueError(f"{name}: axis must be one of {list(CODE_AXES)}, got {axis!r}")
    size = raw["projector_size_px"]
    if not (isinstance(size, list) and len(size) == 2 and all(_is_int(v) and v >= 1 for v in size)):
        raise ValueError(f"{name}: projector_size_px must be [width, height] in pixels, got {size!r}")
    gray = _frames(raw["gray_frames"], name=name, key="gray_frames")
    band = raw["band_px"]
    if not (_is_number(band) and band > 0):
        raise ValueError(f"{name}: band_px must be a positive number of projector pixels, got {band!r}")
    threshold_raw = raw["threshold"]
    threshold: WhiteBlack | InverseFrames | MeanOf
    if not isinstance(threshold_raw, dict) or len(threshold_raw) == 0:
        raise ValueError(
            f'{name}: threshold must be {{"white": i, "black": j}}, {{"inverse_frames": [...]}} or '
            f'{{"mean_of": [...]}}, got {threshold_raw!r}'
        )
    if set(threshold_raw) == {"white", "black"}:
        white, black = threshold_raw["white"], threshold_raw["black"]
        if not (_is_int(white) and _is_int(black) and white >= 0 and black >= 0):
            raise ValueError(
                f"{name}: threshold.white and threshold.black must be frame numbers, got {threshold_raw!r}"
            )
        threshold = WhiteBlack(white=white, black=black)
    elif set(threshold_raw) == {"inverse_frames"}:
        inverse = _frames(threshold_raw["inverse_frames"], name=name, key="threshold.inverse_frames")
        if len(inverse) != len(gray):
            raise ValueError(
                f"{name}: threshold.inverse_frames must name one inverse per Gray frame ({len(gray)}), "
                f"got {len(inverse)}"
            )
        threshold = InverseFrames(frames=inverse)
    elif set(threshold_raw) == {"mean_of"}:
        threshold = MeanOf(frames=_frames(threshold_raw["mean_of"], name=name, key="threshold.mean_of", at_least=2))
    else:
        raise ValueError(
            f"{name}: threshold must hold exactly white and black, inverse_frames, or mean_of; got keys "
            f"{sorted(threshold_raw)}"
        )
    phase = None
    if raw.get("phase") is not None:
        phase_raw = raw["phase"]
        if not isinstance(phase_raw, dict) or not {"frames", "period_px"} <= set(phase_raw):
            raise ValueError(f'{name}: phase must be {{"frames": [...], "period_px": p}}, got {phase_raw!r}')
        frames = _frames(phase_raw["frames"], name=name, key="phase.frames", at_least=3)
        period = phase_raw["period_px"]
        if not (_is_number(period) and period > 0):
            raise ValueError(f"{name}: phase.period_px must be a positive number, got {period!r}")
        offset = phase_raw.get("offset_px")
        if offset is not None and not _is_number(offset):
            raise ValueError(f"{name}: phase.offset_px must be a number or absent, got {offset!r}")
        phase = PhaseFrames(frames=frames, period_px=float(period), offset_px=None if offset is None else float(offset))
    try:
        sequence = PatternSequence(
            axis=axis, projector_size_wh_px=(size[0], size[1]), gray_frames=gray, band_px=float(band),
            threshold=threshold, phase=phase,
        )  # fmt: skip
    except ValueError as error:
        raise ValueError(f"{name}: {error}") from None
    if n_frames is not None:
        check_frames_exist(sequence, n_frames, name=name)
    return sequence


def check_frames_exist(sequence: PatternSequence, n_frames: int, *, name: str = PATTERNS_JSON) -> None:
    """ValueError naming the key when the sequence names frames the recording does not have."""
    groups: list[tuple[str, tuple[int, ...]]] = [("gray_frames", sequence.gray_frames)]
    threshold = sequence.threshold
    if isinstance(threshold, WhiteBlack):
        groups += [("threshold.white", (threshold.white,)), ("threshold.black", (threshold.black,))]
    elif isinstance(threshold, InverseFrames):
        groups.append(("threshold.inverse_frames", threshold.frames))
    else:
        groups.append(("threshold.mean_of", threshold.frames))
    if sequence.phase is not None:
        groups.append(("phase.frames", sequence.phase.frames))
    for key, frames in groups:
        beyond = [f for f in frames if f >= n_frames]
        if beyond:
            raise ValueError(
                f"{name}: {key} names frame{'s' if len(beyond) > 1 else ''} {', '.join(map(str, beyond))} but the "
                f"recording has {n_frames} frames (0–{n_frames - 1})"
            )


def patterns_json_text(sequence: PatternSequence) -> str:
    """The document of a sequence (what `read_patterns_json` reads back to the same sequence)."""
    threshold = sequence.threshold
    if isinstance(threshold, WhiteBlack):
        threshold_doc: dict[str, Any] = {"white": threshold.white, "black": threshold.black}
    elif isinstance(threshold, InverseFrames):
        threshold_doc = {"inverse_frames": list(threshold.frames)}
    else:
        threshold_doc = {"mean_of": list(threshold.frames)}
    document: dict[str, Any] = {
        "axis": sequence.axis, "projector_size_px": list(sequence.projector_size_wh_px),
        "gray_frames": list(sequence.gray_frames), "band_px": sequence.band_px, "threshold": threshold_doc,
    }  # fmt: skip
    if sequence.phase is not None:
        document["phase"] = {"frames": list(sequence.phase.frames), "period_px": sequence.phase.period_px}
        if sequence.phase.offset_px is not None:
            document["phase"]["offset_px"] = sequence.phase.offset_px
    return json.dumps(document, indent=1) + "\n"
