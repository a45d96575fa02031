"""The review loop runs the real teacher code on tiny random-weight models saved locally."""

from tests.teacher_app import client, settings, teacher_weights

__all__ = ["client", "settings", "teacher_weights"]
