"""The comparison job: a succeeded topography result against an uploaded simulation (`pipelines.comparison`).

Writes `comparison.h5` (layout in `fringelab.formats.comparison`) and, when the spec names a `format`, that export
of it as a second download. The result lists the per-frame RMS and largest differences and the mapping used.
"""

from __future__ import annotations

import shutil
import zipfile
from typing import Any

from fringelab.core.models import Job, Simulation
from worker.runner import JobContext

COMPARISON_FILE = "comparison.h5"
# The file each comparison export hands out, and its media type (vtk: the .pvd and its .vtu files in one ZIP).
EXPORT_FILES: dict[str, tuple[str, str]] = {
    "csv": ("comparison.csv", "text/csv"),
    "hdf5": ("comparison-copy.h5", "application/x-hdf5"),
    "mat": ("comparison.mat", "application/x-matlab-data"),
    "vtk": ("comparison-vtk.zip", "application/zip"),
    "profile-csv": ("comparison-profile.csv", "text/csv"),
}


def mapping_of(spec: dict[str, Any]) -> Any:
    """The spec's mapping options as `science.compare.MappingSettings` (None where all are to be detected)."""
    from fringelab.science.compare import MappingSettings

    origin = spec.get("origin_xy_mm")
    return MappingSettings(
        length_unit=spec.get("units"),
        symmetry=spec.get("symmetry"),
        normal_axis=spec.get("normal_axis"),
        w_sign=spec.get("w_sign"),
        origin_xy_mm=(float(origin[0]), float(origin[1])) if origin else None,
        rotation_deg=float(spec.get("rotation_deg") or 0.0),
        surface=spec.get("surface") or "toward-cameras",
        shell_thickness_mm=spec.get("shell_thickness_mm"),
        time_unit_s=spec.get("time_unit_s"),
        time_offset_s=float(spec.get("time_offset_s") or 0.0),
    )


def comparison_body(context: JobContext) -> dict[str, Any]:
    from fringelab.formats.comparison import export_comparison
    from fringelab.pipelines.comparison import compare_result

    spec = context.spec
    with context.sessions() as session:
        source = session.get(Job, spec["job_id"])
        entry = next((f for f in (source.files if source else []) if f["name"] == "topography.h5"), None)
        simulation = session.get(Simulation, spec["simulation_id"])
        simulation_path = simulation.path if simulation is not None else ""
    if entry is None:
        raise ValueError(f"topography job {spec['job_id']} has no result file any more; run it again")
    if not simulation_path:
        raise ValueError(f"simulation {spec['simulation_id']} was deleted; upload it again")
    data = context.settings.data_path
    with context.output(COMPARISON_FILE, media_type="application/x-hdf5") as temporary:
        summary = compare_result(
            data / entry["path"],
            data / simulation_path,
            temporary,
            align=spec.get("align", "displacement"),
            mapping=mapping_of(spec),
            punch_node=spec.get("punch_node"),
            contact_interface=spec.get("contact_interface"),
            progress=lambda done, total, stage: context.progress(done, total, stage),
        )
    fmt = spec.get("format")
    if fmt:
        name, media = EXPORT_FILES[fmt]
        source_file = context.directory / COMPARISON_FILE
        if fmt == "vtk":  # a .pvd time series of .vtu files: one download as a ZIP
            work = context.directory / "vtk"
            shutil.rmtree(work, ignore_errors=True)  # a previous run's leftovers
            export_comparison(source_file, fmt, work / "comparison.pvd")
            with (
                context.output(name, media_type=media) as temporary,
                zipfile.ZipFile(temporary, "w", compression=zipfile.ZIP_DEFLATED) as archive,
            ):
                for path in sorted(work.rglob("*")):
                    if path.is_file():
                        archive.write(path, path.relative_to(work))
            shutil.rmtree(work)
        else:
            with context.output(name, media_type=media) as temporary:
                export_comparison(source_file, fmt, temporary)
    result = summary.as_json()
    result.update(
        file=COMPARISON_FILE,
        source_job_id=spec["job_id"],
        simulation_id=spec["simulation_id"],
        export=EXPORT_FILES[fmt][0] if fmt else None,
    )
    return result
