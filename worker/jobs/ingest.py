"""The ingest job, run after every upload: probe the recording, check every frame, store previews and QA.

Task "fringelab.ingest" takes a job id whose spec is {"recording_id": N}. It probes the format, frame count,
size, bit depth and frame rate (stored at once, so a client sees them within seconds), validates the sidecars
against the frames, then reads every frame once: statistics, a display-size preview and a thumbnail
(`fringelab.formats.previews`), and for camera-calibration recordings whether the chessboard of `board.json` is found.
The recording ends `ready` with its warnings, or `invalid` with the reasons (and the job fails with them);
never `ready` after any failure. Running it twice (acks-late redelivery) writes the same result.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from fringelab.core.recordings import check_budget, zip_limits
from fringelab.core.settings import Settings
from fringelab.core.specs import IngestSpec
from fringelab.core.storage import recording_dir
from fringelab.core.upload_checks import RECORDING_INGEST, claim, store
from fringelab.formats.containers import STATES_BIT_DEPTH, RecordingLayout, recording_layout
from fringelab.formats.previews import PREVIEW_FILE, THUMBNAIL_PX, PreviewWriter
from fringelab.formats.recordings import FrameSource, frame_rate_from_times, open_recording
from fringelab.formats.sidecars import frame_indices, read_board_json, read_frames_csv, read_z_csv
from fringelab.science import Cancelled, MeasurementError
from fringelab.science.chessboard import Board
from fringelab.science.quality import (
    FrameStats,
    QaWarning,
    board_visible,
    describe_frames,
    downscale,
    effective_bit_depth,
    exposure_warnings,
    frame_stats,
    full_scale,
    saturated_pct,
    to_uint8,
)
from worker.context import JobContext

MAX_REASONS = 10
PROBE_FRAMES = 5
CALIBRATION_KINDS = ("camera_calibration", "projector_calibration")


@dataclass
class Probe:
    format: str
    frame_count: int
    width_px: int
    height_px: int
    bit_depth: int
    fps: float | None


@dataclass
class Inspection:
    """What the ingest found: the facts of the recording, its sidecars, QA, and reasons it is invalid."""

    probe: Probe
    sidecar: dict[str, Any] = field(default_factory=dict)
    warnings: list[QaWarning] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    reasons: list[str] = field(default_factory=list)
    summary: dict[str, Any] = field(default_factory=dict)
    fps_header: float | None = None  # the header's rate where it differs from probe.fps (frame_rate_from_times)


def ingest_recording(context: JobContext[IngestSpec]) -> dict[str, Any]:
    recording_id = context.spec.recording_id
    with context.sessions() as session:
        recording = claim(session, RECORDING_INGEST, recording_id, job_id=context.job_id)
        path = context.settings.data_path / recording.path
        kind, duplicate_of = recording.kind, recording.duplicate_of
        camera = (recording.camera.name, recording.camera.image_width_px, recording.camera.image_height_px)
        session.commit()

    def on_probe(probe: Probe) -> None:
        _update(context, recording_id, **probe.__dict__)

    try:
        found = inspect_recording(
            path,
            kind=kind,
            settings=context.settings,
            preview_path=recording_dir(context.settings.data_path, recording_id) / PREVIEW_FILE,
            progress=context.progress,
            on_probe=on_probe,
        )
    except Cancelled:
        _update(context, recording_id, state="invalid", error="the ingest was cancelled; run it again to check it")
        raise
    except (ValueError, MeasurementError) as error:
        _update(context, recording_id, state="invalid", error=str(error))
        raise
    except Exception as error:
        _update(context, recording_id, state="invalid", error=f"internal error while checking it: {error}")
        raise
    camera_name, camera_width, camera_height = camera
    probe = found.probe
    if (probe.width_px, probe.height_px) != (camera_width, camera_height):
        found.warnings.append(
            QaWarning(
                "size_differs_from_camera",
                f"frames are {probe.width_px} × {probe.height_px} px, camera {camera_name!r} declares "
                f"{camera_width} × {camera_height} px",
            )
        )
    if duplicate_of is not None:
        found.notes.append(f"identical to recording {duplicate_of} (same SHA-256); the file is stored once")
    state = "invalid" if found.reasons else "ready"
    _update(
        context,
        recording_id,
        state=state,
        error="\n".join(found.reasons),
        sidecar=found.sidecar,
        qa={
            "warnings": [{"code": w.code, "message": w.message, "frames": list(w.frames)} for w in found.warnings],
            "notes": found.notes,
            "summary": found.summary,
            "fps_header": found.fps_header,
        },
        **probe.__dict__,
    )
    if found.reasons:
        raise ValueError("; ".join(found.reasons))
    return {"recording_id": recording_id, "state": state, "frame_count": probe.frame_count,
            "warnings": len(found.warnings)}  # fmt: skip


def _update(context: JobContext, recording_id: int, **fields: Any) -> None:
    with context.sessions() as session:
        store(session, RECORDING_INGEST, recording_id, **fields)


def inspect_recording(
    path: Path,
    *,
    kind: str,
    settings: Settings,
    preview_path: Path,
    progress: Callable[[int, int, str], None],
    on_probe: Callable[[Probe], None],
) -> Inspection:
    """Probe and check a recording frame by frame, writing its preview store. Raises ValueError when it cannot
    be opened at all; frame-level faults (corrupt frame, mixed sizes, bad sidecar) become `reasons`."""
    # Sizes before bytes: the container's headers against the budgets before frame 0 is decoded (the settings or
    # the disk may have changed since the upload), then each frame against the first one's size as it is read.
    check_budget(recording_layout(path, zip_limits=zip_limits(settings)), settings, name=path.name)
    with open_recording(path, zip_limits=zip_limits(settings), max_frame_bytes=settings.max_frame_bytes) as source:
        first = source[0]
        if first.size == 0:
            raise ValueError("frame 0 is empty (0 × 0 px)")
        found = Inspection(probe=_probe(source, first), fps_header=source.fps_header)
        found.notes.extend(source.notes)  # how the container's frames and times were read (e.g. Save Step)
        on_probe(found.probe)
        # Before the preview store is created: the frames the decoder found (a video's may differ from its
        # header's) against the cap and the disk as it is now, not as it was at upload.
        layout = RecordingLayout(source.format, len(source), found.probe.width_px, found.probe.height_px,
                                 first.dtype.itemsize)  # fmt: skip
        check_budget(layout, settings, name=path.name)
        board = _check_sidecars(source, found, kind=kind)
        writer = PreviewWriter(preview_path, frame_count=len(source))
        try:
            stats = _check_frames(
                source, found, writer, board=board, max_px=settings.preview_size_px, progress=progress
            )
            if found.reasons:
                writer.abort()
                return found
            _summarize(found, stats, kind=kind, board=board, writer=writer)
        except BaseException:
            writer.abort()
            raise
    if source.colour_converted:
        found.notes.append("colour frames converted to grey (ITU-R BT.601 luma)")
    return found


def _probe(source: FrameSource, first: np.ndarray) -> Probe:
    """Facts from the container and a few frames: the effective bit depth needs their largest value."""
    count = len(source)
    if first.dtype == np.uint16 and source.format not in STATES_BIT_DEPTH:
        peak = int(first.max())
        for index in np.unique(np.linspace(0, count - 1, min(count, PROBE_FRAMES)).round().astype(int))[1:]:
            with contextlib.suppress(ValueError):  # a frame that cannot be read is reported by the frame pass
                peak = max(peak, int(source[int(index)].max()))
        bit_depth = effective_bit_depth(peak, stored_bits=16)
    else:
        bit_depth = source.bit_depth if first.dtype == np.uint16 else 8
    height, width = first.shape
    return Probe(source.format, count, width, height, bit_depth, source.fps)


def _check_sidecars(source: FrameSource, found: Inspection, *, kind: str) -> Board | None:
    """Validate z.csv, frames.csv and board.json against the frames; return the board to look for."""
    count = found.probe.frame_count
    board: Board | None = None
    for name in ("z.csv", "frames.csv", "board.json"):
        try:
            text = source.sidecar_text(name)
            if text is None:
                continue
            if name == "z.csv":
                z_by_frame = read_z_csv(text)
                indices = frame_indices(list(z_by_frame), count, name=name)
                values = list(z_by_frame.values())
                found.sidecar[name] = {"rows": len(values), "z_mm_min": min(values), "z_mm_max": max(values)}
                _missing_rows(found, indices, count, "missing_z", "missing Z values (z.csv) for")
            elif name == "frames.csv":
                table = read_frames_csv(text)
                indices = frame_indices(table.frame, count, name=name)
                found.sidecar[name] = {"rows": len(indices), "columns": table.columns()}
                _missing_rows(found, indices, count, "missing_frame_data", "frames.csv has no row for")
                if table.time_s is not None and len(indices) > 1:
                    # frames.csv's times are the result's time axis: they give the rate (the one rule)
                    stated = found.fps_header or found.probe.fps
                    rate, differs = frame_rate_from_times(table.time_s, frame_index=indices, stated_hz=stated)
                    if rate is not None and rate != found.probe.fps:
                        found.probe.fps, found.fps_header = rate, differs
                        found.notes.append("frame rate from the time_s column of frames.csv (median step)")
            else:
                try:
                    board = read_board_json(text)
                except ValueError as error:
                    # A board file is a convenience, never a reason to refuse the recording: the board can be
                    # given in the calibration job's form, or the file replaced on the recording's page.
                    found.sidecar[name] = {"error": str(error)}
                    found.warnings.append(
                        QaWarning(
                            "board_unreadable",
                            f"{error}. The chessboard was not looked for: replace board.json on this page, or give "
                            "the board in the camera calibration job's form",
                        )
                    )
                    continue
                found.sidecar[name] = {
                    "cols": board.cols, "rows": board.rows, "square_mm": board.square_mm,
                    "origin": list(board.origin) if board.origin else None,
                }  # fmt: skip
        except ValueError as error:
            found.reasons.append(str(error) if str(error).startswith(name) else f"{name}: {error}")
    if kind in CALIBRATION_KINDS and "z.csv" not in found.sidecar and not found.reasons:
        found.warnings.append(QaWarning("missing_z", "missing Z values: no z.csv (a Z-stack calibration needs one)"))
    if kind == "test" and "frames.csv" not in found.sidecar and not found.reasons:
        found.warnings.append(
            QaWarning(
                "no_test_log",
                "no frames.csv: the frames have no punch displacement or force (times come from the recording's own "
                "stamps, if it has them); add one on this page for plots against punch travel and force",
            )
        )
    if kind == "camera_calibration" and board is None and "board.json" not in found.sidecar:
        found.warnings.append(
            QaWarning(
                "no_board",
                "no board.json: the chessboard was not looked for (add one on this page to check the frames, or "
                "give the board in the camera calibration job's form)",
            )
        )
    return board if kind == "camera_calibration" else None


def _missing_rows(found: Inspection, indices: np.ndarray, count: int, code: str, message: str) -> None:
    missing = np.setdiff1d(np.arange(count), indices)
    if missing.size:
        found.warnings.append(QaWarning(code, f"{message} {describe_frames(missing)}", tuple(int(i) for i in missing)))


def _check_frames(
    source: FrameSource,
    found: Inspection,
    writer: PreviewWriter,
    *,
    board: Board | None,
    max_px: int,
    progress: Callable[[int, int, str], None],
) -> dict[str, Any]:
    probe = found.probe
    count = probe.frame_count
    scale_dn = full_scale(probe.bit_depth)
    stats: list[FrameStats | None] = [None] * count
    board_found = np.full(count, -1, dtype=np.int8)
    decoded = 0
    for index in range(count):
        try:
            frame = source[index]
        except ValueError as error:
            if source.format in ("avi", "mp4") and index > 0:
                found.warnings.append(
                    QaWarning(
                        "frame_count_mismatch",
                        f"the video announces {count} frames; {index} could be decoded, the rest are left out",
                    )
                )
                break
            found.reasons.append(str(error))
        else:
            if frame.shape != (probe.height_px, probe.width_px):
                found.reasons.append(
                    f"{source.frame_names[index]}: {frame.shape[1]} × {frame.shape[0]} px, but frame 0 is "
                    f"{probe.width_px} × {probe.height_px} px (mixed frame sizes)"
                )
            else:
                stats[index] = frame_stats(frame)
                frame_u8 = to_uint8(frame, full_scale_dn=scale_dn)
                display = downscale(frame_u8, max_px=max_px)
                writer.write_frame(index, display=display, thumbnail=downscale(display, max_px=THUMBNAIL_PX))
                if board is not None:
                    board_found[index] = board_visible(frame_u8, cols=board.cols, rows=board.rows)
        decoded = index + 1
        if len(found.reasons) >= MAX_REASONS:
            found.reasons.append("stopped checking after the first problems")
            break
        progress(decoded, count, "checking frames")
    if decoded < count and not found.reasons:  # a video shorter than announced
        probe.frame_count = decoded
    return {"stats": stats[: probe.frame_count], "board_found": board_found[: probe.frame_count]}


def _summarize(
    found: Inspection, checked: dict[str, Any], *, kind: str, board: Board | None, writer: PreviewWriter
) -> None:
    stats: list[FrameStats] = checked["stats"]
    probe = found.probe
    if probe.format not in STATES_BIT_DEPTH and probe.bit_depth > 8:
        probe.bit_depth = effective_bit_depth(max(s.max for s in stats), stored_bits=16)
    scale_dn = full_scale(probe.bit_depth)
    mean_fraction = np.array([s.mean / scale_dn for s in stats])
    saturation = np.array([saturated_pct(s, full_scale_dn=scale_dn) for s in stats])
    contrast = np.array([s.contrast for s in stats])
    board_found = checked["board_found"]
    found.warnings[:0] = exposure_warnings(
        mean_fraction, saturation, contrast, contrast_of="board" if kind == "camera_calibration" else "stripe"
    )
    if board is not None:
        missing = np.flatnonzero(board_found == 0)
        if missing.size:
            found.warnings.append(
                QaWarning(
                    "board_not_found",
                    f"board ({board.cols} × {board.rows} inner corners) not found in {describe_frames(missing)}",
                    tuple(int(i) for i in missing),
                )
            )
    found.summary = {
        "full_scale_dn": scale_dn,
        "mean_fraction_min": round(float(mean_fraction.min()), 4),
        "mean_fraction_max": round(float(mean_fraction.max()), 4),
        "saturation_pct_max": round(float(saturation.max()), 3),
        "contrast_min": round(float(contrast.min()), 3),
        "contrast_median": round(float(np.median(contrast)), 3),
        "board_found_frames": int((board_found == 1).sum()) if board is not None else None,
    }
    writer.commit(
        frame_count=probe.frame_count,
        qa={"mean_fraction": mean_fraction, "saturation_pct": saturation, "contrast": contrast,
            "board_found": board_found},
        attrs={"width_px": probe.width_px, "height_px": probe.height_px, "full_scale_dn": scale_dn,
               "bit_depth": probe.bit_depth},
    )  # fmt: skip
