"""Generated requests against the jobs and results routes (schemathesis, from the OpenAPI schema): whatever comes
in, the answer is a documented status, never a 500."""

from __future__ import annotations

import pytest
import schemathesis
from hypothesis import HealthCheck, given
from hypothesis import settings as hypothesis_settings

from backend.app import create_app

pytestmark = pytest.mark.slow


def test_no_request_makes_a_500(settings):
    app = create_app(settings.model_copy(update={"reconcile_interval_s": 0.0}))
    schema = schemathesis.openapi.from_asgi("/api/openapi.json", app).include(path_regex="^/api/v1/(jobs|calibrations)")
    checked = []
    for result in schema.get_all_operations():
        operation = result.ok()
        if operation.path.endswith("/events"):
            continue  # a stream that lasts as long as its job

        @given(case=operation.as_strategy())
        @hypothesis_settings(
            max_examples=25, deadline=None, suppress_health_check=list(HealthCheck), database=None, derandomize=True
        )
        def answers_without_a_500(case: schemathesis.Case) -> None:
            response = case.call()
            assert response.status_code != 500, (case.method, case.formatted_path, case.body, case.query, response.text)
            if response.status_code >= 400 and response.status_code != 422:
                assert {"detail", "code"} <= set(response.json()), response.text

        answers_without_a_500()
        checked.append(f"{operation.method.upper()} {operation.path}")
    assert len(checked) >= 15, checked
