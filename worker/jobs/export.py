"""The export job: a topography result, or a comparison with a simulation, written in one of its export formats
(`fringelab.formats.exports`, the owner of every export format). `write_download` also serves the comparison job's
own export."""

from __future__ import annotations

import shutil
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

from fringelab.core.models import Job
from fringelab.core.specs import ExportSpec
from worker.context import JobContext
from worker.reserve import require_reserve

SOURCE_FILES = {"topography": "topography.h5", "comparison": "comparison.h5"}


def write_download(context: JobContext, fmt: str, name: str, media: str, write: Callable[[Path], Path]) -> None:
    """One export as one download `name`: the file `write(path)` writes there, or for "vtk" (a .pvd and its folder
    of .vtu files) all of them in one ZIP."""
    if fmt != "vtk":
        with context.output(name, media_type=media) as temporary:
            write(temporary)
        return
    work = context.directory / "vtk"
    shutil.rmtree(work, ignore_errors=True)  # a previous run's leftovers
    try:
        require_reserve(context.settings, what=f"writing {name}")
        write(work / f"{Path(name).stem.removesuffix('-vtk')}.pvd")
        with (
            context.output(name, media_type=media) as temporary,
            zipfile.ZipFile(temporary, "w", compression=zipfile.ZIP_DEFLATED) as archive,
        ):
            for path in sorted(work.rglob("*")):
                if path.is_file():
                    require_reserve(context.settings, what=f"writing the rest of {name}")
                    archive.write(path, path.relative_to(work))
    finally:  # the .vtu files are only the ZIP's parts: never left behind, whatever ended the job
        shutil.rmtree(work, ignore_errors=True)


def keeping_reserve(context: JobContext, name: str) -> Callable[[int, int, str], None]:
    """A progress callback for a format's writer that stops it (BelowReserve) once the data volume has fallen
    below its reserve while `name` is written frame by frame (issue 26: only topography jobs checked)."""

    def check(done: int, total: int, _stage: str) -> None:
        require_reserve(context.settings, what=f"writing frame {done + 1} of {total} of {name}")

    return check


def export_body(context: JobContext[ExportSpec]) -> dict[str, Any]:
    from fringelab.formats.exports import COMPARISON_EXPORT_FILES, EXPORT_FILES, export_comparison, export_result

    spec = context.spec
    with context.sessions() as session:
        source = session.get(Job, spec.job_id)
        kind = source.kind if source else "topography"
        entry = next((f for f in (source.files if source else []) if f["name"] == SOURCE_FILES.get(kind)), None)
    if entry is None:
        raise ValueError(f"{kind} job {spec.job_id} has no result file any more; run it again")
    source_path = context.settings.data_path / entry["path"]
    line, lines = spec.line, (list(spec.lines) if spec.lines else None)
    frames = spec.frames
    frame_range = (frames.first, frames.last if frames.last is not None else 2**31 - 1) if frames else None
    context.progress(0, 1, "exporting")
    fmt = spec.format
    if kind == "comparison":
        name, media = COMPARISON_EXPORT_FILES[fmt]
        write_download(context, fmt, name, media, lambda path: export_comparison(source_path, fmt, path, line=line))
    else:
        name, media = EXPORT_FILES[fmt]
        write_download(context, fmt, name, media,
                       lambda path: export_result(source_path, fmt, path, line=line, lines=lines, frames=frame_range,
                                                  progress=keeping_reserve(context, name)))  # fmt: skip
    context.progress(1, 1, "exporting")
    frames_json = None if frames is None else frames.model_dump(mode="json")
    return {"format": fmt, "file": name, "source_job_id": spec.job_id, "frames": frames_json, "lines": len(lines or [])}
