"""Time to interactive of the review page on a warm server, in Debian's Chromium (Playwright).

Run: ``.venv/bin/python bench/ui.py [--runs 5]``. It starts ``weldpool serve`` (SQLite, the tiny
random-weight teacher of the tests) in a temporary home, uploads a synthetic 1280×800 frame and
runs the teacher on it, loads the review page once to warm the server (templates, the display
PNG), then loads it ``--runs`` times in a fresh browser context each (empty browser cache, the
session cookie copied in) and once more per run as a revisit (browser cache warm).

"Interactive" is the page's own ``weldpool:interactive`` mark: the frame, the mask overlay and
the keypoints are drawn and every tool answers. Times are milliseconds from the navigation's
start, medians over the runs. Goal: under 1000 ms with an empty browser cache.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
from pathlib import Path
from typing import Any

from results import recorded

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tests.pages import login
from tests.web.server import LiveServer, launch_chromium, missing_browser
from weldpool_core.synth import SynthParams, synth_frame

TIMINGS_JS = """() => {
  const nav = performance.getEntriesByType("navigation")[0];
  const mark = performance.getEntriesByName("weldpool:interactive")[0];
  const image = performance.getEntriesByType("resource")
    .find((r) => r.name.includes("variant=display"));
  return {
    ttfb: nav.responseStart, dom: nav.domContentLoadedEventEnd,
    image: image ? image.responseEnd : NaN, interactive: mark.startTime,
  };
}"""
COLUMNS = ("ttfb", "dom", "image", "interactive")


def _frame_png() -> bytes:
    import cv2

    ok, data = cv2.imencode(".png", synth_frame(seed=3, params=SynthParams(1280, 800)).image)
    assert ok
    return bytes(data.tobytes())


def _load(browser: Any, state: dict[str, Any], url: str, revisit: bool) -> dict[str, float]:
    context = browser.new_context(viewport={"width": 1280, "height": 800}, storage_state=state)
    try:
        page = context.new_page()
        page.goto(url)
        page.wait_for_selector("body[data-ready]", timeout=30_000)
        if revisit:
            page.goto("about:blank")
            page.goto(url)
            page.wait_for_selector("body[data-ready]", timeout=30_000)
        timings: dict[str, float] = page.evaluate(TIMINGS_JS)
        return timings
    finally:
        context.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5)
    args = parser.parse_args()
    problem = missing_browser()
    if problem:
        sys.exit(f"bench/ui.py: {problem}")
    from playwright.sync_api import sync_playwright

    with tempfile.TemporaryDirectory(prefix="weldpool-bench-ui-") as tmp:
        server = LiveServer(Path(tmp) / "home").start()
        try:
            files = [("files", ("bench.png", _frame_png(), "image/png"))]
            frame_id = server.api("POST", "/frames", files=files).json()["stored"][0]["id"]
            job = server.api("POST", "/teacher/runs", json={"frame_ids": [frame_id]}).json()
            assert server.wait_for_job(job["job_id"])["status"] == "succeeded"
            url = f"{server.url}/frames/{frame_id}"
            with sync_playwright() as playwright:
                browser = launch_chromium(playwright)
                context = browser.new_context()
                page = context.new_page()
                login(page, server)
                state = context.storage_state()
                page.goto(url)  # warm the server: templates, the display PNG, the proposal
                page.wait_for_selector("body[data-ready]")
                context.close()
                rows = {
                    "empty browser cache": [
                        _load(browser, state, url, False) for _ in range(args.runs)
                    ],
                    "revisit (browser cache warm)": [
                        _load(browser, state, url, True) for _ in range(args.runs)
                    ],
                }
                browser.close()
        finally:
            server.stop()

    print(f"Review page of a 1280×800 frame with its proposal; median of {args.runs} loads, ms")
    print(f"| case | {' | '.join(COLUMNS)} | interactive min–max |")
    print(f"|---|{'---:|' * len(COLUMNS)}---:|")
    for name, runs in rows.items():
        medians = [statistics.median(r[c] for r in runs) for c in COLUMNS]
        spread = [r["interactive"] for r in runs]
        cells = " | ".join(f"{m:.0f}" for m in medians)
        print(f"| {name} | {cells} | {min(spread):.0f}–{max(spread):.0f} |")
    print("ttfb: first byte of the HTML; dom: DOMContentLoaded; image: the frame's display PNG")
    print("received; interactive: frame, mask and keypoints drawn, tools bound. Goal: < 1000.")


if __name__ == "__main__":
    with recorded(__file__):
        main()
