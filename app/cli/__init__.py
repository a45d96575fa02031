"""The ``weldpool`` command line (``app.cli:main``): one module per domain registers its
commands on the group defined in ``base``, imported when one of its commands runs
(``base.COMMANDS``)."""

from app.cli.base import main

__all__ = ["main"]
