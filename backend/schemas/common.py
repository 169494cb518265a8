"""Field types shared by the resource schemas."""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Annotated

from pydantic import AfterValidator

from fringelab.core.text import calendar_date, plain_free_text, plain_name


def _as_utc(moment: datetime) -> datetime:
    return moment if moment.tzinfo else moment.replace(tzinfo=UTC)  # SQLite gives back naive datetimes


MAX_ID = 2**31 - 1
"""Ids and frame numbers are 32-bit integers in the database (PostgreSQL `integer`); larger ones are a 422."""

UtcDatetime = Annotated[datetime, AfterValidator(_as_utc)]
"""A moment in UTC, marked as such even when the database gave it back without a time zone."""

PLAIN_NAME = AfterValidator(plain_name)
"""No control characters, direction marks or lone surrogates (`fringelab.core.text`): a 422 naming the character."""
PlainText = Annotated[str, AfterValidator(plain_free_text)]
"""Free text (notes): line breaks and tabs allowed, other control characters not."""
CALENDAR_DATE = AfterValidator(calendar_date)
"""`YYYY-MM-DD` that names a real day, or empty."""
