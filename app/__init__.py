"""app: the weldpool service (REST API, browser UI, database, job queue, CLI)."""

import sys

if "structlog" not in sys.modules and "rich" not in sys.modules:
    # structlog draws tracebacks with rich when it can import it (rich comes with typer, which
    # transformers requires), and importing rich brings attrs and pygments: ~30 ms a start. Our
    # logs turn exceptions into plain text before rendering (`app.core.logs`), so rich would draw
    # nothing: hide it while structlog is imported (None in sys.modules makes an import fail).
    sys.modules["rich"] = None  # type: ignore[assignment]
    try:
        import structlog  # noqa: F401
    finally:
        del sys.modules["rich"]
