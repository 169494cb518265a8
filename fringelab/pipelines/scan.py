"""Camera–projector scans and calibrations of whole recordings (docs/procam.md): recordings, sidecars and
calibration files in, results out.

What the command line (and a worker's job) calls: finds `patterns.json` beside the frames when it is not given,
checks that the recording, its sequence and the calibration belong together before decoding anything, and writes
the result only when it is whole. The science lives in `fringelab.science.scan` and `procam_calibration`.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from fringelab.formats.patterns import PATTERNS_JSON, read_patterns_json
from fringelab.formats.procam import read_procam_calibration, write_procam_json
from fringelab.formats.recordings import open_recording
from fringelab.formats.scan import write_scan
from fringelab.pipelines.provenance import code_versions
from fringelab.science.chessboard import Board
from fringelab.science.graycode import PatternSequence
from fringelab.science.procam import ProcamModel
from fringelab.science.procam_calibration import ProcamCalibration, ProgressCallback, calibrate_procam_from_recordings
from fringelab.science.scan import ScanResult, ScanSettings, check_scan_inputs, scan, scan_qa


def sequence_of(source: Any, recording: str, patterns: str | Path | None) -> tuple[PatternSequence, str]:
    """The recording's pattern sequence (from `patterns`, else its patterns.json) and the text it was read from."""
    if patterns is not None:
        path = Path(patterns)
        name, text = path.name, path.read_text(encoding="utf-8")
    else:
        found = source.sidecar_text(PATTERNS_JSON)
        if found is None:
            raise ValueError(f"{recording}: no {PATTERNS_JSON} beside the frames; give one with --patterns")
        name, text = PATTERNS_JSON, found
    return read_patterns_json(text, name=name, n_frames=len(source)), text


def scan_recording(
    recording: str | Path,
    calibration: str | Path | ProcamModel,
    output: str | Path,
    *,
    patterns: str | Path | None = None,
    settings: ScanSettings | None = None,
    camera_size_wh_px: tuple[int, int] | None = None,
    projector_size_wh_px: tuple[int, int] | None = None,
    progress: ProgressCallback | None = None,
) -> ScanResult:
    """Scan a recording (folder or ZIP of frames) with a camera–projector calibration and write `output` (HDF5)."""
    settings = ScanSettings() if settings is None else settings
    name = Path(recording).name
    model = (
        calibration if isinstance(calibration, ProcamModel)
        else read_procam_calibration(calibration, camera_size_wh_px=camera_size_wh_px,
                                     projector_size_wh_px=projector_size_wh_px)
    )  # fmt: skip
    with open_recording(recording) as source:
        sequence, text = sequence_of(source, name, patterns)
        first = np.asarray(source[0])
        check_scan_inputs((int(first.shape[0]), int(first.shape[1])), sequence, model, recording=name)
        used = sorted(set(sequence.frames_used()))
        frames: list[np.ndarray] = [first] * len(source)
        for done, index in enumerate(used):
            frames[index] = np.asarray(source[index])
            if progress is not None:
                progress(done + 1, len(used) + 2, "frames")
    result = scan(frames, sequence, model, settings=settings, recording=name)
    if progress is not None:
        progress(len(used) + 1, len(used) + 2, "points")
    source_name = Path(calibration).name if not isinstance(calibration, ProcamModel) else "(in memory)"
    provenance = {"recording": name, "calibration": source_name,
                  "projector_scale_xy": list(settings.projector_scale_xy),
                  "projector_offset_xy_px": list(settings.projector_offset_xy_px), **code_versions()}  # fmt: skip
    write_scan(output, result, qa=scan_qa(result), patterns=json.loads(text), provenance=provenance)
    if progress is not None:
        progress(len(used) + 2, len(used) + 2, "done")
    return result


def calibrate_procam_recordings(
    poses: Sequence[str | Path],
    output: str | Path,
    *,
    board: Board,
    columns: str | Path | None = None,
    rows: str | Path | None = None,
    white_frame: int | None = None,
    progress: ProgressCallback | None = None,
) -> ProcamCalibration:
    """Calibrate from one recording per chessboard pose, each with `patterns-columns.json` and `patterns-rows.json`
    beside its frames (or the files given); the white frame is the columns sequence's white threshold frame unless
    given. Writes fringelab's calibration JSON with its report."""
    loaded = []
    columns_sequence = rows_sequence = None
    for pose in poses:
        name = Path(pose).name
        with open_recording(pose) as source:
            col_text = (
                Path(columns).read_text(encoding="utf-8") if columns else source.sidecar_text("patterns-columns.json")
            )
            row_text = Path(rows).read_text(encoding="utf-8") if rows else source.sidecar_text("patterns-rows.json")
            if col_text is None or row_text is None:
                raise ValueError(
                    f"{name}: needs patterns-columns.json and patterns-rows.json beside its frames (or --columns and "
                    "--rows)"
                )
            columns_sequence = read_patterns_json(col_text, name="patterns-columns.json", n_frames=len(source))
            rows_sequence = read_patterns_json(row_text, name="patterns-rows.json", n_frames=len(source))
            loaded.append((name, [np.asarray(frame) for frame in source]))
    if columns_sequence is None or rows_sequence is None:
        raise ValueError("no chessboard pose recordings given")
    if white_frame is None:
        threshold = columns_sequence.threshold
        white = getattr(threshold, "white", None)
        if white is None:
            raise ValueError("patterns-columns.json has no white frame (threshold.white): give --white-frame")
        white_frame = int(white)
    calibration = calibrate_procam_from_recordings(
        loaded, columns=columns_sequence, rows=rows_sequence, board=board, white_frame=white_frame, progress=progress
    )
    write_procam_json(output, calibration.model, calibration=calibration,
                      provenance={"poses": [name for name, _ in loaded], **code_versions()})  # fmt: skip
    return calibration
