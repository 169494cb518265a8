"""HTTP answers of errors: domain errors (`fringelab.core.errors`) to statuses and `{"detail", "code"}`; never a
bare 500."""

from __future__ import annotations

import logging
import math

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from pydantic import BaseModel, Field
from sqlalchemy.exc import DataError
from starlette.exceptions import HTTPException

from fringelab.core.errors import (
    Conflict,
    DomainError,
    Forbidden,
    Gone,
    Invalid,
    NotFound,
    RateLimited,
    TooLarge,
    Unauthorized,
    Unavailable,
    UnsupportedFormat,
)

log = logging.getLogger(__name__)


class ErrorBody(BaseModel):
    detail: str
    code: str
    job_id: str | None = Field(
        None, description="With `duplicate_job` (409): the id of the identical job already queued or running."
    )


# The one place where domain errors become HTTP statuses (the most specific class wins).
HTTP_STATUS: dict[type[DomainError], int] = {
    Unauthorized: 401,
    Forbidden: 403,
    NotFound: 404,
    Conflict: 409,
    Gone: 410,
    TooLarge: 413,
    UnsupportedFormat: 415,
    Invalid: 422,
    RateLimited: 429,
    Unavailable: 503,
    DomainError: 400,
}


def http_status(error: DomainError) -> int:
    if isinstance(error, HTTPException):  # a domain error carried through a library that only passes these on
        return error.status_code
    return next(HTTP_STATUS[cls] for cls in type(error).__mro__ if cls in HTTP_STATUS)


def error_headers(error: DomainError) -> dict[str, str] | None:
    if isinstance(error, Unauthorized):
        return {"WWW-Authenticate": "Bearer"}
    if error.retry_after_s is not None:
        return {"Retry-After": str(max(1, round(error.retry_after_s)))}
    return None


def error_json(error: DomainError) -> JSONResponse:
    """`{"detail", "code"}` (and `field` where the error names one) with the error's status."""
    body: dict[str, str | None] = {"detail": error.detail, "code": error.code}
    if error.names_field:
        body["field"] = error.field
    if getattr(error, "job_id", None) is not None:  # errors that skip DomainError.__init__ have none
        body["job_id"] = error.job_id
    return JSONResponse(body, status_code=http_status(error), headers=error_headers(error))


# Codes of HTTPExceptions raised by FastAPI, Starlette and tuspyserver (tus protocol errors).
HTTP_ERROR_CODES = {
    400: "bad_request",
    404: "not_found",
    405: "method_not_allowed",
    409: "conflict",
    410: "gone",
    412: "precondition_failed",
    413: "payload_too_large",
    415: "unsupported_media_type",
    503: "service_unavailable",
}


def error_responses(*codes: int) -> dict[int | str, dict[str, object]]:
    """OpenAPI `responses=` entries for the given status codes, all with the ErrorBody schema."""
    return {code: {"model": ErrorBody} for code in codes}


def install_error_handlers(app: FastAPI) -> None:
    @app.exception_handler(DomainError)
    async def _domain_error(_request: Request, error: DomainError) -> JSONResponse:
        return error_json(error)

    @app.exception_handler(HTTPException)
    async def _http_error(_request: Request, error: HTTPException) -> JSONResponse:
        code = HTTP_ERROR_CODES.get(error.status_code, "error")
        return JSONResponse(
            {"detail": str(error.detail), "code": code}, status_code=error.status_code, headers=error.headers
        )

    @app.exception_handler(RequestValidationError)
    async def _validation_error(_request: Request, error: RequestValidationError) -> JSONResponse:
        problems = []
        for item in error.errors():
            where = ".".join(str(part) for part in item["loc"] if part != "body")
            problems.append(f"{where}: {item['msg']}")
        return JSONResponse(
            {"detail": "; ".join(problems), "code": "invalid_input", "errors": jsonable(error.errors())},
            status_code=422,
        )

    @app.exception_handler(OverflowError)
    @app.exception_handler(DataError)
    async def _out_of_range(request: Request, error: Exception) -> JSONResponse:
        # A number the database cannot hold (an id beyond its integer type) that no validator caught: the
        # request is wrong, not the server.
        log.warning("number out of range on %s %s: %s", request.method, request.url.path, error)
        return JSONResponse(
            {"detail": "a number in the request is out of range for the database", "code": "out_of_range"},
            status_code=422,
        )

    @app.exception_handler(Exception)
    async def _unexpected(request: Request, error: Exception) -> JSONResponse:
        log.exception("unexpected error on %s %s", request.method, request.url.path)
        return JSONResponse(
            {"detail": f"internal error ({type(error).__name__}); the server log has the details", "code": "internal"},
            status_code=500,
        )


def jsonable(errors: object) -> object:
    """Validation errors as JSON that can always be written: the inputs they quote may hold NaN, Infinity,
    bytes or huge integers, which JSON cannot (writing them raised inside this very handler, a 500)."""
    from fastapi.encoders import jsonable_encoder

    return _finite(jsonable_encoder(errors, custom_encoder={Exception: str, bytes: _bytes_text}))


def _bytes_text(data: bytes) -> str:
    return data[:200].decode("utf-8", "replace")


def _finite(value: object) -> object:
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) > 2**53:
        return str(value)
    if isinstance(value, dict):
        return {str(key): _finite(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(item) for item in value]
    if isinstance(value, str) and len(value) > 1000:
        return value[:1000] + "…"
    return value
