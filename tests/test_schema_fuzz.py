"""Schemathesis over the OpenAPI schema, as an admin, on SQLite and PostgreSQL: no answer is a
5xx, and every answer (status, content type, body) is one the schema documents.

Bounded: ``WELDPOOL_FUZZ_EXAMPLES`` examples per operation (default 5 in the suite; `.ci/run`
runs a deeper pass). Jobs are queued but no worker runs them, and the teacher has no weights
here, so the fuzzer cannot start minutes of model work.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from typing import Any

import pytest
import schemathesis
from fastapi.testclient import TestClient
from hypothesis import HealthCheck, settings
from schemathesis.specs.openapi.checks import positive_data_acceptance

from app.core.models import Role
from app.main import create_app
from tests.helpers import auth

EXAMPLES = int(os.environ.get("WELDPOOL_FUZZ_EXAMPLES", "5"))


@pytest.fixture
def fuzz_app(settings: Any, session_factory: Any) -> Iterator[Any]:
    app = create_app(settings)  # no embedded worker
    with TestClient(app):  # run the lifespan once (the reaper thread)
        yield app


@pytest.fixture
def admin_headers(make_user) -> dict[str, str]:
    return auth(make_user("fuzzer", Role.admin)[1])


def test_the_api_answers_as_its_schema_says(fuzz_app: Any, admin_headers: dict[str, str]) -> None:
    """Every operation, ``EXAMPLES`` generated requests each; all failures are listed."""
    from hypothesis import given

    schema = schemathesis.openapi.from_asgi("/api/v1/openapi.json", fuzz_app, headers=admin_headers)
    failures: list[str] = []
    operations = 0
    for result in schema.get_all_operations():
        operation = result.ok()
        operations += 1

        @given(case=operation.as_strategy())
        @settings(
            max_examples=EXAMPLES,
            deadline=None,
            suppress_health_check=list(HealthCheck),
            derandomize=True,
            database=None,
        )
        def check(case: Any) -> None:
            # Rules across fields that OpenAPI cannot state (frame_ids or next, a multipart
            # `files` part, mm_per_px or scale_points) answer a documented 400 / 422 to data the
            # schema alone allows: not a failure. Every other check runs.
            case.call_and_validate(
                headers=admin_headers, excluded_checks=[positive_data_acceptance]
            )

        try:
            check()
        except (Exception, BaseExceptionGroup) as exc:  # collect every operation that failed
            failures.append(f"{operation.label}: {str(exc)[:1500]}")
    assert operations > 20
    assert not failures, "\n\n".join(failures)
