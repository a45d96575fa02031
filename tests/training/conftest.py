"""The training domain runs against the app with the real teacher on tiny random-weight models."""

from tests.teacher_app import client, settings, teacher_weights

__all__ = ["client", "settings", "teacher_weights"]
