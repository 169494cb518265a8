"""Simulations: a finite-element model uploaded into an experiment, with what its reader found in it."""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict, Field

from backend.schemas.common import UtcDatetime


class SimulationOut(BaseModel):
    """A simulation that reads (only those are registered): its format, size and what it holds."""

    model_config = ConfigDict(from_attributes=True)

    id: int
    experiment_id: int
    filename: str = Field(description="The name it was uploaded under (a ZIP for folder formats).")
    kind: str = Field(description="d3plot, vtu, pvd, exodus or csv: the model format read.")
    size_bytes: int
    sha256: str
    n_states: int = Field(description="States (time steps) of the model.")
    n_nodes: int
    info: dict[str, Any] = Field(
        description="time [first, last] in the model's time unit, length_unit and time_unit_s where declared "
        "(null: detected at comparison), has_punch_displacement, has_force, n_shells, n_solids."
    )
    created_at: UtcDatetime
