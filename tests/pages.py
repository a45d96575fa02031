"""What the browser tests do on a page: log in, wait for the page or the review canvas, accept
dialogs, read the canvas, take screenshots. Fixtures (the live server, the browser, a page)
are in ``tests/web/conftest.py``; the data tests build, in ``tests.factories``."""

from __future__ import annotations

import json
import os
import shutil
import time
from decimal import ROUND_HALF_UP, Decimal
from typing import Any

from tests.helpers import REPO
from tests.web.server import PASSWORD, LiveServer

SCREENSHOTS = REPO / "test-artifacts" / "screenshots"
VIEWPORT = {"width": 1280, "height": 800}

# --- logging in, waiting, dialogs ---------------------------------------------------------------


def accept_dialogs(page: Any) -> list[str]:
    """Accept every confirm/alert the page opens from now on; returns the list their messages
    are appended to, in order."""
    messages: list[str] = []

    def accept(dialog: Any) -> None:
        messages.append(dialog.message)
        dialog.accept()

    page.on("dialog", accept)
    return messages


def login(page: Any, server: LiveServer, user: str = "rita") -> None:
    """Log in through the form, as a person does."""
    page.goto(f"{server.url}/login")
    page.fill("input[name=username]", user)
    page.fill("input[name=password]", PASSWORD)
    page.click("[data-testid=login-submit]")
    page.wait_for_url(f"{server.url}/")


def wait_for_js(page: Any, predicate: str, arg: Any = None, timeout: float = 20_000) -> None:
    """Poll a JavaScript predicate until it is true (``timeout`` in ms).

    Playwright's ``wait_for_function`` re-evaluates its predicate with ``eval``, which the
    pages' Content-Security-Policy forbids; ``page.evaluate`` runs through the DevTools
    protocol, which the policy does not cover.
    """
    deadline = time.monotonic() + timeout / 1000
    while not page.evaluate(predicate, arg):
        if time.monotonic() > deadline:
            raise AssertionError(f"Timed out after {timeout:.0f} ms waiting for: {predicate}")
        page.wait_for_timeout(50)


def wait_until(page: Any, condition: Any, timeout: float = 10_000) -> None:
    """Let the page run (events, dialogs) until a Python ``condition()`` holds (``timeout`` ms).

    Playwright delivers events such as dialogs only while the test calls into it, so a test
    that waits for a dialog polls here rather than sleeping a fixed time.
    """
    deadline = time.monotonic() + timeout / 1000
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"Timed out after {timeout:.0f} ms waiting for {condition}")
        page.wait_for_timeout(25)


# --- the review canvas --------------------------------------------------------------------------

CANVAS = "[data-testid=frame-canvas]"


def canvas_data(page: Any, name: str) -> Any:
    """A data attribute of the review canvas (mask area, keypoints, view), parsed as JSON."""
    return json.loads(page.locator(CANVAS).get_attribute(f"data-{name}"))


def to_page(page: Any, x: float, y: float) -> tuple[float, float]:
    """Frame pixels to page coordinates, through the canvas's zoom and pan."""
    box = page.locator(CANVAS).bounding_box()
    view = canvas_data(page, "view")
    return box["x"] + view["tx"] + x * view["scale"], box["y"] + view["ty"] + y * view["scale"]


def wait_for_mask_change(page: Any, before: int) -> int:
    wait_for_js(
        page,
        "([sel, before]) => { const c = document.querySelector(sel);"
        " return c.dataset.pending === '0' && Number(c.dataset.maskArea) !== before; }",
        arg=[CANVAS, before],
        timeout=60_000,
    )
    area: int = canvas_data(page, "mask-area")
    return area


def open_review(page: Any) -> None:
    page.wait_for_selector("body[data-ready]")
    page.wait_for_selector(f"{CANVAS}[data-ready]")


# --- screenshots and numbers as the pages write them ---------------------------------------------

SIZES = ((1280, 800), (1920, 1080))
DOC_IMAGES = REPO / "docs" / "images"
DOC_PICTURES = {"review", "frames", "models", "help"}
"""Screenshots the manual shows: with WELDPOOL_DOC_SCREENSHOTS=1 their 1280×800 shot is also
written to docs/images/<name>.png, so the manual's pictures are what the tests saw."""


def shoot(page: Any, name: str, *, full_page: bool = False, idle: bool = False) -> None:
    """Screenshots of what the page shows now at 1280×800 and 1920×1080 (``<name>-1280.png``,
    ``<name>-1920.png`` in test-artifacts/screenshots/), then back to 1280×800; ``idle`` waits
    for the network to settle first (lazy thumbnails)."""
    SCREENSHOTS.mkdir(parents=True, exist_ok=True)
    for width, height in SIZES:
        page.set_viewport_size({"width": width, "height": height})
        page.wait_for_timeout(150)  # a resize re-lays the canvas out on the next frame
        if idle:
            page.wait_for_load_state("networkidle")
        page.screenshot(path=str(SCREENSHOTS / f"{name}-{width}.png"), full_page=full_page)
        if width == 1280 and name in DOC_PICTURES and os.environ.get("WELDPOOL_DOC_SCREENSHOTS"):
            shutil.copyfile(SCREENSHOTS / f"{name}-{width}.png", DOC_IMAGES / f"{name}.png")
    page.set_viewport_size(VIEWPORT)
    page.wait_for_timeout(150)


def fixed(value: float, digits: int) -> str:
    """``value.toFixed(digits)`` as the pages' JavaScript writes it: the exact binary value
    rounded half up, where Python's format rounds an exact tie (0.25) to even."""
    return str(Decimal(value).quantize(Decimal(1).scaleb(-digits), rounding=ROUND_HALF_UP))
