"""The issue's scenario in a real browser against a live server: log in, upload two frames, run
the (tiny, real) teacher, review with a click, a brush stroke and a moved keypoint, accept, the
queue advances, validation keypoints are saved, the jobs and models pages render."""

from __future__ import annotations

import base64
import re
from typing import Any

import pytest

from tests.factories import synthetic_png
from tests.pages import (
    canvas_data,
    login,
    open_review,
    to_page,
    wait_for_js,
    wait_for_mask_change,
)
from tests.web.server import LiveServer
from weldpool_core.io import decode_mask_png

pytestmark = [pytest.mark.browser, pytest.mark.slow]


def test_review_scenario(page: Any, server: LiveServer) -> None:
    # Log in through the form; the header shows the user and role.
    login(page, server, "rita")
    assert page.inner_text("[data-testid=current-role]") == "reviewer"
    page.wait_for_selector("body[data-ready]")

    # A weld run to upload into, then two frames (and a file that is refused, with its reason).
    page.fill("#new-sequence input[name=name]", "Browser scenario run")
    page.click("#new-sequence button[type=submit]")
    page.wait_for_selector("#sequence-list li.active")
    page.wait_for_selector("[data-testid=sequence-dialog][open]")  # its parameters: later
    page.click("#sequence-cancel")
    page.set_input_files(
        "[data-testid=upload-input]",
        files=[
            {"name": "pool-a.png", "mimeType": "image/png", "buffer": synthetic_png(101)},
            {"name": "pool-b.png", "mimeType": "image/png", "buffer": synthetic_png(102)},
            {"name": "notes.txt", "mimeType": "text/plain", "buffer": b"not a frame"},
        ],
    )
    page.wait_for_selector("[data-testid=upload-item][data-name='pool-a.png'][data-state=ok]")
    page.wait_for_selector("[data-testid=upload-item][data-name='pool-b.png'][data-state=ok]")
    refused = page.locator("[data-testid=upload-item][data-name='notes.txt'][data-state=refused]")
    refused.wait_for()
    assert "refused:" in refused.inner_text()
    wait_for_js(page, "document.querySelectorAll('[data-testid=frame-row]').length === 2")
    rows = page.locator("[data-testid=frame-row]")
    frame_ids = [int(rows.nth(i).get_attribute("data-frame-id")) for i in range(2)]
    # No uncertainty yet: the queue falls back to upload order.
    assert frame_ids == sorted(frame_ids)
    assert page.input_value("select[name=order]") == "uncertainty"

    # The teacher proposes masks for the selection (a real job with the tiny teacher).
    page.check("#select-all")
    page.click("[data-testid=teacher-selection]")
    wait_for_js(
        page,
        "document.querySelectorAll('[data-testid=frame-row] .badge.proposed').length === 2",
        timeout=120_000,
    )

    # The proposals gave the frames uncertainty scores: the queue is now ordered by them.
    page.reload()
    wait_for_js(page, "document.querySelectorAll('[data-testid=frame-row]').length === 2")
    rows = page.locator("[data-testid=frame-row]")
    queue = [int(rows.nth(i).get_attribute("data-frame-id")) for i in range(2)]
    assert sorted(queue) == frame_ids
    scores = [server.api("GET", f"/frames/{i}").json()["uncertainty"] for i in queue]
    assert None not in scores and scores == sorted(scores, reverse=True)

    # Open the review page of the first frame of the queue.
    first, second = queue
    page.click(f"[data-frame-id='{first}'] .frame-link")
    page.wait_for_url(re.compile(rf"/frames/{first}\?"))
    open_review(page)
    assert "order=uncertainty" in page.url

    # Next goes to the next frame of the queue; back again.
    page.click("[data-testid=next]")
    page.wait_for_url(re.compile(rf"/frames/{second}\?"))
    open_review(page)
    page.go_back()
    page.wait_for_url(re.compile(rf"/frames/{first}\?"))
    open_review(page)

    # A positive click changes the mask at once (the segment endpoint, cached embedding).
    area = canvas_data(page, "mask-area")
    page.click("[data-testid=tool-positive]")
    page.mouse.click(*to_page(page, 640, 420))
    assert canvas_data(page, "clicks") == 1
    area = wait_for_mask_change(page, area)
    assert page.is_visible("[data-testid=dirty]")

    # A brush stroke changes it.
    page.click("[data-testid=tool-brush]")
    page.fill("[data-testid=brush-size]", "60")
    page.mouse.move(*to_page(page, 60, 760))
    page.mouse.down()
    page.mouse.move(*to_page(page, 400, 770), steps=10)
    page.mouse.up()
    brushed = canvas_data(page, "mask-area")
    assert brushed > area

    # Move a keypoint with the keypoint tool.
    page.click("[data-testid=tool-keypoint]")
    keypoints = canvas_data(page, "keypoints")
    if not keypoints:  # the random-weight teacher may give none: add one, then move it
        page.mouse.click(*to_page(page, 500, 300))
        keypoints = canvas_data(page, "keypoints")
    x, y = keypoints[0]
    page.mouse.move(*to_page(page, x, y))
    page.mouse.down()
    page.mouse.move(*to_page(page, x + 40, y + 30), steps=5)
    page.mouse.up()
    moved = canvas_data(page, "keypoints")[0]
    assert moved == pytest.approx([x + 40, y + 30], abs=1.5)

    # Accept: the shown label differs from the proposal, so it is stored as corrected, and the
    # queue advances to the next frame.
    page.click("[data-testid=accept]")
    page.wait_for_url(re.compile(rf"/frames/{second}\?"))
    label = server.api("GET", f"/frames/{first}/label").json()
    assert label["status"] == "corrected" and label["revision"] == 1
    assert label["updated_by"] == "rita"
    assert label["keypoints"][0] == pytest.approx(moved, abs=0.2)
    stored = decode_mask_png(base64.b64decode(label["mask_png"]))
    assert int(stored.sum()) == brushed
    assert server.api("GET", f"/frames/{first}").json()["status"] == "corrected"

    # The second frame, untouched: Accept stores the proposal as accepted; it is the last of
    # the queue, so the page says so and stays.
    open_review(page)
    page.keyboard.press("a")
    page.wait_for_selector("[data-testid=queue-position]:has-text('End of the queue')")
    assert server.api("GET", f"/frames/{second}/label").json()["status"] == "accepted"

    # Validation mode: place the four keypoints by hand and save them.
    page.click("[data-testid=validation-mode]")
    assert page.get_attribute("[data-testid=tool-keypoint]", "aria-pressed") == "true"
    placed = [(500, 300), (700, 320), (720, 500), (480, 520)]
    for px, py in placed:
        page.mouse.click(*to_page(page, px, py))
    assert page.inner_text("[data-testid=manual-count]") == "4 of 4 placed"
    page.click("[data-testid=save-validation]")
    page.wait_for_selector("[data-testid=toast-ok]:has-text('Validation keypoints saved')")
    saved = server.api("GET", f"/frames/{second}/validation-keypoints").json()["keypoints"]
    assert [c for point in saved for c in point] == pytest.approx(
        [c for point in placed for c in point], abs=1.5
    )
    assert server.api("GET", f"/frames/{second}").json()["split"] == "validation"

    # The jobs page shows the teacher job, finished; the models page renders.
    page.click("nav >> text=Jobs")
    page.wait_for_selector("[data-testid=job-row][data-status=succeeded] >> text=teacher")
    page.click("nav >> text=Models")
    page.wait_for_selector("body[data-ready]")
    assert page.inner_text("h1") == "Student models"
    assert page.is_visible("[data-testid=train-button]")
    assert (
        page.is_visible("[data-testid=models-empty]")
        or page.locator("[data-testid=model-card]").count()
    )
