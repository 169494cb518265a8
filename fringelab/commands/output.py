"""What the science commands show: a progress bar on stderr while they run (tqdm), and their result as text, or
with `--json` as one JSON object on stdout for scripts (an error too: `{"error": "..."}`, exit status 2).

Every long command takes `add_output_options`; stdout carries only the result, so `--json` output can be piped.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import asdict, is_dataclass
from pathlib import Path
from typing import Any

ProgressCallback = Callable[[int, int, str], None]


def floats(text: str, count: int, what: str) -> tuple[float, ...]:
    """The core of the argparse types that take numbers separated by commas: `count` finite numbers, else
    ArgumentTypeError "expected {what}, got '...'" (what: e.g. "X,Y in mm")."""
    try:
        values = tuple(float(part) for part in text.split(","))
    except ValueError:
        values = ()
    if len(values) != count or not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
    return values


def integers(text: str, count: int, what: str) -> tuple[int, ...]:
    """As `floats`, for whole numbers."""
    try:
        values = tuple(int(part) for part in text.split(","))
    except ValueError:
        values = ()
    if len(values) != count:
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
    return values


def line_mm(text: str) -> tuple[float, float, float, float]:
    """An argparse type: a line X0,Y0,X1,Y1 (mm), e.g. a profile's."""
    x0, y0, x1, y1 = floats(text, 4, "X0,Y0,X1,Y1 in mm")
    return x0, y0, x1, y1


def add_output_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--json",
        action="store_true",
        help='print the result as one JSON object on stdout (an error as {"error": ...}); no progress bar',
    )
    parser.add_argument(
        "--progress",
        choices=("auto", "always", "never"),
        default="auto",
        help="progress bar on stderr (auto: when stderr is a terminal)",
    )


@contextmanager
def progress_bar(args: argparse.Namespace, description: str) -> Iterator[ProgressCallback]:
    """A callback `progress(done, total, stage)` that draws a bar on stderr, the stage as its label."""
    from tqdm import tqdm

    mode = getattr(args, "progress", "auto")
    disable: bool | None = True if getattr(args, "json", False) or mode == "never" else None
    if mode == "always" and not getattr(args, "json", False):
        disable = False
    with tqdm(total=0, desc=description, unit="step", file=sys.stderr, disable=disable, dynamic_ncols=True) as bar:

        def update(done: int, total: int, stage: str) -> None:
            if bar.total != total:
                bar.reset(total=total)
            bar.set_description(f"{description}: {stage}", refresh=False)
            bar.n = done
            bar.refresh()

        yield update


def jsonable(value: Any) -> Any:
    """Dataclasses, paths, ranges, numpy scalars and arrays as JSON values; NaN and infinities as null."""
    if is_dataclass(value) and not isinstance(value, type):
        return jsonable(asdict(value))
    if isinstance(value, Mapping):
        return {str(key): jsonable(item) for key, item in value.items()}
    if isinstance(value, range):
        return {"start": value.start, "stop": value.stop}
    if isinstance(value, Path):
        return str(value)
    if isinstance(value, list | tuple):
        return [jsonable(item) for item in value]
    if hasattr(value, "tolist"):  # numpy scalar or array
        return jsonable(value.tolist())
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def emit(args: argparse.Namespace, result: Mapping[str, Any], lines: list[str]) -> int:
    """Print the result: `lines` as text, or `result` as JSON with --json. Returns the exit status 0."""
    if getattr(args, "json", False):
        print(json.dumps(jsonable(result), allow_nan=False))
    else:
        for line in lines:
            print(line)
    return 0


def fail(args: argparse.Namespace, error: Exception) -> int:
    """Report an error (stderr; also stdout as JSON with --json) and return the exit status 2."""
    print(f"error: {error}", file=sys.stderr)
    if getattr(args, "json", False):
        print(json.dumps({"error": str(error), "type": type(error).__name__}))
    return 2
