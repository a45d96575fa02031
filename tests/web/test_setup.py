"""Without Chromium the browser tests fail with one clear sentence; they never skip."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.web import server


def test_missing_chromium_is_named_with_the_fix(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(server, "CHROMIUM", Path("/nonexistent/chromium"))
    reason = server.missing_browser()
    assert reason == (
        "Chromium is missing at /nonexistent/chromium: apt-get install -y chromium (.ci/run does)."
    )


def test_this_machine_can_run_the_browser_tests() -> None:
    assert server.missing_browser() is None
