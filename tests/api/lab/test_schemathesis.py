"""Generated requests for every operation of the OpenAPI document (schemathesis, property-based), on a lab server
(accounts on, an admin's token) and on a laptop (accounts off): no request makes a 500, and every answer matches
the document (status code, content type, headers, body schema; error bodies are `{"detail", "code"}`).

Nothing is excluded: the tus PATCH body is sent as bytes, and an event stream of a job that does not exist is a
404 (no generated id names a real job). This replaces the jobs-only contract test that tests/worker had."""

from __future__ import annotations

from collections.abc import Callable, Iterator

import pytest
import schemathesis
from hypothesis import HealthCheck, Phase, given
from hypothesis import settings as hypothesis_settings
from schemathesis.specs.openapi.checks import (
    content_type_conformance,
    response_headers_conformance,
    response_schema_conformance,
    status_code_conformance,
)
from sqlalchemy import update

from backend.app import create_app
from fringelab.core.accounts import create_user, issue_token
from fringelab.core.db import make_engine, make_sessionmaker
from fringelab.core.models import ApiToken, User
from fringelab.core.settings import Settings

pytestmark = [pytest.mark.integration, pytest.mark.slow]
# tus PATCH bodies are plain bytes, as for application/octet-stream
schemathesis.serializer.alias("application/offset+octet-stream", "application/octet-stream")
EXAMPLES_PER_OPERATION = 10  # ~56 operations x 2 modes: about a minute on a loaded 2-core machine


@schemathesis.check
def no_internal_error(ctx, response, case) -> None:  # type: ignore[no-untyped-def]
    """A 500 is a bug (the health check's 503 is its answer when a part is down: documented, not a failure)."""
    if response.status_code == 500:
        raise AssertionError(f"500 Internal Server Error: {response.text[:500]}")


CHECKS = [
    no_internal_error,
    status_code_conformance,
    content_type_conformance,
    response_headers_conformance,
    response_schema_conformance,
]


@pytest.fixture(params=["lab server", "laptop"])
def mode(request, lab_settings) -> Iterator[tuple[Settings, dict[str, str], Callable[[], None]]]:  # type: ignore[no-untyped-def]
    """Settings, headers and a reset to run before each request. On the lab server the headers carry an admin's
    token, and the reset undoes what a generated request may do to it (disable, demote, revoke)."""
    # No background sweep mid-test; a jobs-list event stream (which only ends when its lifetime is up) ends soon.
    settings = lab_settings.model_copy(update={"reconcile_interval_s": 0.0, "list_events_s": 0.3})
    if request.param == "laptop":
        yield settings.model_copy(update={"auth_enabled": False}), {}, lambda: None
        return
    engine = make_engine(settings.resolved_database_url)
    sessions = make_sessionmaker(engine)
    with sessions() as session:
        user = create_user(session, "root", "root-password", role="admin")
        token, secret = issue_token(session, user, name="schemathesis")
        session.commit()
        user_id, token_id = user.id, token.id

    def reset() -> None:
        with sessions() as session:
            session.execute(update(User).where(User.id == user_id).values(disabled=False, role="admin"))
            session.execute(update(ApiToken).where(ApiToken.id == token_id).values(revoked_at=None, expires_at=None))
            session.commit()

    yield settings, {"Authorization": f"Bearer {secret}"}, reset
    engine.dispose()


def test_generated_requests_get_documented_answers(mode):
    settings, headers, reset = mode
    schema = schemathesis.openapi.from_asgi("/api/openapi.json", create_app(settings))
    findings, checked, sent = [], [], []
    for result in schema.get_all_operations():
        operation = result.ok()

        @given(case=operation.as_strategy())
        @hypothesis_settings(
            max_examples=EXAMPLES_PER_OPERATION,
            deadline=None,
            derandomize=True,  # the same requests on every run: a failure here is a regression, not bad luck
            database=None,
            suppress_health_check=list(HealthCheck),
            phases=[Phase.explicit, Phase.generate],  # no shrinking: the first failing request is reported as is
        )
        def documented_answers(case: schemathesis.Case) -> None:
            reset()
            sent.append(1)
            case.call_and_validate(headers=headers, checks=CHECKS)

        name = f"{operation.method.upper()} {operation.path}"
        try:
            documented_answers()
        except (Exception, BaseExceptionGroup) as error:  # every operation is tried; all findings are listed at the end
            findings.append(f"{name}: {str(error)[:1500]}")
        checked.append(name)
    print(f"schemathesis: {len(checked)} operations, {len(sent)} requests, {len(findings)} findings")
    assert not findings, "\n\n".join(findings)
    assert len(checked) >= 56, checked  # every operation of the document, jobs and results included
