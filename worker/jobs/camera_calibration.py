"""The camera-calibration job: a chessboard recording of a camera in, its calibration (JSON, report) out."""

from __future__ import annotations

from typing import Any

from fringelab.core.specs import CameraCalibrationSpec
from worker.context import JobContext
from worker.jobs.inputs import record_calibration, recording_input


def camera_calibration_body(context: JobContext[CameraCalibrationSpec]) -> dict[str, Any]:
    from fringelab.formats.camera import write_camera_json
    from fringelab.formats.recordings import open_recording
    from fringelab.pipelines.camera_calibration import calibrate_camera_recording
    from fringelab.science.chessboard import Board

    spec = context.spec
    recording, camera, path = recording_input(context)
    board = None
    if spec.board is not None:
        b = spec.board
        board = Board(b.cols, b.rows, b.square_mm, origin=b.origin)
    pitch_u_um, pitch_v_um = camera.pixel_pitch_uv_um
    if not (pitch_u_um > 0 and pitch_v_um > 0):
        raise ValueError(f"camera {camera.name!r} has no pixel pitch; set it on the camera, then retry")
    context.log(f"calibrating camera {camera.name!r} from recording {recording.id} ({spec.mode})")
    with open_recording(path) as source:
        calibration = calibrate_camera_recording(
            source,
            board=board,
            mode=spec.mode,
            du_px_per_mm=1000.0 / pitch_u_um,
            dv_px_per_mm=1000.0 / pitch_v_um,
            scale_on=spec.scale_on,
            reject_outliers=spec.reject_outliers,
            pixel_pitch_um=(pitch_u_um, pitch_v_um),
            detector=spec.detector,
            subpix_half_window_px=spec.subpix_window_px,
            progress=context.progress,
            should_cancel=context.should_cancel,
        )
    with context.output("camera.json", media_type="application/json") as temporary:
        write_camera_json(calibration, temporary)
    for frame in calibration.frames:
        if frame.status != "used":
            context.log(f"frame {frame.frame} {frame.status}: {frame.reason}", level="warning")
    used = sum(f.status == "used" for f in calibration.frames)
    summary = {
        "mode": calibration.mode,
        "rms_px": calibration.rms_px,
        "verdict": calibration.verdict.level,
        "n_points": calibration.n_points,
        "frames_used": used,
        "frames_total": len(calibration.frames),
        "f_mm": calibration.camera.f_mm,
    }
    size = (calibration.camera.image_width_px, calibration.camera.image_height_px)
    row = record_calibration(
        context, kind="camera", camera_id=camera.id, recording_id=recording.id, name="camera.json",
        image_size_wh_px=size, summary=summary,
    )  # fmt: skip
    context.provenance.update({"science": calibration.provenance})
    context.log(
        f"camera calibration version {row.version}: RMS {calibration.rms_px:.3f} px, "
        f"verdict {calibration.verdict.level}"
    )
    return {"calibration_id": row.id, "version": row.version, **summary, "reasons": list(calibration.verdict.reasons)}
