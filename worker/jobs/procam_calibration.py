"""The camera–projector calibration job: chessboard poses under Gray code in, the pair's calibration (procam.json
with its report) out (docs/procam.md §1)."""

from __future__ import annotations

from typing import Any

from fringelab.core.models import Recording
from fringelab.core.specs import ProcamCalibrationSpec
from worker.context import JobContext
from worker.jobs.inputs import record_calibration


def procam_calibration_body(context: JobContext[ProcamCalibrationSpec]) -> dict[str, Any]:
    from fringelab.pipelines.scan import calibrate_procam_recordings
    from fringelab.science.chessboard import Board

    spec = context.spec
    paths = []
    camera_ids = set()
    with context.sessions() as session:
        for recording_id in spec.recording_ids:
            recording = session.get(Recording, recording_id)
            if recording is None:
                raise ValueError(f"recording {recording_id} was deleted; upload it again")
            paths.append(context.settings.data_path / recording.path)
            camera_ids.add(recording.camera_id)
    if len(camera_ids) != 1:
        raise ValueError("the chessboard poses must be recordings of one camera")
    board = Board(spec.board.cols, spec.board.rows, spec.board.square_mm, origin=spec.board.origin)
    context.log(f"calibrating the camera–projector pair from {len(paths)} chessboard poses")
    with context.output("procam.json", media_type="application/json") as temporary:
        calibration = calibrate_procam_recordings(paths, temporary, board=board, progress=context.progress)
    summary = {
        "camera_rms_px": calibration.camera_rms_px, "projector_rms_px": calibration.projector_rms_px,
        "stereo_rms_px": calibration.stereo_rms_px, "verdict": calibration.verdict.level,
        "poses": len(calibration.poses),
    }  # fmt: skip
    row = record_calibration(
        context, kind="procam", camera_id=camera_ids.pop(), recording_id=spec.recording_ids[0], name="procam.json",
        image_size_wh_px=calibration.model.camera_size_wh_px, summary=summary,
    )  # fmt: skip
    context.log(
        f"camera–projector calibration version {row.version}: stereo RMS {calibration.stereo_rms_px:.3f} px, "
        f"verdict {calibration.verdict.level}"
    )
    return {"calibration_id": row.id, "version": row.version, **summary,
            "reasons": list(calibration.verdict.reasons)}  # fmt: skip
