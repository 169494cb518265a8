"""Field types shared by the resource schemas."""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Annotated

from pydantic import AfterValidator


def _as_utc(moment: datetime) -> datetime:
    return moment if moment.tzinfo else moment.replace(tzinfo=UTC)  # SQLite gives back naive datetimes


UtcDatetime = Annotated[datetime, AfterValidator(_as_utc)]
"""A moment in UTC, marked as such even when the database gave it back without a time zone."""
