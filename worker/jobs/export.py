"""The export job: a topography result written in one of the export formats (fringelab.formats.exports)."""

from __future__ import annotations

import shutil
import zipfile
from typing import Any

from fringelab.core.models import Job
from worker.runner import JobContext


def export_body(context: JobContext) -> dict[str, Any]:
    from fringelab.formats.exports import export_result

    spec = context.spec
    with context.sessions() as session:
        source = session.get(Job, spec["job_id"])
        entry = next((f for f in (source.files if source else []) if f["name"] == "topography.h5"), None)
    if entry is None:
        raise ValueError(f"topography job {spec['job_id']} has no result file any more; run it again")
    result_path = context.settings.data_path / entry["path"]
    line = tuple(spec["line"]) if spec.get("line") else None
    context.progress(0, 1, "exporting")
    fmt = spec["format"]
    if fmt == "vtk":  # a .pvd time series of .vtu files: one download as a ZIP
        work = context.directory / "vtk"
        shutil.rmtree(work, ignore_errors=True)  # a previous run's leftovers
        export_result(result_path, fmt, work / "topography.pvd")
        name = "topography-vtk.zip"
        with (
            context.output(name, media_type="application/zip") as temporary,
            zipfile.ZipFile(temporary, "w", compression=zipfile.ZIP_DEFLATED) as archive,
        ):
            for path in sorted(work.rglob("*")):
                if path.is_file():
                    archive.write(path, path.relative_to(work))
        shutil.rmtree(work)
    else:
        suffix, media = {
            "points-csv": (".csv", "text/csv"),
            "profile-csv": ("-profile.csv", "text/csv"),
            "grid-npz": (".npz", "application/octet-stream"),
            "mat": (".mat", "application/x-matlab-data"),
        }[fmt]
        name = f"topography{suffix}"
        with context.output(name, media_type=media) as temporary:
            export_result(result_path, fmt, temporary, line=line)  # type: ignore[arg-type]
    context.progress(1, 1, "exporting")
    return {"format": fmt, "file": name, "source_job_id": spec["job_id"]}
