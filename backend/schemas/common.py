"""Field types and parts shared by the resource schemas."""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Annotated

from pydantic import AfterValidator, BaseModel

from fringelab.core.text import calendar_date, plain_free_text, plain_name
from fringelab.science.fields import Grid


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


class GridExtentOut(BaseModel):
    """Where a result's grid lies and how fine it is (the `grid` of the topography and comparison overviews).

    The overviews declare `grid` as a plain object (`dict`, as before this type existed) so that their OpenAPI
    document did not change; this model is the one place its keys are written."""

    x_min_mm: float
    x_max_mm: float
    y_min_mm: float
    y_max_mm: float
    nx: int
    ny: int
    step_mm: float

    @classmethod
    def of(cls, grid: Grid) -> GridExtentOut:
        x, y = grid.x_mm, grid.y_mm
        return cls(
            x_min_mm=float(x[0]), x_max_mm=float(x[-1]), y_min_mm=float(y[0]), y_max_mm=float(y[-1]),
            nx=int(x.size), ny=int(y.size), step_mm=float(x[1] - x[0]) if x.size > 1 else 0.0,
        )  # fmt: skip
