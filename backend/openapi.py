"""The OpenAPI document as clients are generated from it: what FastAPI derives from the routes, completed.

FastAPI documents what a route declares. What no single route can declare is added here, to the document, so
that a new route is documented the same way without anyone remembering to:

- 401 and 429 on every operation that takes a token (it has `security`: it depends on `get_principal`, which
  counts the user's requests, `backend.limits`);
- 413 on every operation with a request body outside the upload routes (`backend.limits.BodySizeLimit`);
- 422 with the body our handler sends (`{"detail", "code", "errors"}`), not FastAPI's default shape;
- the `{"detail", "code"}` schema on every error response that has none;
- the tus routes, which tuspyserver generates bare: their headers, the PATCH body and the answers (and its
  trailing-slash twins of `/uploads` left out: one path per operation).

What a route knows best (403, 404, 409, its examples) stays declared on the route.
"""

from __future__ import annotations

import json
from http import HTTPStatus
from typing import Any

from fastapi import FastAPI
from pydantic import BaseModel, Field

from backend.errors import ErrorBody

UPLOADS = "/api/v1/uploads"
ERROR_REF = {"$ref": "#/components/schemas/ErrorBody"}
METHODS = ("get", "put", "post", "delete", "options", "head", "patch", "trace")


class ValidationErrorBody(BaseModel):
    """A request the server cannot process: it does not match the schema (`invalid_input`, with `errors` for
    programs), or a value is not acceptable (another `code`, e.g. `unknown_group`)."""

    detail: str = Field(description="What is wrong, naming the field(s).")
    code: str = Field(description="`invalid_input` for a schema mismatch, or the specific problem.")
    errors: list[dict[str, Any]] | None = Field(
        None, description="With `invalid_input`: pydantic's errors (`loc`, `msg`, `type`, ...)."
    )


DESCRIPTIONS = {
    401: "Missing, unknown, expired or revoked token, or a disabled account; `detail` says which.",
    403: "Not allowed: an admin route, or read-only access to a shared experiment (`code` says which).",
    413: "The request body is larger than FRINGELAB_MAX_JSON_BYTES.",
    422: "The request does not match the schema; `detail` names each field.",
    429: "This user sent more than FRINGELAB_USER_REQUESTS_PER_S requests per second (beyond a burst of "
    "FRINGELAB_USER_REQUEST_BURST); wait the `Retry-After` seconds and send it again.",
}


# Operation ids as a generated client's method names: verb_noun, from the route function's name (FastAPI's
# default glues on the path and method: `read_job_api_v1_jobs__job_id__get`). One table, so a client's names are
# reviewed in one place; a route missing here gets its function's name, and tests/api/lab/test_openapi.py fails.
OPERATION_IDS = {
    "health": "get_health",
    "login": "login", "logout": "logout", "me": "get_me",
    "list_tokens": "list_tokens", "create_token": "create_token", "revoke_token": "revoke_token",
    "list_users": "list_users", "add_user": "create_user", "update_user": "update_user",
    "list_groups": "list_groups", "add_group": "create_group", "audit_trail": "list_audit_events",
    "create_experiment": "create_experiment", "list_experiments": "list_experiments",
    "read_experiment": "get_experiment", "patch_experiment": "update_experiment",
    "remove_experiment": "delete_experiment",
    "create_camera": "create_camera", "list_cameras": "list_cameras", "read_camera": "get_camera",
    "update_camera": "update_camera", "remove_camera": "delete_camera",
    "list_recordings": "list_recordings", "list_camera_recordings": "list_camera_recordings",
    "read_recording": "get_recording", "update_recording": "update_recording",
    "remove_recording": "delete_recording", "reingest_recording": "reingest_recording",
    "put_sidecar": "put_recording_sidecar", "frame_png": "get_recording_frame", "recording_qa": "get_recording_qa",
    "download_recording": "download_recording",
    "tus_options": "get_upload_options", "extension_creation_route": "create_upload",
    "core_head_route": "get_upload_offset", "core_patch_route": "append_upload",
    "extension_termination_route": "delete_upload", "put_recording": "upload_recording",
    "start_job": "create_job", "list_jobs": "list_jobs", "job_specs": "get_job_specs", "read_job": "get_job",
    "read_log": "get_job_log",
    "job_events": "stream_job_events", "cancel": "cancel_job", "retry": "retry_job",
    "download": "download_job_file",
    "list_calibrations": "list_calibrations", "read_calibration": "get_calibration",
    "calibration_report": "get_calibration_report", "projector_table_curves": "get_projector_table",
    "calibration_file": "download_calibration_file",
    "topography_overview": "get_topography", "topography_grid": "get_topography_grid",
    "topography_profile": "get_topography_profile", "topography_history": "get_topography_history",
    "camera_against_camera": "get_camera_against_camera", "list_calibration_pairs": "list_calibration_pairs",
    "make_demo": "create_demo",
    "experiment_deletion": "preview_experiment_deletion", "camera_deletion": "preview_camera_deletion",
    "recording_deletion": "preview_recording_deletion", "job_deletion": "preview_job_deletion",
    "jobs_events": "stream_jobs_events", "remove_job": "delete_job",
    "projector_calibration_report": "get_projector_calibration_report",
    "procam_report": "get_procam_calibration_report", "scan_view": "get_scan",
    "list_docs": "list_docs", "read_doc": "get_doc", "queue": "get_queue", "storage": "get_storage",
    "put_simulation": "upload_simulation", "list_simulations": "list_simulations",
    "read_simulation": "get_simulation", "remove_simulation": "delete_simulation",
    "comparison_overview": "get_comparison", "comparison_grid": "get_comparison_grid",
    "comparison_profile": "get_comparison_profile", "preview_comparison_route": "preview_comparison",
}  # fmt: skip


def operation_id(route: Any) -> str:
    """The operationId of a route (FastAPI's `generate_unique_id_function`): its name in OPERATION_IDS. Routes
    outside the document (the dashboard's files) and tuspyserver's trailing-slash twins, which `complete` leaves
    out, get names of their own so no two collide."""
    if not getattr(route, "include_in_schema", True):
        return str(route.name)
    if route.path.endswith("/") and route.path.startswith(UPLOADS):
        return f"{OPERATION_IDS.get(route.name, route.name)}_twin"
    # A route not in the table yet keeps its function's name (a test lists it, so it gets a reviewed one).
    return OPERATION_IDS.get(route.name, route.name)


def install_openapi(app: FastAPI) -> None:
    """Make `app.openapi()` return the completed document (built once, on first use)."""
    generate = app.openapi

    def openapi() -> dict[str, Any]:
        if app.openapi_schema is None:
            document = generate()
            complete(document)
            app.openapi_schema = document
        return app.openapi_schema

    app.openapi = openapi  # type: ignore[method-assign]


def complete(document: dict[str, Any]) -> None:
    schemas = document.setdefault("components", {}).setdefault("schemas", {})
    schemas.setdefault("ErrorBody", ErrorBody.model_json_schema())
    schemas["ValidationErrorBody"] = ValidationErrorBody.model_json_schema()
    document["paths"].pop(UPLOADS + "/", None)
    for path, path_item in document["paths"].items():
        for method in METHODS:
            operation = path_item.get(method)
            if operation is None:
                continue
            responses = operation.setdefault("responses", {})
            if operation.get("security"):
                responses.setdefault("401", {})
                responses.setdefault("429", {})
            if "requestBody" in operation and not path.startswith(UPLOADS):
                responses.setdefault("413", {})
            if path in TUS_OPERATIONS.get(method, {}):
                _describe_tus(operation, TUS_OPERATIONS[method][path])
            for status, response in responses.items():
                _complete_error(int(status) if status.isdigit() else 0, response)
    _drop_unused(document, ("HTTPValidationError", "ValidationError"))


def _complete_error(status: int, response: dict[str, Any]) -> None:
    if status < 400:
        return
    if status == 422:
        response["content"] = {"application/json": {"schema": {"$ref": "#/components/schemas/ValidationErrorBody"}}}
    else:
        # errors are JSON even on routes that answer files or event streams (FastAPI gives them the route's type)
        declared = next((media.get("schema") for media in response.get("content", {}).values()), None)
        response["content"] = {"application/json": {"schema": declared or ERROR_REF}}
    if not response.get("description") or response["description"] in ("Validation Error", "Additional Response"):
        response["description"] = DESCRIPTIONS.get(status) or HTTPStatus(status).phrase


def _drop_unused(document: dict[str, Any], names: tuple[str, ...]) -> None:
    """Remove FastAPI's own validation error schemas once nothing refers to them (in order: the first refers to
    the second)."""
    schemas = document["components"]["schemas"]
    for name in names:
        if f'"#/components/schemas/{name}"' not in json.dumps(document):
            schemas.pop(name, None)


# ---------------------------------------------------------------------------------------------- tus


def _header(name: str, description: str, *, example: str | None = None) -> dict[str, Any]:
    return {"description": description, "schema": {"type": "string", **({"example": example} if example else {})}}


_OFFSET = _header("Upload-Offset", "Bytes the server has; the next PATCH starts here.", example="1048576")
_RESUMABLE = _header("Tus-Resumable", "The tus version: 1.0.0.", example="1.0.0")
TUS_OPERATIONS: dict[str, dict[str, dict[str, Any]]] = {
    "options": {
        "/api/v1/uploads": {
            "summary": "tus capabilities",
            "responses": {
                "204": {
                    "description": "The server's tus version, extensions and largest upload.",
                    "headers": {
                        "Tus-Version": _header("Tus-Version", "Supported versions.", example="1.0.0"),
                        "Tus-Extension": _header("Tus-Extension", "Supported extensions."),
                        "Tus-Max-Size": _header("Tus-Max-Size", "FRINGELAB_MAX_UPLOAD_BYTES."),
                    },
                }
            },
        }
    },
    "post": {
        "/api/v1/uploads": {
            "summary": "Create a resumable upload (tus)",
            "description": "Start a tus 1.0 upload of a recording. `Upload-Metadata` carries `filename`, `filetype`, "
            "`camera_id` and `kind` (base64 values, tus style); the camera's experiment must be writable. Then "
            "PATCH the bytes to `Location`.",
            "required_headers": ("tus-resumable", "upload-length", "upload-metadata"),
            "responses": {
                "201": {
                    "description": "Created; `Location` is the upload's URL.",
                    "headers": {"Location": _header("Location", "URL of the new upload."), "Tus-Resumable": _RESUMABLE},
                },
                "400": {},
                "403": {},
                "404": {},
                "412": {},
                "413": {},
                "415": {},
            },
        }
    },
    "head": {
        "/api/v1/uploads/{uuid}": {
            "summary": "Offset of an upload (resume from here)",
            "description": "How many bytes the server has (`Upload-Offset`) of your upload; someone else's is a 404.",
            "required_headers": ("tus-resumable",),
            "responses": {
                "200": {
                    "description": "The offset to resume from, and the length.",
                    "headers": {"Upload-Offset": _OFFSET, "Upload-Length": _header("Upload-Length", "Total bytes.")},
                },
                "404": {},
                "410": {},
                "412": {},
            },
        }
    },
    "patch": {
        "/api/v1/uploads/{uuid}": {
            "summary": "Append bytes to an upload (tus)",
            "description": "Append the body at `Upload-Offset`. The PATCH that completes the upload turns it into a "
            "recording (its ingest starts) and answers with `Fringelab-Recording-Id`.",
            "required_headers": ("tus-resumable", "upload-offset", "content-type"),
            "drop_parameters": ("post_request",),
            "requestBody": {
                "required": True,
                "content": {"application/offset+octet-stream": {"schema": {"type": "string", "format": "binary"}}},
            },
            "responses": {
                "204": {
                    "description": "Appended; `Upload-Offset` is the new offset.",
                    "headers": {
                        "Upload-Offset": _OFFSET,
                        "Fringelab-Recording-Id": _header(
                            "Fringelab-Recording-Id", "On the last PATCH: the recording made of the upload."
                        ),
                    },
                },
                "400": {},
                "404": {},
                "409": {},
                "410": {},
                "412": {},
                "413": {},
                "415": {},
            },
        }
    },
    "delete": {
        "/api/v1/uploads/{uuid}": {
            "summary": "Abandon an upload (tus termination)",
            "required_headers": ("tus-resumable",),
            "responses": {"204": {"description": "Removed with its bytes."}, "404": {}, "412": {}},
        }
    },
}


def _describe_tus(operation: dict[str, Any], spec: dict[str, Any]) -> None:
    for key in ("summary", "description", "requestBody"):
        if key in spec:
            operation[key] = spec[key]
    required = spec.get("required_headers", ())
    dropped = spec.get("drop_parameters", ())
    parameters = [p for p in operation.get("parameters", []) if p["name"] not in dropped]
    for parameter in parameters:
        if parameter["in"] == "header" and parameter["name"].lower() in required:
            parameter["required"] = True
    operation["parameters"] = parameters
    responses = operation.setdefault("responses", {})
    for status, response in spec["responses"].items():
        responses[status] = dict(response)  # success answers of tus carry headers, never a JSON body
