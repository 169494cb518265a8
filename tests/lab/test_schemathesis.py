"""Generated requests for every operation of the OpenAPI document (schemathesis, property-based): with accounts on
and an admin's token, no request makes a 500, and every answer matches the document (status code, content type,
headers, body schema)."""

from __future__ import annotations

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
from backend.auth import create_user, issue_token
from backend.db import make_engine, make_sessionmaker
from backend.models import ApiToken, User

pytestmark = [pytest.mark.integration, pytest.mark.slow]
# tus PATCH bodies are plain bytes, as for application/octet-stream
schemathesis.serializer.alias("application/offset+octet-stream", "application/octet-stream")


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
EXAMPLES_PER_OPERATION = 25  # ~50 operations: about a minute here


@pytest.fixture
def api_schema(lab_settings):
    return schemathesis.openapi.from_asgi("/api/openapi.json", create_app(lab_settings))


@pytest.fixture
def admin(lab_settings):
    """An admin's token, and a reset that undoes what a generated request may do to it (disable, demote, revoke)."""
    engine = make_engine(lab_settings.resolved_database_url)
    sessions = make_sessionmaker(engine)
    with sessions() as session:
        user = create_user(session, "root", "root-password", role="admin")
        token, secret = issue_token(session, user, name="schemathesis")
        session.commit()
        ids = user.id, token.id

    def reset() -> None:
        with sessions() as session:
            session.execute(update(User).where(User.id == ids[0]).values(disabled=False, role="admin"))
            session.execute(update(ApiToken).where(ApiToken.id == ids[1]).values(revoked_at=None, expires_at=None))
            session.commit()

    yield {"Authorization": f"Bearer {secret}"}, reset
    engine.dispose()


def test_generated_requests_get_documented_answers(api_schema, admin):
    headers, reset = admin
    findings, checked, sent = [], [], []
    for result in api_schema.get_all_operations():
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
    assert len(checked) >= 39, checked
