"""The scan job: a Gray-code recording and a camera–projector calibration in, 3-D points (scan.h5) out
(docs/procam.md §3)."""

from __future__ import annotations

from typing import Any

from fringelab.core.specs import ScanSpec
from worker.context import JobContext
from worker.jobs.inputs import calibration_file, recording_input


def scan_body(context: JobContext[ScanSpec]) -> dict[str, Any]:
    from fringelab.pipelines.scan import scan_recording
    from fringelab.science.scan import ScanSettings, scan_qa

    spec = context.spec
    recording, camera, path = recording_input(context)
    calibration = calibration_file(context, spec.procam_calibration_id)
    settings = ScanSettings(
        code_points=spec.code_points,
        projector_scale_xy=(spec.projector_scale_x, spec.projector_scale_y),
        projector_offset_xy_px=(spec.projector_offset_x_px, spec.projector_offset_y_px),
    )
    context.log(f"scanning recording {recording.id} of camera {camera.name!r}")
    with context.output("scan.h5", media_type="application/x-hdf5") as temporary:
        result = scan_recording(path, calibration, temporary, settings=settings, progress=context.progress)
    qa = scan_qa(result)
    context.log(
        f"{qa['n_points']} points ({qa['points_by_source']['stripe edge']} on stripe edges), "
        f"{100 * qa['valid_share']:.1f} % of the pixels decoded"
    )
    if not result.calibration_sigma:
        context.log(str(qa["calibration_sigma_note"]), level="warning")
    return {"n_points": qa["n_points"], "valid_share": qa["valid_share"], "points_by_source": qa["points_by_source"],
            "median_sigma_mm_by_source": qa["median_sigma_mm_by_source"]}  # fmt: skip
