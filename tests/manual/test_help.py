"""/help: the manual of docs/ served by the app, every page of mkdocs.yml's nav, its links and
pictures on this server only, generated reference pages that hold what the code has."""

from __future__ import annotations

import re
from typing import Any

from fastapi.testclient import TestClient

from app.core.config import Settings
from app.core.models import Role
from app.manual.pages import nav, url_of
from app.manual.reference import cli_commands

HREF = re.compile(r'(?:href|src)="([^"#]*)(?:#[^"]*)?"')
LOADED = re.compile(r'(?:src="|<link[^>]*href=")([^"]*)"')


def _urls(items: Any) -> list[str]:
    found = []
    for item in items:
        found += [item.url] if item.url else _urls(item.children)
    return found


def test_every_page_of_the_nav_renders_and_loads_only_from_this_server(
    client: TestClient, make_user: Any
) -> None:
    _, token = make_user("ann", Role.annotator)
    headers = {"Authorization": f"Bearer {token}"}
    seen: set[str] = set()
    for url in _urls(nav()):
        page = client.get(url, headers=headers)
        assert page.status_code == 200, url
        assert 'data-testid="manual-page"' in page.text
        for loaded in LOADED.findall(page.text):  # pictures, scripts, styles: no network
            assert not loaded.startswith(("http://", "https://", "//")), (url, loaded)
        for target in HREF.findall(page.text):
            if target.startswith("/help") and target not in seen:
                seen.add(target)
                assert client.get(target, headers=headers).status_code == 200, (url, target)
    assert "/help/images/closed-loop.png" in seen


def test_help_needs_a_login_and_reads_nothing_outside_docs(
    client: TestClient, make_user: Any
) -> None:
    assert client.get("/help/", headers={"Accept": "application/json"}).status_code == 401
    _, token = make_user("ann", Role.annotator)
    headers = {"Authorization": f"Bearer {token}"}
    for path in ("/help/nothing-here", "/help/../app/config", "/help/%2e%2e/pyproject.png"):
        assert client.get(path, headers=headers).status_code == 404, path
    picture = client.get("/help/images/closed-loop.png", headers=headers)
    assert picture.status_code == 200 and picture.headers["content-type"] == "image/png"


def test_reference_pages_hold_every_setting_command_and_route(
    client: TestClient, make_user: Any
) -> None:
    _, token = make_user("ann", Role.annotator)
    headers = {"Authorization": f"Bearer {token}"}
    settings_page = client.get("/help/reference/settings", headers=headers).text
    for name in Settings.model_fields:
        assert f"WELDPOOL_{name.upper()}" in settings_page
    cli_page = client.get("/help/reference/cli", headers=headers).text
    for command in cli_commands():
        assert command in cli_page
    api_page = client.get("/help/reference/api", headers=headers).text
    for path in client.app.openapi()["paths"]:  # type: ignore[attr-defined]
        assert f"<code>{path}</code>" in api_page


def test_a_page_url_is_its_file() -> None:
    assert url_of("index.md") == "/help/"
    assert url_of("getting-started/index.md") == "/help/getting-started/"
    assert url_of("guides/reviewing.md") == "/help/guides/reviewing"


def test_each_page_s_help_topic_is_a_page_and_heading_of_the_manual() -> None:
    from app.manual.pages import render_page
    from app.web.routes import HELP_TOPICS

    for page, url in HELP_TOPICS.items():
        path, _, anchor = url.removeprefix("/help/").partition("#")
        html = render_page(path, dict).html
        assert not anchor or f'id="{anchor}"' in html, (page, url)
