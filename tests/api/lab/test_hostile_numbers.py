"""Generated requests (schemathesis) for every operation, with numbers JSON cannot hold put in: NaN, Infinity,
-Infinity and integers beyond 64 bits in every numeric field of a JSON body, and in every integer path or query
parameter (issue 16, finding 9). Schemathesis itself never generates them; no answer may be a 500, and every 4xx
body is `{"detail", "code"}` JSON (the 422 handler used to raise while writing NaN back)."""

from __future__ import annotations

import json
import re
from typing import Any

import pytest
import schemathesis
from fastapi.testclient import TestClient
from hypothesis import HealthCheck, Phase, given
from hypothesis import settings as hypothesis_settings

from backend.app import create_app
from fringelab.core.accounts import create_user, issue_token
from fringelab.core.db import make_engine, make_sessionmaker

pytestmark = [pytest.mark.integration, pytest.mark.slow]
schemathesis.serializer.alias("application/offset+octet-stream", "application/octet-stream")  # tus PATCH bodies

HOSTILE = ("NaN", "Infinity", "-Infinity", str(2**70), "-" + str(2**64), "1e400")
_NUMBER_MARK = "\u0000hostile-number\u0000"


def _numbers_replaced(body: Any) -> list[str]:
    """JSON texts of `body` with each of its number leaves (all at once) replaced by each HOSTILE literal, plus
    the literals as whole bodies; a body without numbers gets one added."""

    def mark(value: Any) -> Any:
        if isinstance(value, bool):
            return value
        if isinstance(value, int | float):
            return _NUMBER_MARK
        if isinstance(value, dict):
            return {key: mark(item) for key, item in value.items()} or {"n": _NUMBER_MARK}
        if isinstance(value, list):
            return [mark(item) for item in value] or [_NUMBER_MARK]
        return value

    marked = json.dumps(mark(body) if isinstance(body, dict | list) else {"n": _NUMBER_MARK})
    if _NUMBER_MARK not in marked:
        marked = marked[:-1] + (", " if len(marked) > 2 else "") + f'"n": "{_NUMBER_MARK}"' + "}"
    quoted = json.dumps(_NUMBER_MARK)
    return [marked.replace(quoted, literal) for literal in HOSTILE] + list(HOSTILE)


def test_nan_infinity_and_huge_integers_never_make_a_500(lab_settings):
    settings = lab_settings.model_copy(update={"reconcile_interval_s": 0.0})
    engine = make_engine(settings.resolved_database_url)
    with make_sessionmaker(engine)() as session:
        secret = issue_token(session, create_user(session, "root", "root-password", role="admin"))[1]
        session.commit()
    engine.dispose()
    app = create_app(settings)
    schema = schemathesis.openapi.from_asgi("/api/openapi.json", app)
    headers = {"Authorization": f"Bearer {secret}"}
    failures: list[str] = []
    sent = 0
    with TestClient(app) as client:
        for result in schema.get_all_operations():
            sent += _try_operation(client, result.ok(), headers, failures)
    print(f"hostile numbers: {sent} requests, {len(failures)} failures")
    assert sent > 100
    assert not failures, "\n".join(failures)


def _try_operation(client: TestClient, operation: Any, headers: dict[str, str], failures: list[str]) -> int:
    """Send one generated case of `operation` with hostile numbers in each place; returns the requests sent."""
    method = operation.method.upper()
    sent = 0

    @given(case=operation.as_strategy())
    @hypothesis_settings(max_examples=1, deadline=None, derandomize=True, database=None,
                         suppress_health_check=list(HealthCheck), phases=[Phase.generate])  # fmt: skip
    def hostile(case: schemathesis.Case) -> None:
        nonlocal sent
        path = case.formatted_path
        query = dict(case.query or {})
        requests: list[tuple[str, dict[str, Any]]] = []
        if method in ("POST", "PUT", "PATCH") and case.media_type == "application/json":
            json_headers = {**headers, "Content-Type": "application/json"}
            requests += [(path, {"content": text, "headers": json_headers, "params": query})
                         for text in _numbers_replaced(case.body)]  # fmt: skip
        for value in (case.path_parameters or {}).values():
            if isinstance(value, int) and not isinstance(value, bool):
                for literal in ("NaN", str(2**70)):
                    target = re.sub(rf"/{value}(?=/|$)", f"/{literal}", path, count=1)
                    requests.append((target, {"headers": headers, "params": query}))
        for name, value in query.items():
            if isinstance(value, int | float) and not isinstance(value, bool):
                for literal in ("NaN", "Infinity", str(2**70)):
                    requests.append((path, {"headers": headers, "params": {**query, name: literal}}))
        for target, options in requests:
            if (
                "content" not in options
                and method in ("POST", "PUT", "PATCH")
                and case.media_type == "application/json"
            ):
                options["json"] = case.body
            answer = client.request(method, target, **options)
            sent += 1
            if answer.status_code >= 500 and not (target.endswith("/health") and answer.status_code == 503):
                shown = str(options.get("content", options.get("params")))[:200]
                failures.append(f"{method} {target} {shown}: {answer.status_code} {answer.text[:300]}")
            elif answer.status_code >= 400 and "json" in answer.headers.get("content-type", ""):
                assert {"detail", "code"} <= set(answer.json()), answer.text

    hostile()
    return sent
