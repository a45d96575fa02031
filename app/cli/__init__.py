"""The ``weldpool`` command line (``app.cli:main``): one module per domain registers its
commands on the group defined in ``base``."""

from app.cli import evaluation, frames, review, service, stream, student, teacher, users
from app.cli.base import main

__all__ = [
    "evaluation",
    "frames",
    "main",
    "review",
    "service",
    "stream",
    "student",
    "teacher",
    "users",
]
