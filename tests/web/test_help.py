"""The manual in the app: Help in the header opens the page's topic, /help renders with every
other host unreachable and nothing blocked by the Content-Security-Policy."""

from __future__ import annotations

from typing import Any

import pytest

from tests.pages import login, shoot
from tests.web.server import LiveServer

pytestmark = [pytest.mark.browser]


def test_help_opens_the_topic_of_each_page_and_works_offline(page: Any, server: LiveServer) -> None:
    elsewhere: list[str] = []

    def only_this_server(route: Any) -> None:
        if route.request.url.startswith(server.url):
            route.continue_()
        else:
            elsewhere.append(route.request.url)
            route.abort()

    page.route("**/*", only_this_server)
    login(page, server, "anna")
    page.goto(f"{server.url}/models")
    assert page.get_attribute("[data-testid=help-student]", "href") == "/help/guides/student"
    page.click("[data-testid=nav-help]")
    page.wait_for_selector("[data-testid=manual-page]")
    assert page.url == f"{server.url}/help/guides/student"
    assert page.inner_text("[data-testid=manual-page] h1") == "The student and active learning"
    assert page.get_attribute("[data-testid=nav-help]", "aria-current") == "page"

    page.goto(f"{server.url}/frames/1")
    assert page.get_attribute("[data-testid=nav-help]", "href") == "/help/guides/reviewing"
    assert page.get_attribute("[data-testid=help-reviewing]", "href") == "/help/guides/reviewing"
    page.goto(f"{server.url}/help/guides/reviewing")
    picture = page.locator("[data-testid=manual-page] img").first
    picture.wait_for()
    assert page.evaluate("(img) => img.complete && img.naturalWidth", picture.element_handle())
    shoot(page, "help-reviewing")
    page.goto(f"{server.url}/help/reference/settings")
    page.wait_for_selector("[data-testid=manual-page] table")
    shoot(page, "help-settings")
    page.click("[data-testid=manual-nav] >> text=Weights")
    page.wait_for_selector("h1:has-text('Weights')")
    assert page.url == f"{server.url}/help/getting-started/weights"
    page.goto(f"{server.url}/help/")
    page.wait_for_selector("[data-testid=manual-page] h1")
    shoot(page, "help")
    assert elsewhere == []


def test_the_login_page_names_the_users_page(browser: Any, server: LiveServer) -> None:
    context = browser.new_context()
    try:
        tab = context.new_page()
        tab.goto(f"{server.url}/login")
        assert "Users" in tab.inner_text("[data-testid=login-hint]")
    finally:
        context.close()
