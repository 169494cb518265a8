"""Errors of the API as `{"detail": "...", "code": "..."}` with a 4xx status, whoever raises them.

Routes and services raise `ApiError(status, code, detail)`; `HTTPException`s from FastAPI, Starlette and
tuspyserver get a code from their status; validation errors keep FastAPI's list of problems as `detail`.
"""

from __future__ import annotations

from fastapi import FastAPI, HTTPException, Request
from fastapi.encoders import jsonable_encoder
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException

CODE_OF_STATUS = {
    400: "bad_request",
    401: "unauthorized",
    403: "forbidden",
    404: "not_found",
    405: "method_not_allowed",
    409: "conflict",
    410: "gone",
    412: "precondition_failed",
    413: "too_large",
    415: "unsupported_media_type",
    422: "invalid",
    503: "unavailable",
}


class ApiError(HTTPException):
    """A failure the client must act on; `code` is stable and machine-readable, `detail` is for people.

    An HTTPException, so that code written for those (tuspyserver's request handling) lets it through.
    """

    def __init__(self, status_code: int, code: str, detail: str, *, headers: dict[str, str] | None = None):
        super().__init__(status_code, detail, headers)
        self.code = code


def error_response(status_code: int, code: str, detail: object, headers: dict[str, str] | None = None) -> JSONResponse:
    return JSONResponse({"detail": jsonable_encoder(detail), "code": code}, status_code=status_code, headers=headers)


def install_error_handlers(app: FastAPI) -> None:
    @app.exception_handler(ApiError)
    async def api_error(_request: Request, error: ApiError) -> JSONResponse:
        return error_response(error.status_code, error.code, str(error.detail), error.headers)

    @app.exception_handler(StarletteHTTPException)
    async def http_error(_request: Request, error: StarletteHTTPException) -> JSONResponse:
        code = CODE_OF_STATUS.get(error.status_code, "error" if error.status_code >= 500 else "http_error")
        return error_response(error.status_code, code, str(error.detail), dict(error.headers or {}) or None)

    @app.exception_handler(RequestValidationError)
    async def validation_error(_request: Request, error: RequestValidationError) -> JSONResponse:
        return error_response(422, "invalid_request", error.errors())
