"""What a name, a file name or a date a person sends may hold: the one rule every route and upload uses.

Names (experiments, cameras, plates, groups, tokens) and file names are shown in pages, logs, file listings and
exports: a control character (NUL, ESC, ...) breaks them or the terminal that shows a log, a bidirectional
override (U+202E) makes `gpj.exe` read as `exe.jpg`, and a lone surrogate ("\\ud800", which JSON allows) cannot be
stored at all (it raised in the database driver: a 500). Free text (notes) may hold line breaks and tabs; nothing
else of the above. A date is a real calendar date (2026-13-45 was stored).
"""

from __future__ import annotations

import re
from datetime import date

from fringelab.core.errors import Invalid

# C0 controls, DEL and C1 controls; the bidirectional embeddings, overrides and isolates, and the invisible marks
# that reorder text (LRM, RLM, ALM).
_BIDI = "\u061c\u200e\u200f\u202a-\u202e\u2066-\u2069"
_NAME_FORBIDDEN = re.compile(f"[\x00-\x1f\x7f-\x9f{_BIDI}]")
_FREE_TEXT_FORBIDDEN = re.compile(f"[\x00-\x08\x0b\x0c\x0e-\x1f\x7f-\x9f{_BIDI}]")
_SURROGATE = re.compile("[\ud800-\udfff]")


def _describe(character: str) -> str:
    return f"U+{ord(character):04X}"


def text_problem(value: str, *, free_text: bool = False) -> str:
    """Why `value` may not be stored as a name (`free_text`: as notes, where line breaks and tabs are allowed);
    empty when it may."""
    surrogate = _SURROGATE.search(value)
    if surrogate:
        return f"holds {_describe(surrogate.group())}, half of a UTF-16 pair, which is no character"
    forbidden = (_FREE_TEXT_FORBIDDEN if free_text else _NAME_FORBIDDEN).search(value)
    if forbidden:
        kind = "a direction-changing mark" if forbidden.group() in _bidi_set() else "a control character"
        return f"holds {kind} ({_describe(forbidden.group())}) at position {forbidden.start()}; remove it"
    return ""


def _bidi_set() -> set[str]:
    return {"\u061c", "\u200e", "\u200f", *map(chr, range(0x202A, 0x202F)), *map(chr, range(0x2066, 0x206A))}


def plain_name(value: str) -> str:
    """A pydantic validator of names: ValueError naming the character (a 422)."""
    problem = text_problem(value)
    if problem:
        raise ValueError(problem)
    return value


def plain_free_text(value: str) -> str:
    """A pydantic validator of notes and other free text (line breaks and tabs allowed)."""
    problem = text_problem(value, free_text=True)
    if problem:
        raise ValueError(problem)
    return value


def calendar_date(value: str) -> str:
    """A pydantic validator of `YYYY-MM-DD` (or empty): a date that exists."""
    if value:
        try:
            date.fromisoformat(value)
        except ValueError:
            raise ValueError(f"{value!r} is no calendar date; send YYYY-MM-DD, e.g. 2026-11-20") from None
    return value


def check_file_name(filename: str) -> None:
    """Refuse (Invalid, 422 `invalid_filename`) a name that is not a plain file name: empty or over 255
    characters, a path, hidden (a leading dot), or holding a character `text_problem` refuses."""
    if not filename or len(filename) > 255 or "/" in filename or "\\" in filename or filename.startswith("."):
        raise Invalid("filename must be a plain file name of 1 to 255 characters", code="invalid_filename")
    problem = text_problem(filename)
    if problem:
        raise Invalid(f"filename {problem}", code="invalid_filename")


# An absolute POSIX or Windows path (at least two parts), and a memory address as Python prints it (0x7f3a...).
_ABSOLUTE_PATH = re.compile(r"(?<![\w.~:/])(?:/[^\s'\"/:,;()\[\]]+){2,}/?|\b[A-Za-z]:\\(?:[^\s'\"\\:,;()\[\]]+\\?)+")
_ADDRESS = re.compile(r"\b0x[0-9a-fA-F]{6,}\b")


def public_text(message: str) -> str:
    """An error text as a user may see it: a server path becomes its last part (the file's name, which the user
    knows), a memory address `0x…`. What the server log keeps stays whole."""
    shown = _ABSOLUTE_PATH.sub(lambda found: found.group().rstrip("/\\").replace("\\", "/").rsplit("/", 1)[-1], message)
    return _ADDRESS.sub("0x…", shown)
