"""Browser tests: a live `weldpool serve` (tiny random-weight teacher, SQLite) driven through
Debian's Chromium by Playwright. Missing Chromium or Playwright fails these tests (never skips)."""

from __future__ import annotations

import os
import shutil
from collections.abc import Iterator
from decimal import ROUND_HALF_UP, Decimal
from pathlib import Path
from typing import Any

import cv2
import pytest

from tests.helpers import REPO
from tests.web.server import LiveServer, launch_chromium, missing_browser
from weldpool_core.synth import SynthParams, synth_frame

SCREENSHOTS = REPO / "test-artifacts" / "screenshots"
VIEWPORT = {"width": 1280, "height": 800}


@pytest.fixture(scope="session")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LiveServer]:
    live = LiveServer(tmp_path_factory.mktemp("live-server") / "home").start()
    yield live
    live.stop()


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    reason = missing_browser()
    if reason:
        pytest.fail(f"The browser tests cannot run: {reason}", pytrace=False)
    from playwright.sync_api import sync_playwright

    with sync_playwright() as playwright:
        chromium = launch_chromium(playwright)
        yield chromium
        chromium.close()


@pytest.fixture
def page(browser: Any) -> Iterator[Any]:
    """A fresh browser context at 1280×800; a JavaScript error on the page, or anything the
    Content-Security-Policy blocked, fails the test."""
    context = browser.new_context(viewport=VIEWPORT)
    context.set_default_timeout(20_000)
    tab = context.new_page()
    errors: list[str] = []
    tab.on("pageerror", lambda error: errors.append(str(error)))
    tab.on(
        "console",
        lambda message: (
            errors.append(message.text) if "Content Security Policy" in message.text else None
        ),
    )
    yield tab
    context.close()
    assert not errors, f"JavaScript errors on the page: {errors}"


@pytest.fixture(scope="session")
def screenshots() -> Path:
    SCREENSHOTS.mkdir(parents=True, exist_ok=True)
    return SCREENSHOTS


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


def synthetic_png(seed: int, width: int = 1280, height: int = 800) -> bytes:
    """A realistic weld-pool frame, PNG-encoded."""
    ok, data = cv2.imencode(".png", synth_frame(seed=seed, params=SynthParams(width, height)).image)
    assert ok
    return data.tobytes()
