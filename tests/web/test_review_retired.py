"""A class, tag and attribute removed from the label configuration with ``force``: the review
page shows their objects and values read-only ("class removed"), visible and toggleable; a
changed save keeps them on the label, and only their × removes them."""

from __future__ import annotations

import itertools
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

from tests.factories import add_frame
from tests.helpers import corrected_label, mask_b64
from tests.pages import canvas_data, login, open_review, shoot, to_page, wait_for_js
from tests.web.server import LiveServer

pytestmark = [pytest.mark.browser, pytest.mark.slow]

BEFORE = {
    "classes": [
        {"name": "wire", "kind": "mask", "color": "#40c057", "hotkey": "w"},
        {"name": "spatter", "kind": "instances", "color": "#e64980"},
    ],
    "frame_tags": ["humping", "arc unstable"],
    "frame_attributes": [{"name": "note", "type": "text"}],
}
AFTER = {  # spatter, "humping" and "note" removed with force
    "classes": [{"name": "wire", "kind": "mask", "color": "#40c057", "hotkey": "w"}],
    "frame_tags": ["arc unstable"],
}
SEEDS = itertools.count(331)  # one frame per test on the module's server


def _box(x0: int, y0: int, x1: int, y1: int) -> np.ndarray:
    mask = np.zeros((800, 1280), bool)
    mask[y0:y1, x0:x1] = True
    return mask


@pytest.fixture
def retired_frame(server: LiveServer) -> Iterator[int]:
    """A frame labelled with two spatter objects, a tag and a note, then those removed from
    the configuration with force; the pool alone again afterwards."""
    version = server.api("GET", "/label-config", user="ada").json()["version"]
    first = server.api("PUT", "/label-config", user="ada", json={**BEFORE, "version": version})
    assert first.status_code == 200, first.text
    frame = add_frame(server, next(SEEDS), teacher=False)
    body = corrected_label(_box(500, 300, 700, 450)) | {
        "objects": [
            {"class": "spatter", "mask_png": mask_b64(_box(200, 150, 260, 200))},
            {"class": "spatter", "mask_png": mask_b64(_box(900, 550, 980, 640))},
        ],
        "tags": ["humping"],
        "attributes": {"note": "porous"},
    }
    saved = server.api("PUT", f"/frames/{frame}/label", json=body)
    assert saved.status_code == 200, saved.text
    version = first.json()["version"]
    forced = {**AFTER, "version": version, "force": True}
    second = server.api("PUT", "/label-config", user="ada", json=forced)
    assert second.status_code == 200, second.text
    yield frame
    back = {"version": second.json()["version"], "classes": [], "force": True}
    assert server.api("PUT", "/label-config", user="ada", json=back).status_code == 200


def _stroke(page: Any, start: tuple[float, float], end: tuple[float, float]) -> None:
    page.mouse.move(*to_page(page, *start))
    page.mouse.down()
    for t in (0.5, 1.0):
        x, y = start[0] + (end[0] - start[0]) * t, start[1] + (end[1] - start[1]) * t
        page.mouse.move(*to_page(page, x, y))
    page.mouse.up()


def _save(page: Any, revision: int) -> None:
    page.click("[data-testid=save]")
    page.locator("[data-testid=toast-ok]", has_text=f"revision {revision}").wait_for()


def test_a_removed_class_shows_read_only_and_survives_a_changed_save(
    page: Any, server: LiveServer, retired_frame: int
) -> None:
    frame = retired_frame
    stored = server.api("GET", f"/frames/{frame}/label").json()
    spatter = [o for o in stored["objects"] if o["class"] == "spatter"]
    login(page, server, "rita")
    page.goto(f"{server.url}/frames/{frame}")
    open_review(page)
    page.uncheck("#advance")
    rows = page.locator("[data-testid=layer-row][data-retired=true]")
    assert rows.count() == 2
    assert "class removed" in rows.first.inner_text()
    shown = [o for o in canvas_data(page, "objects") if o.get("retired")]
    assert [o["bbox"] for o in shown] == [[200, 150, 60, 50], [900, 550, 80, 90]]
    assert page.locator("[data-testid=retired-tag][data-tag=humping]").is_visible()
    assert page.locator("[data-testid=retired-attribute][data-name=note]").is_visible()
    shoot(page, "review-retired")

    # Not editable: clicking its row leaves the pool edited; hiding it works.
    rows.first.click(position={"x": 60, "y": 8})
    assert page.locator("[data-testid=frame-canvas]").get_attribute("data-layer") == "pool"
    rows.first.locator("[data-testid=layer-visible]").uncheck()
    assert not rows.first.locator("[data-testid=layer-visible]").is_checked()

    # A changed save: a wire painted, a configured tag set. The retired parts stay.
    page.keyboard.press("w")
    page.keyboard.press("4")
    page.locator("[data-testid=brush-size]").fill("16")
    _stroke(page, (300, 600), (420, 600))
    page.click("[data-testid=frame-tag][data-tag='arc unstable']")
    _save(page, 2)
    label = server.api("GET", f"/frames/{frame}/label").json()
    assert [o["class"] for o in label["objects"]] == ["wire", "spatter", "spatter"]
    assert label["objects"][1:] == spatter  # byte for byte as they were stored
    assert label["tags"] == ["arc unstable", "humping"]
    assert label["attributes"] == {"note": "porous"}
    assert label["retired"] == {"objects": [1, 2], "tags": ["humping"], "attributes": ["note"]}

    # Removed only by their ×: the second spatter object and the tag.
    page.locator("[data-testid=layer-row][data-retired=true] [data-testid=layer-remove]").nth(
        1
    ).click()
    page.locator("[data-testid=retired-tag][data-tag=humping] button").click()
    wait_for_js(page, "() => document.querySelectorAll('[data-retired=true]').length === 1")
    _save(page, 3)
    label = server.api("GET", f"/frames/{frame}/label").json()
    assert [o["class"] for o in label["objects"]] == ["wire", "spatter"]
    assert label["objects"][1] == spatter[0]
    assert label["tags"] == ["arc unstable"] and label["attributes"] == {"note": "porous"}
    # After the save the page names the remaining one where the server now lists it.
    page.locator("[data-testid=retired-attribute][data-name=note] button").click()
    page.locator("[data-testid=layer-row][data-retired=true] [data-testid=layer-remove]").click()
    _save(page, 4)
    label = server.api("GET", f"/frames/{frame}/label").json()
    assert [o["class"] for o in label["objects"]] == ["wire"] and label["attributes"] == {}


def _in_conflict(page: Any, server: LiveServer, frame: int) -> list[dict[str, Any]]:
    """The frame open for rita, ada's label saved meanwhile (the pool alone), a wire painted
    and saved: the conflict dialog open. Returns the retired spatter objects as stored."""
    spatter = server.api("GET", f"/frames/{frame}/label").json()["objects"]
    login(page, server, "rita")
    page.goto(f"{server.url}/frames/{frame}")
    open_review(page)
    page.uncheck("#advance")
    theirs = corrected_label(_box(520, 320, 720, 470)) | {"base_revision": 1}
    assert server.api("PUT", f"/frames/{frame}/label", "ada", json=theirs).status_code == 200
    page.keyboard.press("w")
    page.keyboard.press("4")
    page.locator("[data-testid=brush-size]").fill("16")
    _stroke(page, (300, 600), (420, 600))
    page.click("[data-testid=save]")
    page.locator("[data-testid=conflict-dialog]").wait_for()
    return spatter


def test_a_conflict_overwritten_with_mine_keeps_the_retired_parts(
    page: Any, server: LiveServer, retired_frame: int
) -> None:
    """The conflict dialog reads their label to say what differs; that look must not make the
    page name the retired parts for removal: "Overwrite with mine" keeps them stored."""
    frame, spatter = retired_frame, _in_conflict(page, server, retired_frame)
    page.click("[data-testid=conflict-overwrite]")
    page.locator("[data-testid=toast-ok]", has_text="revision 3").wait_for()
    label = server.api("GET", f"/frames/{frame}/label").json()
    assert [o["class"] for o in label["objects"]] == ["wire", "spatter", "spatter"]
    assert label["objects"][1:] == spatter
    assert label["tags"] == ["humping"] and label["attributes"] == {"note": "porous"}


def test_their_label_taken_and_undone_names_no_retired_part_for_removal(
    page: Any, server: LiveServer, retired_frame: int
) -> None:
    """ "Take theirs" loads their label (its retired objects with other uids); undo brings mine
    back: a save then keeps every retired object, since no × was pressed on any."""
    frame, spatter = retired_frame, _in_conflict(page, server, retired_frame)
    page.click("[data-testid=conflict-reload]")
    wait_for_js(
        page, "() => document.querySelector('[data-testid=frame-canvas]').dataset.revision === '2'"
    )
    page.keyboard.press("Control+z")  # mine again, unsaved
    _save(page, 3)
    label = server.api("GET", f"/frames/{frame}/label").json()
    assert [o["class"] for o in label["objects"]] == ["wire", "spatter", "spatter"]
    assert label["objects"][1:] == spatter
