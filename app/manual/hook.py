"""The mkdocs hook (``hooks:`` in mkdocs.yml): each page's markers expanded from the code, as
/help expands them (``reference.expand``)."""

from __future__ import annotations

import sys
import tempfile
from functools import cache
from pathlib import Path
from typing import Any

# mkdocs loads this file by its path: the repository it sits in is the one documented.
sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from app.manual.reference import expand


@cache
def openapi_schema() -> dict[str, Any]:
    """The app's OpenAPI schema, from an app made on a throw-away home (nothing is served)."""
    from app.core.config import Settings
    from app.main import create_app

    with tempfile.TemporaryDirectory() as home:
        return create_app(Settings(home=Path(home))).openapi()


def on_page_markdown(markdown: str, **_: Any) -> str:
    return expand(markdown, openapi_schema)
