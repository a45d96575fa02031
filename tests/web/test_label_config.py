"""The label configuration page in the browser: an admin adds classes, attributes and frame
tags beside the built-in pool; the save is a new version the API reads back."""

from __future__ import annotations

from typing import Any

import pytest

from tests.pages import accept_dialogs, login, shoot
from tests.web.server import LiveServer

pytestmark = [pytest.mark.browser, pytest.mark.slow]


def _add(
    page: Any, name: str, kind: str, hotkey: str, attributes: str = "", points: str = ""
) -> None:
    page.click("[data-testid=add-class]")
    row = page.locator("[data-testid=class-row]").last
    row.locator("[data-testid=class-name]").fill(name)
    row.locator("[data-testid=class-kind]").select_option(kind)
    row.locator("[data-testid=class-hotkey]").fill(hotkey)
    row.locator("[data-testid=class-attributes]").fill(attributes)
    if points:  # the field opens for a points class alone
        row.locator("[data-testid=class-points]").fill(points)


def test_an_admin_configures_wire_tip_spatter_and_a_tag(page: Any, server: LiveServer) -> None:
    accept_dialogs(page)
    login(page, server, "ada")
    page.click("[data-testid=nav-label-config]")
    page.wait_for_url(f"{server.url}/label-config")
    page.wait_for_selector("body[data-ready]")
    start = server.api("GET", "/label-config", user="ada").json()["version"]
    assert page.locator("[data-testid=class-row]").count() == 1  # the pool, built in
    _add(page, "wire", "mask", "w")
    assert page.locator("[data-testid=class-points]").last.is_disabled()  # the wire: a mask
    _add(page, "wire tip", "points", "t", points="tip, root")
    _add(page, "spatter", "instances", "x", "size:choice:small|large, hot:flag")
    page.fill("[data-testid=frame-tags]", "arc unstable, humping")
    shoot(page, "label-config")
    page.click("[data-testid=save-config]")
    page.wait_for_selector(f"[data-testid=config-version]:has-text('Version {start + 1}')")
    saved = server.api("GET", "/label-config", user="anna").json()
    assert [(c["name"], c["kind"]) for c in saved["classes"]] == [
        ("pool", "mask"),
        ("wire", "mask"),
        ("wire tip", "points"),
        ("spatter", "instances"),
    ]
    assert saved["classes"][3]["attributes"] == [
        {"name": "size", "type": "choice", "options": ["small", "large"]},
        {"name": "hot", "type": "flag"},
    ]
    assert saved["frame_tags"] == ["arc unstable", "humping"]
    assert saved["classes"][2]["point_names"] == ["tip", "root"]
    assert "point_names" not in saved["classes"][1]
    # Loaded again and saved with a new tag, the point names stay as they were.
    page.reload()
    page.wait_for_selector("body[data-ready]")
    page.fill("[data-testid=frame-tags]", "arc unstable, humping, porosity")
    page.click("[data-testid=save-config]")
    page.wait_for_selector(f"[data-testid=config-version]:has-text('Version {start + 2}')")
    saved = server.api("GET", "/label-config", user="anna").json()
    assert saved["classes"][2]["point_names"] == ["tip", "root"]
    _add(page, "Wire", "mask", "z")  # a second "wire": the server's sentence, nothing saved
    page.click("[data-testid=save-config]")
    page.locator("[data-testid=toast-error]", has_text="named 'Wire'").wait_for()
    shoot(page, "label-config-refused")
    assert server.api("GET", "/label-config", user="ada").json()["version"] == start + 2
    page.locator("[data-testid=class-row]").last.locator("button").click()  # "Wire" goes
    spatter = page.locator("[data-testid=class-row]").nth(3).locator("[data-testid=class-hotkey]")
    spatter.fill("s")  # the review page's Save: refused, in words, nothing saved
    page.click("[data-testid=save-config]")
    page.locator("[data-testid=toast-error]", has_text="review page's own shortcuts").wait_for()
    shoot(page, "label-config-hotkey-refused")
    assert server.api("GET", "/label-config", user="ada").json()["version"] == start + 2
    back = {"version": start + 2, "classes": [], "force": True}  # the pool alone again
    assert server.api("PUT", "/label-config", user="ada", json=back).status_code == 200


def test_the_page_is_for_admins(page: Any, server: LiveServer) -> None:
    login(page, server, "rita")
    assert page.locator("[data-testid=nav-label-config]").count() == 0
    response = page.goto(f"{server.url}/label-config")
    assert response is not None and response.status == 403
