"""The projector-calibration job: a flat-plate Z-stack in, the projector look-up table out."""

from __future__ import annotations

from dataclasses import asdict
from typing import Any

from fringelab.core.specs import ProjectorCalibrationSpec
from worker.context import JobContext
from worker.jobs.inputs import calibration_file, record_calibration, recording_input


def projector_calibration_body(context: JobContext[ProjectorCalibrationSpec]) -> dict[str, Any]:
    from fringelab.formats.camera import read_camera_json
    from fringelab.formats.projector import write_projector_calibration
    from fringelab.formats.recordings import open_recording
    from fringelab.pipelines.projector_calibration import calibrate_projector_recording
    from fringelab.science.fringes import EdgeSettings
    from fringelab.science.projector import ProjectorSettings
    from fringelab.science.projector_quality import judge_projector

    spec = context.spec
    recording, camera, path = recording_input(context)
    camera_model = read_camera_json(calibration_file(context, spec.camera_calibration_id))
    settings = ProjectorSettings(
        edges=EdgeSettings(axis=spec.axis),
        reference_z_mm=spec.reference_z_mm,
        poly_degree=spec.poly_degree,
        min_z_samples=max(6, spec.poly_degree + 2),
    )
    context.log(f"projector calibration of camera {camera.name!r} from recording {recording.id}")
    with open_recording(path) as source:
        calibration = calibrate_projector_recording(
            source, camera_model, settings=settings, progress=context.progress, should_cancel=context.should_cancel
        )
    with context.output("projector.h5", media_type="application/x-hdf5") as temporary:
        write_projector_calibration(calibration, temporary)
    qa = calibration.qa
    summary = {
        "axis": calibration.axis,
        "n_edges": qa.n_edges,
        "n_lines": calibration.n_lines,
        "z_range_mm": [float(v) for v in qa.z_range_mm],
        "z_steps": len(calibration.z_mm),
        "coverage": qa.coverage,
        "sensitivity_px_per_mm": float(qa.sensitivity_px_per_mm[1]),
        "fit_rms_mm": qa.fit_rms_mm,
        # what the calibration lists show: the camera calibration it is built on, and its verdict
        "camera_calibration_id": spec.camera_calibration_id,
        "verdict": judge_projector(asdict(qa)).level,
    }
    height, width = calibration.image_shape_hw_px
    row = record_calibration(
        context, kind="projector", camera_id=camera.id, recording_id=recording.id, name="projector.h5",
        image_size_wh_px=(width, height), summary=summary,
    )  # fmt: skip
    context.provenance.update({"science": calibration.provenance})
    context.log(
        f"projector calibration version {row.version}: {qa.n_edges} edges, coverage {qa.coverage:.1%}, "
        f"fit RMS {qa.fit_rms_mm:.4f} mm"
    )
    return {"calibration_id": row.id, "version": row.version, **summary}
