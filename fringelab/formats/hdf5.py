"""HDF5 conventions shared by fringelab's result files: every dataset carries its unit and description, JSON
documents in attributes have no NaN, every file names its schema and version, and a result file's reader opens it
read-only and closes it the same way (`ResultReader`)."""

from __future__ import annotations

import json
import math
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
