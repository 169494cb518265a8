"""Hand-overs between a job's tasks: arrays a chunk writes for its merge (or an entry for its chunks), one record at
a time, in a file written atomically (`.npy` records, no ZIP), or kept in the process that wrote them when only that
process reads them (`JobContext.hold`: a merge's own later chunks).

What does not belong here: what the records hold (each job kind's typed records, e.g.
`fringelab.pipelines.topography.PackedFrame`), and when they are written (`worker.chunks`).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from worker.context import (
    JobContext,
)


def remove_chunk_files(directory: Path) -> None:
    chunk_dir = directory / "chunks"
    if chunk_dir.is_dir():
        for path in chunk_dir.iterdir():
            path.unlink(missing_ok=True)
        chunk_dir.rmdir()


def save_arrays(context: JobContext, name: str, **arrays: Any) -> None:
    """Arrays a task hands over (to `load_arrays`), in one file written atomically (one `array_records` record)."""
    with array_records(context, name) as write:
        write(**arrays)


def load_arrays(context: JobContext, name: str) -> dict[str, np.ndarray]:
    return next(read_array_records(context, name))


def _npy_writer(handle: Any) -> Callable[..., None]:
    """`write(**arrays)`: one record, its names, then each array as a .npy record (no ZIP: read back at the speed
    of the disk cache, no checksum per read)."""
    from numpy.lib import format as npy

    def write(**arrays: Any) -> None:
        npy.write_array(handle, np.array(list(arrays), dtype=str), allow_pickle=False)
        for value in arrays.values():
            npy.write_array(handle, np.asarray(value), allow_pickle=False)

    return write


def _npy_records(handle: Any) -> Iterator[dict[str, np.ndarray]]:
    """The records `_npy_writer` wrote to `handle`, from its start."""
    from numpy.lib import format as npy

    size = handle.seek(0, os.SEEK_END)
    handle.seek(0)
    while handle.tell() < size:
        names = npy.read_array(handle, allow_pickle=False)
        yield {str(key): npy.read_array(handle, allow_pickle=False) for key in names}


# Hand-overs kept in this process (`JobContext.hold`), by (job id, name); a merge drops its job's when it ends.
HELD_HAND_OVER_BYTES = 256 << 20


class _Kept:
    """A hand-over kept in this process: its records as written (arrays, not encoded and decoded again) while
    they fit in HELD_HAND_OVER_BYTES, the rest in an anonymous temporary file."""

    def __init__(self) -> None:
        self.records: list[dict[str, np.ndarray]] = []
        self.nbytes = 0
        self.spill: Any = None

    def write(self, **arrays: Any) -> None:
        # contiguous: a column of a larger array is copied, not kept as a view holding the whole
        record = {name: np.array(value, order="C", copy=None) for name, value in arrays.items()}
        size = sum(value.nbytes for value in record.values())
        if self.spill is None and self.nbytes + size <= HELD_HAND_OVER_BYTES:
            self.records.append(record)
            self.nbytes += size
            return
        if self.spill is None:
            import tempfile

            self.spill = tempfile.TemporaryFile()  # noqa: SIM115 (closed by `close`)
        _npy_writer(self.spill)(**record)

    def read(self) -> Iterator[dict[str, np.ndarray]]:
        while self.records:  # each record given up as it is read
            yield self.records.pop(0)
        if self.spill is not None:
            yield from _npy_records(self.spill)

    def close(self) -> None:
        self.records.clear()
        if self.spill is not None:
            self.spill.close()


_held: dict[tuple[str, str], _Kept] = {}


@contextmanager
def array_records(context: JobContext, name: str) -> Iterator[Callable[..., None]]:
    """A hand-over file written record by record (`write(**arrays)`, e.g. one per frame, so that what a chunk holds
    does not grow with its frames, `_npy_writer`), committed when the block completes. With `context.hold` it
    stays in this process instead (`_Kept`: no file, no fsync), for this process to read."""
    if context.hold:
        kept = _Kept()
        try:
            yield kept.write
        except BaseException:
            kept.close()
            raise
        _held[(context.job_id, name)] = kept
        return
    with context.output(name, publish=False) as path, path.open("wb") as handle:
        yield _npy_writer(handle)


def read_array_records(context: JobContext, name: str) -> Iterator[dict[str, np.ndarray]]:
    """The records of a hand-over (`array_records`), one at a time: kept in this process (given up as read), or
    its file."""
    kept = _held.pop((context.job_id, name), None)
    if kept is not None:
        try:
            yield from kept.read()
        finally:
            kept.close()
        return
    path = context.directory / name
    if not path.is_file():
        raise RuntimeError(f"the intermediate file {name} is missing")
    with path.open("rb") as handle:
        yield from _npy_records(handle)


def has_hand_over(context: JobContext, name: str) -> bool:
    """Whether a hand-over `name` of the context's job can be read here (kept in this process, or its file)."""
    return (context.job_id, name) in _held or (context.directory / name).is_file()


def drop_held(job_id: str) -> None:
    for key in [key for key in _held if key[0] == job_id]:
        _held.pop(key).close()
