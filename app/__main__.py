"""``python -m app`` is the ``weldpool`` command."""

from app.cli import main

if __name__ == "__main__":  # not when a spawned process (the label import's) imports it again
    main()
