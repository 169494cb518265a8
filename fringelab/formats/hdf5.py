"""HDF5 conventions shared by fringelab's result files: every dataset carries its unit and description, JSON
documents in attributes have no NaN, every file names its schema and version, and a result file's reader opens it
read-only and closes it the same way (`ResultReader`)."""

from __future__ import annotations

import json
import math
import os
import threading
from collections import OrderedDict
from collections.abc import Callable, Hashable
from pathlib import Path
from typing import TYPE_CHECKING, Any, Self

import h5py
import numpy as np

if TYPE_CHECKING:
    from fringelab.science.fields import Grid


SCHEMA_VERSION = 1


def unit_dataset(
    group: h5py.Group, name: str, data: Any, *, unit: str, description: str, **kwargs: Any
) -> h5py.Dataset:
    dataset = group.create_dataset(name, data=data, **kwargs)
    dataset.attrs["unit"] = unit
    dataset.attrs["description"] = description
    return dataset


def json_text(value: Any) -> str:
    def clean(obj: Any) -> Any:
        if isinstance(obj, dict):
            return {str(k): clean(v) for k, v in obj.items()}
        if isinstance(obj, list | tuple):
            return [clean(v) for v in obj]
        if isinstance(obj, float | np.floating):
            return float(obj) if math.isfinite(obj) else None
        if isinstance(obj, np.integer):
            return int(obj)
        if isinstance(obj, np.ndarray):
            return clean(obj.tolist())
        return obj

    return json.dumps(clean(value))


def require_schema(file: h5py.File, schema: str, path: Path, *, version_optional: bool = False) -> None:
    """ValueError unless `file` is a `schema` file of a version this code reads (`version_optional`: files
    written before versions were recorded count as version 1)."""
    found = file.attrs.get("schema")
    if found != schema:
        raise ValueError(f"{path}: not a {schema} file (schema {found!r})")
    version = file.attrs.get("schema_version", SCHEMA_VERSION if version_optional else None)
    if version is None or int(version) != SCHEMA_VERSION:
        raise ValueError(f"{path}: schema version {version} is not supported (expected {SCHEMA_VERSION})")


def open_read_only(path: Path, error: type[ValueError] = ValueError) -> h5py.File:
    """`path` opened read-only; `error` (a ValueError) naming the file when it is not a readable HDF5 file."""
    try:
        return h5py.File(path, "r")
    except OSError as reason:
        raise error(f"{path.name}: not a readable HDF5 file ({reason})") from None


class FrameCache:
    """Frames recently read from result files, kept in memory by one process: a viewer's grid, profile and history
    reads come back to the same few frames, and reading one again costs its decompression every time (a profile
    over ten frames read ten 250 × 250 chunks; issue 26's heavy mix cost 8.2 ms of web CPU per request).

    Bounded by bytes (least recently used first out; a frame over an eighth of the bound is never kept, so one
    cannot flush the rest). The key is the file's identity as `file_key` gives it (device, inode, size,
    modification time): a result written again (a new file renamed into place) or deleted is never answered from
    the old one's frames. Arrays handed out are read-only (shared by the threads of the process)."""

    def __init__(self, *, max_bytes: int) -> None:
        self.max_bytes = max_bytes
        self._frames: OrderedDict[Hashable, np.ndarray] = OrderedDict()
        self._bytes = 0
        self._lock = threading.Lock()
        self.hits = 0
        self.misses = 0

    @property
    def held_bytes(self) -> int:
        return self._bytes

    def get_or_read(self, key: Hashable, read: Callable[[], np.ndarray]) -> np.ndarray:
        """The array kept under `key` (from `file_key` and what names the frame), or `read()`'s, then kept."""
        with self._lock:
            kept = self._frames.get(key)
            if kept is not None:
                self._frames.move_to_end(key)
                self.hits += 1
                return kept
            self.misses += 1
        array = read()
        array.setflags(write=False)
        if self.max_bytes > 0 and array.nbytes <= self.max_bytes // 8:
            with self._lock:
                if key not in self._frames:
                    self._frames[key] = array
                    self._bytes += array.nbytes
                while self._bytes > self.max_bytes:
                    _, dropped = self._frames.popitem(last=False)
                    self._bytes -= dropped.nbytes
        return array

    def clear(self) -> None:
        with self._lock:
            self._frames.clear()
            self._bytes = 0


def file_key(file: h5py.File) -> tuple[int, int, int, int]:
    """The identity of an open file's contents for `FrameCache`: (device, inode, size, modification time in ns) of
    what is open (fstat of its descriptor, so a file renamed over it after opening does not count as this one)."""
    handle = file.id.get_vfd_handle()
    info = os.fstat(handle) if isinstance(handle, int) else os.stat(file.filename)
    return (info.st_dev, info.st_ino, info.st_size, info.st_mtime_ns)


def path_key(path: Path, error: type[ValueError] = ValueError) -> tuple[int, int, int, int]:
    """The identity `file_key` gives, of the file at `path` before it is opened; `error` (a ValueError) naming the
    file when there is none."""
    try:
        info = os.stat(path)
    except OSError as reason:
        raise error(f"{path.name}: not a readable HDF5 file ({reason})") from None
    return (info.st_dev, info.st_ino, info.st_size, info.st_mtime_ns)


class ResultReader:
    """What the readers of result files on a grid share (`TopographyResult`, `ComparisonResult`): the open file,
    its grid and frames, use as a context manager, `close()` and `n_frames`. Each reader opens its file
    (`open_read_only`) and checks its own schema in its `__init__`."""

    path: Path
    file: h5py.File
    grid: Grid
    frames: np.ndarray

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def close(self) -> None:
        self.file.close()

    @property
    def n_frames(self) -> int:
        return len(self.frames)
