"""HTTP answers of errors: domain errors (`fringelab.core.errors`) to statuses and `{"detail", "code"}`; never a
bare 500."""

from __future__ import annotations

import logging

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from pydantic import BaseModel
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

    @app.exception_handler(Exception)
    async def _unexpected(request: Request, error: Exception) -> JSONResponse:
        log.exception("unexpected error on %s %s", request.method, request.url.path)
        return JSONResponse(
            {"detail": f"internal error ({type(error).__name__}); the server log has the details", "code": "internal"},
            status_code=500,
        )


def jsonable(errors: object) -> object:
    from fastapi.encoders import jsonable_encoder

    return jsonable_encoder(errors, custom_encoder={Exception: str})
