"""Shapes shared by every resource: the error body."""

from __future__ import annotations

from pydantic import BaseModel


class ErrorBody(BaseModel):
    """Every 4xx answer: what went wrong for a person, and a stable code for a program."""

    detail: str
    code: str


def error_responses(*statuses: int) -> dict[int | str, dict[str, object]]:
    """OpenAPI `responses` entries for the given error statuses."""
    return {status: {"model": ErrorBody} for status in statuses}
