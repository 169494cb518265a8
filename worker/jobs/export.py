"""The export job: a topography result written in one of the export formats (fringelab.formats.exports)."""

from __future__ import annotations

import shutil
import zipfile
from typing import Any

from fringelab.core.models import Job
from worker.runner import JobContext


def export_body(context: JobContext) -> dict[str, Any]:
    from fringelab.formats.exports import EXPORT_FILES, export_result

    spec = context.spec
    with context.sessions() as session:
        source = session.get(Job, spec["job_id"])
        entry = next((f for f in (source.files if source else []) if f["name"] == "topography.h5"), None)
    if entry is None:
        raise ValueError(f"topography job {spec['job_id']} has no result file any more; run it again")
    result_path = context.settings.data_path / entry["path"]
    line = tuple(spec["line"]) if spec.get("line") else None
    lines = [tuple(one) for one in spec["lines"]] if spec.get("lines") else None
    frames = spec.get("frames")
    frame_range = (frames["first"], frames["last"] if frames.get("last") is not None else 2**31 - 1) if frames else None
    context.progress(0, 1, "exporting")
    fmt = spec["format"]
    if fmt == "vtk":  # a .pvd time series of .vtu files: one download as a ZIP
        work = context.directory / "vtk"
        shutil.rmtree(work, ignore_errors=True)  # a previous run's leftovers
        export_result(result_path, fmt, work / "topography.pvd", frames=frame_range)
        name, media = EXPORT_FILES[fmt]
        with (
            context.output(name, media_type=media) as temporary,
            zipfile.ZipFile(temporary, "w", compression=zipfile.ZIP_DEFLATED) as archive,
        ):
            for path in sorted(work.rglob("*")):
                if path.is_file():
                    archive.write(path, path.relative_to(work))
        shutil.rmtree(work)
    else:
        name, media = EXPORT_FILES[fmt]
        with context.output(name, media_type=media) as temporary:
            export_result(result_path, fmt, temporary, line=line, lines=lines, frames=frame_range)  # type: ignore[arg-type]
    context.progress(1, 1, "exporting")
    return {"format": fmt, "file": name, "source_job_id": spec["job_id"], "frames": frames, "lines": len(lines or [])}
