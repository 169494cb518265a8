"""The OpenAPI document is complete enough to generate a client from: every operation says how it fails (401 when
it takes a token, `{"detail", "code"}` bodies), every request body has an example, every success has a schema or
is a 204, a file or an event stream, and every reference resolves."""

from __future__ import annotations

import json
from collections.abc import Iterator
from typing import Any

import pytest

from backend.app import create_app

# Public on purpose: health for monitors, login, the tus capability probe, and the method documentation (the same
# text ships in the repository's docs/, so the help pages also work on the login page).
PUBLIC = {
    ("get", "/api/v1/health"),
    ("post", "/api/v1/auth/login"),
    ("options", "/api/v1/uploads"),
    ("get", "/api/v1/docs"),
    ("get", "/api/v1/docs/{name}"),
}
METHODS = ("get", "put", "post", "delete", "options", "head", "patch")
# Error answers whose body is not {detail, code}, and why: a failing health check answers with the health report
# itself (which part is down), for monitors and load balancers.
OTHER_ERROR_BODIES = {("get", "/api/v1/health", "503")}
# Successes that are not JSON: files, images, event streams.
BINARY_MEDIA = ("application/octet-stream", "application/offset+octet-stream", "image/png", "text/event-stream")


@pytest.fixture(scope="module")
def document(tmp_path_factory) -> dict[str, Any]:
    from fringelab.core.settings import Settings

    settings = Settings(_env_file=None, data_dir=tmp_path_factory.mktemp("var"), redis_url="redis://127.0.0.1:9/0")  # type: ignore[call-arg]
    return create_app(settings.model_copy(update={"auth_enabled": True})).openapi()


def operations(document: dict[str, Any]) -> Iterator[tuple[str, str, dict[str, Any]]]:
    for path, item in document["paths"].items():
        for method in METHODS:
            if method in item:
                yield method, path, item[method]


def resolve(document: dict[str, Any], schema: dict[str, Any]) -> dict[str, Any]:
    while "$ref" in schema:
        schema = document["components"]["schemas"][schema["$ref"].rsplit("/", 1)[1]]
    return schema


def has_example(document: dict[str, Any], media: dict[str, Any]) -> bool:
    if "example" in media or media.get("examples"):
        return True
    schema = resolve(document, media.get("schema", {}))
    if schema.get("examples") or "example" in schema:
        return True
    variants = schema.get("oneOf") or schema.get("anyOf")
    return bool(variants) and all(has_example(document, {"schema": variant}) for variant in variants)


def test_every_operation_says_how_it_fails(document):
    problems = []
    for method, path, operation in operations(document):
        name = f"{method.upper()} {path}"
        responses = operation.get("responses", {})
        if (method, path) in PUBLIC:
            if operation.get("security"):
                problems.append(f"{name}: public but asks for a token")
        elif not {"401", "429"} <= set(responses) or not operation.get("security"):
            problems.append(f"{name}: takes a token but documents no 401 or 429 (or no security scheme)")
        for status, response in responses.items():
            if int(status) < 400 or (method, path, status) in OTHER_ERROR_BODIES:
                continue
            schema = resolve(document, response.get("content", {}).get("application/json", {}).get("schema", {}))
            if not {"detail", "code"} <= set(schema.get("required", [])):
                problems.append(f"{name} {status}: no {{detail, code}} body schema")
            if not response.get("description"):
                problems.append(f"{name} {status}: no description")
        if "requestBody" in operation and "422" not in responses:
            problems.append(f"{name}: takes a body but documents no 422")
    assert not problems, "\n".join(problems)


def test_every_request_body_has_an_example(document):
    problems = []
    for method, path, operation in operations(document):
        for media_type, media in operation.get("requestBody", {}).get("content", {}).items():
            if media_type in BINARY_MEDIA:
                if resolve(document, media.get("schema", {})).get("format") != "binary":
                    problems.append(f"{method.upper()} {path}: {media_type} body not declared as binary")
            elif not has_example(document, media):
                problems.append(f"{method.upper()} {path}: {media_type} body has no example")
    assert not problems, "\n".join(problems)


def test_every_success_has_a_schema_or_is_empty_a_file_or_a_stream(document):
    problems = []
    for method, path, operation in operations(document):
        for status, response in operation["responses"].items():
            if not status.startswith("2"):
                continue
            content = response.get("content", {})
            if not content:
                # 204, or an answer that is all headers (HEAD, tus) and says so
                if status != "204" and not response.get("headers") and method != "head":
                    problems.append(f"{method.upper()} {path} {status}: no content, no headers")
                continue
            for media_type, media in content.items():
                if media_type in BINARY_MEDIA:
                    continue
                if not resolve(document, media.get("schema", {})):
                    problems.append(f"{method.upper()} {path} {status}: {media_type} without a schema")
    assert not problems, "\n".join(problems)


def test_every_reference_resolves_and_ids_are_unique(document):
    text = json.dumps(document)
    names = {part.split('"')[0] for part in text.split('"#/components/schemas/')[1:]}
    assert names <= set(document["components"]["schemas"]), names - set(document["components"]["schemas"])
    ids = [operation["operationId"] for _, _, operation in operations(document)]
    assert len(ids) == len(set(ids))
    for method, path, operation in operations(document):
        assert operation.get("summary") and operation.get("tags"), f"{method.upper()} {path}"


def test_operation_ids_read_as_names(document):
    import re

    ids = [operation["operationId"] for _, _, operation in operations(document)]
    assert len(ids) == len(set(ids)), "operation ids must be unique"
    for name in ids:
        assert re.fullmatch(r"[a-z]+(_[a-z0-9]+)*", name) and "api_v1" not in name, name
    from backend.openapi import OPERATION_IDS

    unnamed = sorted(set(ids) - set(OPERATION_IDS.values()))
    assert not unnamed, f"routes without a reviewed operation id (add them to backend.openapi.OPERATION_IDS): {unnamed}"
    by_route = {(method, path): operation["operationId"] for method, path, operation in operations(document)}
    assert by_route[("post", "/api/v1/jobs")] == "create_job"
    assert by_route[("get", "/api/v1/jobs/{job_id}/topography/grid")] == "get_topography_grid"
    assert by_route[("get", "/api/v1/jobs/{job_id}")] == "get_job"


def test_a_served_process_builds_the_document_before_its_first_request(settings, monkeypatch):
    """Issue 26: the first `openapi()` of a process took 0.7-9.6 s under load, paid by whichever request asked;
    `app_from_env` (what uvicorn serves) builds it in the lifespan, so it exists before any request."""
    from fastapi.testclient import TestClient

    from backend.app import app_from_env

    for name, value in {
        "FRINGELAB_DATA_DIR": str(settings.data_path),
        "FRINGELAB_REDIS_URL": settings.redis_url,
    }.items():
        monkeypatch.setenv(name, value)
    app = app_from_env()
    assert app.openapi_schema is None  # not built by the factory: the lifespan does it
    with TestClient(app):
        assert app.openapi_schema is not None
        assert "401" in app.openapi_schema["paths"]["/api/v1/jobs"]["get"]["responses"]  # the completed one
