"""Work that finds its person, in the browser, with the review stage on: the header's badge on
every page, an annotator landing on what was sent back to her (with the comment) and then her
frames, a reviewer landing on what awaits his approval, one set of verdicts per role and state,
and the per-person figures on the metrics and users pages."""

from __future__ import annotations

from typing import Any

import pytest

from tests.factories import synthetic_png
from tests.helpers import corrected_label
from tests.pages import login, shoot, wait_for_js
from tests.web.server import LiveServer
from weldpool_core.synth import SynthParams, synth_frame

pytestmark = [pytest.mark.browser, pytest.mark.slow]


def _badge(page: Any, key: str) -> str:
    item = page.locator(f"[data-testid=work-{key}]")
    item.wait_for()
    return str(item.inner_text())


def _ids(page: Any) -> list[int]:
    return [
        int(r.get_attribute("data-frame-id")) for r in page.locator("[data-testid=frame-row]").all()
    ]


@pytest.fixture
def stage_server(tmp_path: Any) -> Any:
    """anna saved frames a (nobody's) and b (hers), rita sent a back; c is hers, untouched."""
    server = LiveServer(tmp_path / "home", env={"WELDPOOL_REVIEW_STAGE": "true"}).start()
    try:
        files = [("files", (f"w{i}.png", synthetic_png(900 + i), "image/png")) for i in range(3)]
        a, b, c = (f["id"] for f in server.api("POST", "/frames", files=files).json()["stored"])
        anna = next(
            u for u in server.api("GET", "/users/assignable").json() if u["username"] == "anna"
        )
        server.api("POST", "/frames/assign", json={"frame_ids": [b, c], "assignee_id": anna["id"]})
        mask = synth_frame(seed=900, params=SynthParams(1280, 800)).mask
        for frame in (a, b):
            server.api("PUT", f"/frames/{frame}/label", user="anna", json=corrected_label(mask))
        server.api(
            "POST",
            f"/frames/{a}/label/review",
            json={"decision": "return", "base_revision": 1, "comment": "The wire tip is inside."},
        )
        server.frames = (a, b, c)  # type: ignore[attr-defined]
        yield server
    finally:
        server.stop()


def test_each_role_lands_on_its_work(browser: Any, stage_server: LiveServer) -> None:
    a, b, c = stage_server.frames  # type: ignore[attr-defined]
    context = browser.new_context(viewport={"width": 1280, "height": 800})
    page = context.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda error: errors.append(str(error)))
    try:
        login(page, stage_server, "anna")
        page.wait_for_selector("body[data-ready]")
        assert page.input_value("[data-testid=filter-assignee]") == "work"
        wait_for_js(page, "document.querySelectorAll('[data-testid=frame-row]').length === 2")
        assert _ids(page) == [a, c]  # sent back first, then her frame still to review
        first = page.locator("[data-testid=frame-row]").first
        assert first.locator("[data-testid=review-badge]").inner_text() == "sent back"
        assert (
            "The wire tip is inside." in first.locator("[data-testid=review-comment]").inner_text()
        )
        assert (
            _badge(page, "sent-back") == "sent back 1" and _badge(page, "assigned") == "assigned 1"
        )
        assert page.locator("[data-testid=work-awaiting-review]").count() == 0
        shoot(page, "work-annotator-frames", idle=True)

        page.click("[data-testid=work-sent-back]")
        page.wait_for_selector("body[data-ready]")
        wait_for_js(page, "document.querySelectorAll('[data-testid=frame-row]').length === 1")
        page.locator("[data-testid=frame-row] a.frame-link").click()
        page.wait_for_selector("[data-testid=frame-canvas][data-ready]")
        assert page.inner_text("#frame-state [data-testid=review-badge]") == "sent back"
        assert page.is_hidden("[data-testid=accept]") and page.is_hidden("[data-testid=reject]")
        assert "Submit for review" in page.inner_text("[data-testid=save]")
        assert "The wire tip is inside." in page.inner_text("[data-testid=review-state]")
        shoot(page, "work-annotator-review")
        page.goto(f"{stage_server.url}/metrics")
        page.locator("[data-testid=people-row]").first.wait_for()
        assert [
            r.get_attribute("data-username") for r in page.locator("[data-testid=people-row]").all()
        ] == ["anna"]
        shoot(page, "work-annotator-metrics", full_page=True)

        page.context.clear_cookies()
        login(page, stage_server, "rita")
        page.wait_for_selector("body[data-ready]")
        assert page.input_value("[data-testid=filter-review]") == "awaiting"
        wait_for_js(page, "document.querySelectorAll('[data-testid=frame-row]').length === 1")
        assert _ids(page) == [b]
        assert _badge(page, "awaiting-review") == "to approve 1"
        shoot(page, "work-reviewer-frames", idle=True)
        page.locator("[data-testid=frame-row] a.frame-link").click()
        page.wait_for_selector("[data-testid=frame-canvas][data-ready]")
        assert page.inner_text("#frame-state [data-testid=review-badge]") == "awaiting review"
        for hidden in ("accept", "reject", "save"):
            assert page.is_hidden(f"[data-testid={hidden}]"), hidden
        assert page.is_visible("[data-testid=approve]") and page.is_visible(
            "[data-testid=send-back]"
        )
        assert page.is_disabled("[data-testid=approve-corrected]")  # nothing corrected yet
        shoot(page, "work-reviewer-review")
        page.click("[data-testid=approve]")
        page.locator("[data-testid=toast-ok]", has_text="Approved").wait_for()
        wait_for_js(
            page,
            "document.querySelector('[data-testid=work-awaiting-review]')?.textContent"
            " === 'to approve 0'",
        )
        assert page.inner_text("#frame-state [data-testid=review-badge]") == "approved"
        assert page.is_visible("[data-testid=accept]")  # his own verdicts again

        page.context.clear_cookies()
        login(page, stage_server, "ada")
        page.goto(f"{stage_server.url}/users")
        page.locator("[data-testid=people-row][data-username=rita]").wait_for()
        rita = page.locator("[data-testid=people-row][data-username=rita]").inner_text()
        assert "1 approved" in rita and "1 sent back" in rita
        anna = page.locator("[data-testid=people-row][data-username=anna]").inner_text()
        assert "1 of 2" in anna  # one of her two submissions was sent back
        shoot(page, "work-admin-users", full_page=True)
        page.goto(f"{stage_server.url}/metrics")
        page.locator("[data-testid=people-row]").first.wait_for()
        shoot(page, "work-admin-metrics", full_page=True)
    finally:
        context.close()
    assert not errors, errors


def test_agreement_in_the_browser(browser: Any, stage_server: LiveServer) -> None:
    """Frame c given to anna and otto: anna's page keeps her label apart ("Save my label"),
    rita's shows both labels and their agreement and merges them into the frame's label."""
    from tests.helpers import mask_b64

    _, _, c = stage_server.frames  # type: ignore[attr-defined]
    otto = stage_server.api(
        "POST", "/users", user="ada", json={"username": "otto", "password": "otto-password"}
    ).json()
    anna = next(
        u for u in stage_server.api("GET", "/users/assignable").json() if u["username"] == "anna"
    )
    given = stage_server.api(
        "POST", "/frames/overlap", json={"frame_ids": [c], "user_ids": [anna["id"], otto["id"]]}
    )
    assert given.json()["given"] == 2
    wide = synth_frame(seed=902, params=SynthParams(1280, 800)).mask
    narrow = wide.copy()
    narrow[:, 640:] = False
    stage_server.api(
        "PUT", f"/frames/{c}/overlap/mine", user="anna", json={"mask_png": mask_b64(wide)}
    )
    token = stage_server.api(
        "POST", "/tokens", user="ada", json={"username": "otto", "password": "otto-password"}
    ).json()["token"]
    stage_server.tokens["otto"] = token
    stage_server.api(
        "PUT", f"/frames/{c}/overlap/mine", user="otto", json={"mask_png": mask_b64(narrow)}
    )

    context = browser.new_context(viewport={"width": 1280, "height": 800})
    page = context.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda error: errors.append(str(error)))
    try:
        login(page, stage_server, "anna")
        page.goto(f"{stage_server.url}/frames/{c}")
        page.wait_for_selector("[data-testid=frame-canvas][data-ready]")
        page.locator("[data-testid=agreement-own]").wait_for()
        assert "Your label is saved" in page.inner_text("[data-testid=agreement-own]")
        wait_for_js(
            page,
            "document.querySelector('[data-testid=save]').textContent.includes('Save my label')",
        )
        area = int(page.get_attribute("[data-testid=frame-canvas]", "data-mask-area") or 0)
        assert area == int(wide.sum())  # her own label, not anyone else's
        shoot(page, "agreement-annotator")

        page.context.clear_cookies()
        login(page, stage_server, "rita")
        page.goto(f"{stage_server.url}/frames/{c}")
        page.wait_for_selector("[data-testid=frame-canvas][data-ready]")
        figures = page.locator("[data-testid=agreement-figures]")
        figures.wait_for()
        expected = f"mask IoU {narrow.sum() / wide.sum():.3f}"
        assert "2 of 2 annotators labelled" in figures.inner_text()
        assert expected in figures.inner_text()
        shoot(page, "agreement-reviewer")
        with page.expect_navigation():  # the page reloads on the frame's new label
            page.click("[data-testid=agreement-merge]")
        page.wait_for_selector("[data-testid=frame-canvas][data-ready]")
        wait_for_js(
            page, "document.querySelector('[data-testid=frame-canvas]').dataset.revision === '1'"
        )
        label = stage_server.api("GET", f"/frames/{c}/label").json()
        assert label["updated_by"] == "rita" and label["review"] == "approved"
        page.goto(f"{stage_server.url}/metrics")
        page.locator("[data-testid=agreement-table]").wait_for()
        assert expected.split()[-1] in page.inner_text("[data-testid=agreement-table]")
        shoot(page, "agreement-metrics", full_page=True)
    finally:
        context.close()
    assert not errors, errors
