"""Experiments: one physical test (plate, punch, date, notes), its owner and whom it is shared with."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, StringConstraints
from sqlalchemy.orm import Session

from backend.schemas.common import CALENDAR_DATE, MAX_ID, PLAIN_NAME, PlainText, UtcDatetime
from fringelab.core.accounts import Principal, access_level
from fringelab.core.models import Experiment

Name = Annotated[str, StringConstraints(strip_whitespace=True, min_length=1, max_length=200), PLAIN_NAME]
Label = Annotated[str, StringConstraints(strip_whitespace=True, max_length=200), PLAIN_NAME]
TestDate = Annotated[str, StringConstraints(pattern=r"^(\d{4}-\d{2}-\d{2})?$"), CALENDAR_DATE]
GroupAccess = Literal["read", "write"]
Access = Literal["admin", "owner", "write", "read"]

_GROUP_ID = "A group (`GET /api/v1/groups`) whose members may read the experiment, or write it with group_access."
_GROUP_ACCESS = "What the group may do: read (see everything, change nothing) or write (also upload, start jobs, edit)."


class ExperimentCreate(BaseModel):
    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={
            "examples": [
                {
                    "name": "plate 3",
                    "plate": "AA7075-T651, 2 mm",
                    "punch": "hemispherical, 20 mm",
                    "test_date": "2026-11-20",
                    "notes": "drop tower, 4.2 m/s",
                    "group_id": None,
                    "group_access": "read",
                }  # fmt: skip
            ]
        },
    )

    name: Name
    plate: Label = ""
    punch: Label = ""
    test_date: TestDate = Field("", description="YYYY-MM-DD, or empty.")
    notes: PlainText = Field("", max_length=20_000)
    group_id: int | None = Field(None, ge=1, le=MAX_ID, description=_GROUP_ID)
    group_access: GroupAccess = Field("read", description=_GROUP_ACCESS)


class ExperimentUpdate(BaseModel):
    """Fields to change; those left out keep their value. `group_id: null` stops sharing. Only the owner or an
    admin may change group_id and group_access; a group member with write access may change the rest."""

    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={"examples": [{"notes": "punch 20 mm, 4.2 m/s"}, {"group_id": 1, "group_access": "write"}]},
    )

    name: Name | None = None
    plate: Label | None = None
    punch: Label | None = None
    test_date: TestDate | None = None
    notes: PlainText | None = Field(None, max_length=20_000)
    group_id: int | None = Field(None, ge=1, le=MAX_ID, description=_GROUP_ID + " null: not shared.")
    group_access: GroupAccess | None = Field(None, description=_GROUP_ACCESS)


class ExperimentOut(BaseModel):
    id: int
    name: str
    plate: str
    punch: str
    test_date: str
    notes: str
    owner_id: int | None = Field(description="The user who created it; null when made with accounts off.")
    owner: str | None = Field(description="The owner's username.")
    group_id: int | None = Field(description="The group it is shared with, or null.")
    group: str | None = Field(description="That group's name.")
    group_access: GroupAccess
    access: Access = Field(description="What you may do with it: admin or owner (everything), write, or read.")
    created_at: UtcDatetime
    updated_at: UtcDatetime


def experiment_out(session: Session, principal: Principal, experiment: Experiment) -> ExperimentOut:
    """The API's view of an experiment, with what the caller may do with it (call inside its session)."""
    return ExperimentOut(
        id=experiment.id,
        name=experiment.name,
        plate=experiment.plate,
        punch=experiment.punch,
        test_date=experiment.test_date,
        notes=experiment.notes,
        owner_id=experiment.owner_id,
        owner=experiment.owner.username if experiment.owner else None,
        group_id=experiment.group_id,
        group=experiment.group.name if experiment.group else None,
        group_access="write" if experiment.group_access == "write" else "read",
        access=access_level(session, principal, experiment) or "read",
        created_at=experiment.created_at,
        updated_at=experiment.updated_at,
    )
