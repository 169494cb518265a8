"""Comparison results (a comparison job's `comparison.h5`, `fringelab.formats.comparison`) cut to what the dashboard
draws: the per-frame differences and both curves, a frame's difference or σ map within a display budget, and the
profiles through the punch axis, measured against simulated with ±σ; and the mapping form's live preview
(`POST /comparisons/preview`: what a comparison with the form's choices would pair, without running it).

Thin: the file is read through `ComparisonResult`; access follows the job's experiment. Arrays come as JSON lists
with null where nothing was compared (the frame's `reason` says why for a frame without a simulation partner).
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Query
from pydantic import BaseModel, ConfigDict, Field

from backend.api.deps import CurrentUser, JobDep, SessionDep, StateDep
from backend.errors import error_responses
from backend.result_files import listed, succeeded_file
from backend.schemas.common import GridExtentOut
from backend.schemas.jobs import MAX_ID, RESULT_ERRORS
from fringelab.core.errors import Gone, Invalid
from fringelab.core.jobs import job_error
from fringelab.core.models import Job
from fringelab.core.simulations import preview_comparison
from fringelab.core.specs import ComparisonSpec
from fringelab.formats.comparison import FRAME_COLUMNS, SIMULATION_COLUMNS, ComparisonResult
from fringelab.formats.hdf5 import json_text
from fringelab.formats.topography import GRID_BUDGET_NODES, ResultUnavailable
from fringelab.science.compare import in_form_terms

router = APIRouter(tags=["results"])
COMPARISON_FILE = "comparison.h5"


@contextmanager
def comparison(job: Job, data_path: Any) -> Iterator[ComparisonResult]:
    """The file of a succeeded comparison job, open; a job error (404/409/410) with what to do otherwise."""
    path = succeeded_file(job, data_path, kind="comparison", name=COMPARISON_FILE)
    try:
        reader = ComparisonResult(path)
    except (ResultUnavailable, ValueError) as error:
        raise job_error(Gone, "result_missing", str(error)) from None
    with reader:
        yield reader


def _position(reader: ComparisonResult, frame: int) -> int:
    try:
        return reader.position(frame)
    except ValueError as error:
        raise job_error(Invalid, "frame_not_in_result", str(error), field="frame") from None


def _in_form_terms(mapping: dict[str, Any]) -> dict[str, Any]:
    """The mapping with its notes naming settings as the mapping form and the job spec do (not the CLI's options)."""
    return {**mapping, "notes": [in_form_terms(note) for note in mapping.get("notes", [])]}


class ComparisonOverview(BaseModel):
    job_id: str
    alignment: str = Field(description="displacement, time or peak: how frames were paired with states.")
    mapping: dict[str, Any] = Field(
        description="Every mapping choice; `detected` lists those detected, with notes (settings named as in the spec)."
    )
    frames: dict[str, list[Any]] = Field(
        description="Per frame: frame, state_lo (−1: no partner), n_nodes, reason, the measured test log, the "
        "simulated blend (sim_*), rms_diff_mm, max_diff_mm, mean_diff_mm, fraction_beyond_2sigma; null: not compared."
    )
    simulation: dict[str, list[float | None]] = Field(
        description="Per simulation state: time_s, punch_displacement_mm, force_kN, peak_w_mm (null: none)."
    )
    grid: dict[str, float | int]


@router.get("/jobs/{job_id}/comparison", response_model=ComparisonOverview, responses=RESULT_ERRORS)
def comparison_overview(job: JobDep, state: StateDep) -> ComparisonOverview:
    """The per-frame differences (RMS, largest, mean, share beyond 2σ) with both sides' test log and peak
    deflection (for the frame slider and the peak and force curves of measurement and simulation), the
    simulation's own curves per state, and the mapping used."""
    with comparison(job, state.settings.data_path) as reader:
        frames: dict[str, list[Any]] = {
            "frame": reader.frames.astype(int).tolist(),
            "state_lo": reader.column("state_lo").astype(int).tolist(),
            "n_nodes": reader.column("n_nodes").astype(int).tolist(),
            "reason": reader.column("reason").tolist(),
        }
        for name, _, _ in FRAME_COLUMNS:
            frames[name] = listed(reader.column(name), 6)
        simulation = {name: listed(reader.column(f"simulation/{name}"), 6) for name, _, _ in SIMULATION_COLUMNS}
        return ComparisonOverview(
            job_id=job.id,
            alignment=str(reader.file.attrs.get("alignment", "")),
            mapping=_in_form_terms(json.loads(json.dumps(reader.mapping, default=str))),
            frames=frames,
            simulation=simulation,
            grid=GridExtentOut.of(reader.grid).model_dump(),
        )


class ComparisonGridOut(BaseModel):
    frame: int
    field: str
    step: int = Field(description="Grid nodes per returned node along each axis (1: full resolution).")
    x_mm: list[float]
    y_mm: list[float]
    values_mm: list[list[float | None]] = Field(description="[iy][ix], mm; null where nothing was compared.")


@router.get("/jobs/{job_id}/comparison/grid", response_model=ComparisonGridOut, responses=RESULT_ERRORS)
def comparison_grid(
    job: JobDep,
    state: StateDep,
    frame: Annotated[int, Query(ge=0, le=MAX_ID, description="Recording frame index.")],
    field: Literal["diff_mm", "sigma_w_mm", "w_meas_mm", "w_sim_mm"] = "diff_mm",
    budget: Annotated[int, Query(ge=8, le=2000, description="Largest number of nodes per side.")] = GRID_BUDGET_NODES,
) -> ComparisonGridOut:
    """One frame's difference map w_meas − w_sim (or σ_w, or either side), block-averaged (NaN-aware) to at
    most `budget` nodes per side."""
    with comparison(job, state.settings.data_path) as reader:
        x, y, values, step = reader.field_cut(field, _position(reader, frame), budget=budget)
    return ComparisonGridOut(
        frame=frame, field=field, step=step, x_mm=listed(x), y_mm=listed(y), values_mm=listed(values)
    )


class ComparisonProfileOut(BaseModel):
    frame: int
    axis: str
    s_mm: list[float | None]
    x_mm: list[float | None]
    y_mm: list[float | None]
    measured_mm: list[float | None]
    simulated_mm: list[float | None]
    sigma_mm: list[float | None] = Field(description="σ_w of the measurement (the ±σ band); null: not known.")


@router.get("/jobs/{job_id}/comparison/profile", response_model=ComparisonProfileOut, responses=RESULT_ERRORS)
def comparison_profile(
    job: JobDep,
    state: StateDep,
    frame: Annotated[int, Query(ge=0, le=MAX_ID, description="Recording frame index.")],
    axis: Literal["x", "y"] = "x",
) -> ComparisonProfileOut:
    """The profile through the punch axis along X or Y: measured and simulated deflection with σ_w."""
    with comparison(job, state.settings.data_path) as reader:
        profile = reader.profile(axis, _position(reader, frame))
    return ComparisonProfileOut(frame=frame, axis=axis, **{name: listed(values) for name, values in profile.items()})


class ComparisonPreviewIn(BaseModel):
    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={
            "examples": [
                {
                    "spec": {"kind": "comparison", "job_id": "6f1c2b8e-2d4a-4f6e-9a51-3c7d0e9b2f10", "simulation_id": 1,
                             "align": "displacement", "units": "mm", "symmetry": "quarter"},
                    "frame": 5,
                }
            ]
        },
    )  # fmt: skip

    spec: ComparisonSpec = Field(description="The comparison job's spec as the form has it now (format is ignored).")
    frame: int | None = Field(
        None, ge=0, le=MAX_ID, description="Recording frame of the profiles; empty: the most deflected paired frame."
    )


class PreviewProfile(BaseModel):
    s_mm: list[float | None]
    x_mm: list[float | None]
    y_mm: list[float | None]
    measured_mm: list[float | None]
    simulated_mm: list[float | None]
    sigma_mm: list[float | None] = Field(description="σ_w of the measurement from its edge noise; null: not known.")


class ComparisonPreviewOut(BaseModel):
    frame: int = Field(description="The recording frame the profiles are of.")
    alignment: str
    mapping: dict[str, Any] = Field(description="Every mapping choice as resolved; `detected` lists those detected.")
    overlap_fraction: float = Field(description="Share of the model's area the measurement covers.")
    axis_xy_mm: list[float] = Field(description="The measured punch axis the profiles run through, mm.")
    frames: dict[str, list[Any]] = Field(
        description="Per frame: frame, state_lo (−1: no partner), state_fraction, reason (why not paired), peak_w_mm."
    )
    simulation: dict[str, Any] = Field(description="n_states, and peak_w_mm per state.")
    profiles: dict[str, PreviewProfile] = Field(description="Through the punch axis along X (`x`) and Y (`y`).")


@router.post(
    "/comparisons/preview",
    response_model=ComparisonPreviewOut,
    tags=["simulations"],
    responses=error_responses(401, 404, 409, 422),
)
def preview_comparison_route(body: ComparisonPreviewIn, session: SessionDep, state: StateDep,
                             principal: CurrentUser) -> ComparisonPreviewOut:  # fmt: skip
    """What a comparison with these mapping choices would compare, without running it: the mapping resolved (the
    detected choices named), each frame's partner state or why it has none, and the measured and simulated
    profiles through the punch axis. A choice that cannot work is a 422 naming the form's setting to change."""
    preview = preview_comparison(session, state.settings, principal, body.spec, frame=body.frame)
    frames = preview["frames"]
    return ComparisonPreviewOut(
        frame=preview["frame"], alignment=preview["alignment"],
        mapping=json.loads(json_text(preview["mapping"])), overlap_fraction=preview["overlap_fraction"],
        axis_xy_mm=[float(v) for v in preview["axis_xy_mm"]],
        frames={"frame": frames["frame"], "state_lo": frames["state_lo"], "reason": frames["reason"],
                "state_fraction": listed(frames["state_fraction"], 4), "peak_w_mm": listed(frames["peak_w_mm"], 4)},
        simulation={"n_states": preview["simulation"]["n_states"],
                    "peak_w_mm": listed(preview["simulation"]["peak_w_mm"], 4)},
        profiles={axis: PreviewProfile(**{name: listed(values) for name, values in profile.items()})
                  for axis, profile in preview["profiles"].items()},
    )  # fmt: skip
