"""The comparison job: a succeeded topography result against an uploaded simulation (`pipelines.comparison`).

Writes `comparison.h5` (layout in `fringelab.formats.comparison`) and, when the spec names a `format`, that export
of it as a second download (`fringelab.formats.exports`; an export job of the comparison writes any other later).
The result lists the per-frame RMS and largest differences and the mapping used.
"""

from __future__ import annotations

from typing import Any

from fringelab.core.job_kinds import COMPARISON_FILE, TOPOGRAPHY_FILE
from fringelab.core.models import Job, Simulation
from fringelab.core.specs import ComparisonSpec
from worker.context import JobContext
from worker.jobs.export import write_download


def comparison_body(context: JobContext[ComparisonSpec]) -> dict[str, Any]:
    from fringelab.core.simulations import mapping_settings
    from fringelab.formats.exports import COMPARISON_EXPORT_FILES, export_comparison
    from fringelab.pipelines.comparison import compare_result
    from fringelab.science.compare import ComparisonError, in_form_terms

    spec = context.spec
    with context.sessions() as session:
        source = session.get(Job, spec.job_id)
        entry = next((f for f in (source.files if source else []) if f["name"] == TOPOGRAPHY_FILE), None)
        simulation = session.get(Simulation, spec.simulation_id)
        simulation_path = simulation.path if simulation is not None else ""
    if entry is None:
        raise ValueError(f"topography job {spec.job_id} has no result file any more; run it again")
    if not simulation_path:
        raise ValueError(f"simulation {spec.simulation_id} was deleted; upload it again")
    data = context.settings.data_path
    try:
        with context.output(COMPARISON_FILE, media_type="application/x-hdf5") as temporary:
            summary = compare_result(
                data / entry["path"],
                data / simulation_path,
                temporary,
                align=spec.align,
                mapping=mapping_settings(spec),
                punch_node=spec.punch_node,
                contact_interface=spec.contact_interface,
                progress=lambda done, total, stage: context.progress(done, total, stage),
                max_simulation_bytes=context.settings.simulation_max_bytes,
            )
    except (ComparisonError, ValueError) as error:  # the setting to change named as the mapping form names it
        raise type(error)(in_form_terms(str(error))) from None
    fmt = spec.format
    if fmt:
        name, media = COMPARISON_EXPORT_FILES[fmt]
        source_file = context.directory / COMPARISON_FILE
        write_download(context, fmt, name, media, lambda path: export_comparison(source_file, fmt, path))
    result = summary.as_json()
    result.update(
        file=COMPARISON_FILE,
        source_job_id=spec.job_id,
        simulation_id=spec.simulation_id,
        export=COMPARISON_EXPORT_FILES[fmt][0] if fmt else None,
    )
    return result
