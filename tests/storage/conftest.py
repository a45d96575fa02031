from tests.teacher_app import teacher_weights  # noqa: F401
