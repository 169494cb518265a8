"""Domain errors: a request that cannot be done, for a reason its sender can act on.

Raised by core services and the worker's job checks; `detail` is for people (what happened and what to do),
`code` for programs, `field` names the input at fault where there is one. No HTTP here: the API maps each class
to a status in one table (`backend.errors.HTTP_STATUS`).
"""

from __future__ import annotations


class DomainError(Exception):
    """Base of every error a client must act on; on its own: a malformed request."""

    code = "bad_request"

    def __init__(
        self, detail: str, *, code: str | None = None, field: str | None = None, retry_after_s: float | None = None
    ) -> None:
        super().__init__(detail)
        self.detail = detail
        self.code = code or type(self).code
        self.field = field
        self.retry_after_s = retry_after_s
        self.names_field = field is not None  # the answer has a `field` key (jobs' answers always have one)


class Unauthorized(DomainError):
    """No valid login or token."""

    code = "unauthorized"


class Forbidden(DomainError):
    """Known, but not allowed to do this (a read-only member writing, a member doing an admin's task)."""

    code = "forbidden"


class NotFound(DomainError):
    """No such thing, or one the caller may not see (answered alike: no oracle)."""

    code = "not_found"


class Conflict(DomainError):
    """Not in the state this needs (a job still running, a name taken, a recording in use)."""

    code = "conflict"


class Gone(DomainError):
    """It existed, but its files are no longer there."""

    code = "gone"


class TooLarge(DomainError):
    """Over a size limit or the free disk."""

    code = "too_large"


class UnsupportedFormat(DomainError):
    """A file of a kind fringelab does not read."""

    code = "unsupported_format"


class Invalid(DomainError):
    """Well-formed, but its values cannot be used (a frame beyond the recording, a calibration of another camera)."""

    code = "invalid"


class RateLimited(DomainError):
    """Too many attempts; `retry_after_s` says when to try again."""

    code = "too_many_requests"


class Unavailable(DomainError):
    """A part the request needs (the queue, the database) does not answer; try again later."""

    code = "service_unavailable"
