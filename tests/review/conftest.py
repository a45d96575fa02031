"""The review loop runs the real teacher code on tiny random-weight models saved locally."""

import pytest

from app.core.models import Role
from tests.teacher_app import client, settings, teacher_weights

__all__ = ["client", "people", "settings", "teacher_weights"]


@pytest.fixture
def people(make_user) -> dict[str, str]:  # type: ignore[no-untyped-def]
    """Tokens of two reviewers and an annotator."""
    return {
        "reviewer": make_user("rita", Role.reviewer)[1],
        "other": make_user("otto", Role.reviewer)[1],
        "annotator": make_user("anna", Role.annotator)[1],
    }
