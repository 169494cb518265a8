"""Experiments: one physical test (plate, punch, date, notes)."""

from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field, StringConstraints

from backend.schemas.common import UtcDatetime

Name = Annotated[str, StringConstraints(strip_whitespace=True, min_length=1, max_length=200)]
Label = Annotated[str, StringConstraints(strip_whitespace=True, max_length=200)]
TestDate = Annotated[str, StringConstraints(pattern=r"^(\d{4}-\d{2}-\d{2})?$")]


class ExperimentCreate(BaseModel):
    model_config = ConfigDict(extra="forbid")

    name: Name
    plate: Label = ""
    punch: Label = ""
    test_date: TestDate = Field("", description="YYYY-MM-DD, or empty.")
    notes: str = Field("", max_length=20_000)


class ExperimentUpdate(BaseModel):
    """Fields to change; those left out keep their value."""

    model_config = ConfigDict(extra="forbid")

    name: Name | None = None
    plate: Label | None = None
    punch: Label | None = None
    test_date: TestDate | None = None
    notes: str | None = Field(None, max_length=20_000)


class ExperimentOut(BaseModel):
    model_config = ConfigDict(from_attributes=True)

    id: int
    name: str
    plate: str
    punch: str
    test_date: str
    notes: str
    created_at: UtcDatetime
    updated_at: UtcDatetime
