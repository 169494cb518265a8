"""Simulations: a finite-element model uploaded into an experiment, with what its reader found in it."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from backend.schemas.common import UtcDatetime

SimulationState = Literal["checking", "ready", "failed"]


class SimulationOut(BaseModel):
    """A simulation: `checking` until its check job has read it in a worker, then `ready` with its format and what
    it holds, or `failed` with the reason in `error`. Only a ready one can be compared."""

    model_config = ConfigDict(from_attributes=True)

    id: int
    experiment_id: int
    filename: str = Field(description="The name it was uploaded under (a ZIP for folder formats).")
    state: SimulationState = Field(description="checking (its check job reads it), ready, or failed (see error).")
    error: str = Field(description="Why its check failed; empty otherwise.")
    check_job_id: str | None = Field(description="Its check job (GET /api/v1/jobs/{id}: progress and log).")
    kind: str = Field(description="d3plot, vtu, pvd, exodus or csv: the model format read (empty while checking).")
    size_bytes: int
    sha256: str
    n_states: int = Field(description="States (time steps) of the model.")
    n_nodes: int
    info: dict[str, Any] = Field(
        description="time [first, last] in the model's time unit, length_unit and time_unit_s where declared "
        "(null: detected at comparison), has_punch_displacement, has_force, n_shells, n_solids."
    )
    created_at: UtcDatetime
