"""``python -m app`` is the ``weldpool`` command."""

from app.cli import main

main()
