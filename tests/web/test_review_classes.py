"""The review page edits every configured class: picked by hotkey, painted with the pool's
brush, points placed by name, instances added (one by a SAM2 click), the frame tagged; one
save carries them all, and the label read back holds each object where it was drawn. Undo
walks back across layers."""

from __future__ import annotations

import base64
import json
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from app.labelconfig.schemas import REVIEW_KEYS
from tests.factories import add_frame
from tests.helpers import SHARED_DATA
from tests.pages import canvas_data, login, open_review, shoot, to_page, wait_for_js
from tests.web.server import LiveServer
from weldpool_core.outline import rle_mask

pytestmark = [pytest.mark.browser, pytest.mark.slow]

CONFIG = {
    "classes": [
        {"name": "wire", "kind": "mask", "color": "#40c057", "hotkey": "w"},
        {
            "name": "wire tip",
            "kind": "points",
            "color": "#fab005",
            "hotkey": "t",
            "point_names": ["tip"],
        },
        {
            "name": "spatter",
            "kind": "instances",
            "color": "#e64980",
            "hotkey": "x",
            "attributes": [{"name": "size", "type": "choice", "options": ["small", "large"]}],
        },
    ],
    "frame_tags": ["arc unstable", "humping"],
    "frame_attributes": [{"name": "visibility", "type": "choice", "options": ["good", "poor"]}],
}
WAAM = Path(os.environ.get("WELDPOOL_SHARED_DATA") or SHARED_DATA) / "waam"


@pytest.fixture
def classes(server: LiveServer) -> Iterator[None]:
    """The test's classes configured, and the pool alone again afterwards."""
    version = server.api("GET", "/label-config", user="ada").json()["version"]
    saved = server.api("PUT", "/label-config", user="ada", json={**CONFIG, "version": version})
    assert saved.status_code == 200, saved.text
    yield
    back = {"version": saved.json()["version"], "classes": [], "force": True}
    assert server.api("PUT", "/label-config", user="ada", json=back).status_code == 200


def _objects(page: Any) -> dict[str, Any]:
    return {o["name"]: o for o in canvas_data(page, "objects")}


def _wait_for_area(page: Any, name: str) -> None:
    """Until the object `name` has pixels and nothing is pending (a SAM2 answer, a trace)."""
    wait_for_js(
        page,
        "(name) => { const c = document.querySelector('[data-testid=frame-canvas]');"
        " const o = JSON.parse(c.dataset.objects).find((o) => o.name === name);"
        " return c.dataset.pending === '0' && o && o.area > 0; }",
        arg=name,
        timeout=60_000,
    )


def _stroke(page: Any, start: tuple[float, float], end: tuple[float, float]) -> None:
    """A brush drag from `start` to `end`, in frame pixels."""
    page.mouse.move(*to_page(page, *start))
    page.mouse.down()
    for t in (0.25, 0.5, 0.75, 1.0):
        x, y = start[0] + (end[0] - start[0]) * t, start[1] + (end[1] - start[1]) * t
        page.mouse.move(*to_page(page, x, y))
    page.mouse.up()


def _layer(page: Any) -> str:
    value: str = page.locator("[data-testid=frame-canvas]").get_attribute("data-layer")
    return value


def _region(obj: dict[str, Any]) -> Any:
    return rle_mask(obj["rle"])


def _brush(page: Any, size: int) -> None:
    page.keyboard.press("4")
    page.locator("[data-testid=brush-size]").fill(str(size))


def test_every_class_is_edited_and_saved_in_one_put(
    page: Any, server: LiveServer, classes: None
) -> None:
    frame = add_frame(server, 311)
    login(page, server, "rita")
    page.goto(f"{server.url}/frames/{frame}")
    open_review(page)
    pool_before = canvas_data(page, "mask-area")
    picker = page.locator("[data-testid=class-option]")
    assert picker.evaluate_all("nodes => nodes.map(n => n.dataset.class)") == [
        "pool",
        "wire",
        "wire tip",
        "spatter",
    ]
    assert page.locator("[data-testid=class-option][data-class=wire] kbd").inner_text() == "w"
    keys = page.evaluate("import('/static/js/review/page.js').then(m => [...m.PAGE_KEYS])")
    assert sorted(keys) == sorted(REVIEW_KEYS)  # the page's own keys, as the server's rule says

    # The wire, picked by its hotkey, painted with the pool's brush: a horizontal stroke.
    page.keyboard.press("w")
    assert _layer(page) == "wire"
    _brush(page, 20)
    _stroke(page, (300, 200), (420, 200))
    _wait_for_area(page, "wire")
    assert canvas_data(page, "mask-area") == pool_before  # the pool is not what the brush edits
    x, y, w, h = _objects(page)["wire"]["bbox"]  # the drag's frame pixels, through zoom and pan
    assert abs(x - 290) <= 2 and abs(y - 190) <= 2 and abs(w - 141) <= 3 and abs(h - 21) <= 3

    # The wire tip: one named point, placed by a click, then dragged a little.
    page.keyboard.press("t")
    assert _layer(page) == "wire tip"
    page.mouse.click(*to_page(page, 880, 480))
    page.mouse.move(*to_page(page, 880, 480))
    page.mouse.down()
    page.mouse.move(*to_page(page, 895, 490))
    page.mouse.move(*to_page(page, 900, 500))
    page.mouse.up()
    tip = _objects(page)["wire tip"]["points"]["tip"]
    assert abs(tip[0] - 900) < 1.5 and abs(tip[1] - 500) < 1.5

    # Two spatter instances: the first from a SAM2 click (any class uses the cached embedding),
    # the second painted; the first gets an attribute.
    page.keyboard.press("x")
    assert _layer(page) == "spatter 1"
    page.keyboard.press("1")
    page.mouse.click(*to_page(page, 640, 400))
    _wait_for_area(page, "spatter 1")
    page.select_option("[data-testid=object-attribute][data-name=size]", "large")
    page.click("[data-testid=add-instance][data-class=spatter]")
    assert _layer(page) == "spatter 2"
    _brush(page, 12)
    _stroke(page, (1000, 650), (1000, 700))
    assert page.locator("[data-testid=layer-row]").count() == 5  # pool, wire, tip, 2 spatter

    # A frame tag, then one save for everything.
    page.click("[data-testid=frame-tag][data-tag=humping]")
    page.select_option("[data-testid=frame-attribute][data-name=visibility]", "poor")
    page.uncheck("#advance")
    page.click("[data-testid=save]")
    page.locator("[data-testid=toast-ok]", has_text="Saved as corrected").wait_for()
    shoot(page, "review-classes")

    label = server.api("GET", f"/frames/{frame}/label").json()
    assert label["revision"] == 1 and label["tags"] == ["humping"]
    assert label["attributes"] == {"visibility": "poor"}
    by_class: dict[str, list[Any]] = {}
    for obj in label["objects"]:
        by_class.setdefault(obj["class"], []).append(obj)
    assert sorted(by_class) == ["spatter", "wire", "wire tip"]
    wire = _region(by_class["wire"][0])
    assert wire.shape == (800, 1280)
    # The stroke ran along y = 200 from x = 300 to 420, 20 px wide: swapped axes or a dropped
    # view scale put the pixels elsewhere.
    ys, xs = wire.nonzero()
    assert 288 <= xs.min() <= 292 and 428 <= xs.max() <= 432
    assert 188 <= ys.min() <= 192 and 208 <= ys.max() <= 212
    assert wire[200, 360] and not wire[360, 200]
    assert by_class["wire tip"][0]["points"]["tip"] == pytest.approx([900, 500], abs=1.5)
    first, second = by_class["spatter"]
    assert first["attributes"] == {"size": "large"} and first["area"] > 0
    painted = _region(second)
    assert painted[675, 1000] and not painted[675, 1030]
    assert 643 <= painted.nonzero()[0].min() <= 645  # 650 less the brush's radius, 6
    pool = base64.b64decode(label["mask_png"])
    assert pool  # the pool travels in the same PUT


def test_undo_walks_back_across_layers(page: Any, server: LiveServer, classes: None) -> None:
    frame = add_frame(server, 312)
    login(page, server, "rita")
    page.goto(f"{server.url}/frames/{frame}")
    open_review(page)
    pool = canvas_data(page, "mask-area")
    page.keyboard.press("w")
    _brush(page, 16)
    _stroke(page, (200, 600), (300, 600))
    page.keyboard.press("x")
    _stroke(page, (900, 150), (950, 150))
    wire, spatter = (_objects(page)[n]["area"] for n in ("wire", "spatter 1"))
    assert wire > 0 and spatter > 0
    page.click("[data-testid=class-option][data-class=pool]")
    page.keyboard.press("5")  # the eraser, on the pool
    _stroke(page, (0, 0), (1280, 800))
    assert canvas_data(page, "mask-area") <= pool

    page.keyboard.press("Control+z")  # the pool's erasure goes; the others stay
    assert canvas_data(page, "mask-area") == pool and _layer(page) == "pool"
    assert (_objects(page)["wire"]["area"], _objects(page)["spatter 1"]["area"]) == (wire, spatter)
    page.keyboard.press("Control+z")  # the spatter stroke goes, the wire's stays
    assert _layer(page) == "spatter 1"
    assert (_objects(page)["wire"]["area"], _objects(page)["spatter 1"]["area"]) == (wire, 0)
    page.keyboard.press("Control+z")  # the spatter object itself: the pool is edited again
    assert "spatter 1" not in _objects(page) and _layer(page) == "pool"
    page.keyboard.press("Control+z")  # the wire stroke
    assert _objects(page)["wire"]["area"] == 0 and _layer(page) == "wire"
    page.keyboard.press("Control+Shift+z")
    page.keyboard.press("Control+Shift+z")
    assert _objects(page)["spatter 1"]["area"] == 0 and _objects(page)["wire"]["area"] == wire
    assert _layer(page) == "spatter 1"
    # Redone, the spatter's stroke lands on the spatter again, not on the wire being edited.
    page.keyboard.press("w")
    page.keyboard.press("Control+Shift+z")
    assert (_objects(page)["wire"]["area"], _objects(page)["spatter 1"]["area"]) == (wire, spatter)
    assert _layer(page) == "spatter 1"


def test_a_real_frame_with_several_classes(page: Any, server: LiveServer, classes: None) -> None:
    """Screenshots of the review page on a real WAAM frame with every kind of layer."""
    stem = "compressed_0mm_f0250"
    image, mask = WAAM / "frames" / f"{stem}.png", WAAM / "labels" / f"{stem}.png"
    if not image.exists() or not mask.exists():
        pytest.skip(f"The real frames are not here ({WAAM}).")
    files = [("files", (image.name, image.read_bytes(), "image/png"))]
    answer = server.api("POST", "/frames", files=files).json()
    frame = (answer["stored"] or answer["duplicates"])[0][
        "frame_id" if not answer["stored"] else "id"
    ]
    base = server.api("GET", f"/frames/{frame}").json()
    wire = [[1280, 300], [900, 395], [905, 420], [1280, 345]]
    body = {
        "status": "corrected",
        "base_revision": (base.get("label") or {}).get("revision", 0),
        "mask_png": base64.b64encode(mask.read_bytes()).decode(),
        "objects": [
            {"class": "wire", "polygons": [wire]},
            {"class": "wire tip", "points": {"tip": [902, 408]}},
            {"class": "spatter", "polygons": [[[700, 250], [730, 250], [730, 275], [700, 275]]]},
            {
                "class": "spatter",
                "polygons": [[[420, 600], [445, 600], [445, 630]]],
                "attributes": {"size": "small"},
            },
        ],
        "tags": ["arc unstable"],
    }
    saved = server.api("PUT", f"/frames/{frame}/label", json=body)
    assert saved.status_code == 200, saved.text
    login(page, server, "rita")
    page.goto(f"{server.url}/frames/{frame}")
    open_review(page)
    shown = canvas_data(page, "objects")
    assert [o["name"] for o in shown] == ["wire", "wire tip", "spatter 1", "spatter 2"]
    # The stored regions (COCO RLE, down the columns) decode where the server has them.
    stored = server.api("GET", f"/frames/{frame}/label").json()["objects"]
    for here, there in zip(shown, stored, strict=True):
        if "rle" in there:
            assert (here["area"], here["bbox"]) == (there["area"], there["bbox"])
    assert shown[1]["points"] == {"tip": [902, 408]}
    page.click("[data-testid=layer-row][data-class=spatter] >> nth=1")
    assert _layer(page) == "spatter 2"
    assert page.input_value("[data-testid=object-attribute][data-name=size]") == "small"
    shoot(page, "review-classes-real")


def test_a_wire_drawn_as_a_new_polygon(page: Any, server: LiveServer, classes: None) -> None:
    """On an empty layer the polygon tool's clicks are corners of a new polygon: the first
    corner or Enter closes it, Esc drops one half drawn; the saved region is the polygon."""
    frame = add_frame(server, 313)
    login(page, server, "rita")
    page.goto(f"{server.url}/frames/{frame}")
    open_review(page)
    page.keyboard.press("w")
    page.keyboard.press("7")
    for corner in ((1000, 300), (1250, 300), (1250, 340)):
        page.mouse.click(*to_page(page, *corner))
    page.keyboard.press("Escape")  # half drawn: dropped, nothing filled
    page.mouse.click(*to_page(page, 600, 600))
    page.mouse.click(*to_page(page, 620, 600))
    page.keyboard.press("Escape")
    assert _objects(page)["wire"]["area"] == 0
    wire = [(900, 395), (1270, 300), (1270, 345), (905, 420)]
    for corner in wire:
        page.mouse.click(*to_page(page, *corner))
    shoot(page, "review-new-polygon")  # half drawn: dashed, its first corner larger
    page.mouse.click(*to_page(page, *wire[0]))  # the first corner closes it
    _wait_for_area(page, "wire")
    x, y, w, h = _objects(page)["wire"]["bbox"]
    assert (x, y) == (900, 300) and 370 <= w <= 372 and 120 <= h <= 122
    # A second polygon on the same layer, closed by Enter: a second region of the wire.
    area = _objects(page)["wire"]["area"]
    for corner in ((100, 100), (140, 100), (140, 130)):
        page.mouse.click(*to_page(page, *corner))
    page.keyboard.press("Enter")
    wait_for_js(
        page,
        "(area) => JSON.parse(document.querySelector('[data-testid=frame-canvas]').dataset"
        ".objects).find((o) => o.name === 'wire').area > area",
        arg=area,
    )
    page.uncheck("#advance")
    page.click("[data-testid=save]")
    page.locator("[data-testid=toast-ok]", has_text="Saved as corrected").wait_for()
    saved = server.api("GET", f"/frames/{frame}/label").json()["objects"]
    region = _region(next(o for o in saved if o["class"] == "wire"))
    assert region[400, 950] and region[320, 1260] and not region[330, 950]  # inside, corner, above
    assert region[110, 130] and not region[125, 105]  # the triangle: its hypotenuse cuts the box
    assert not region[600:, :].any()  # the dropped drafts left nothing


def _shown(page: Any, x: float, y: float) -> list[int]:
    """The stage canvas's RGBA at frame pixel (x, y), as drawn."""
    px, py = to_page(page, x, y)
    return list(
        page.evaluate(
            "([px, py]) => { const c = document.querySelector('[data-testid=frame-canvas]');"
            " const r = c.getBoundingClientRect(), s = c.width / r.width;"
            " return Array.from(c.getContext('2d').getImageData(Math.floor((px - r.left) * s),"
            " Math.floor((py - r.top) * s), 1, 1).data); }",
            [px, py],
        )
    )


def test_an_object_painted_beyond_its_first_box(
    page: Any, server: LiveServer, classes: None
) -> None:
    """An object's overlay is as big as its box: a stroke outside the box grows it, and the
    page shows, and saves, both strokes; the overlay holds a fraction of a frame's pixels."""
    frame = add_frame(server, 316)
    login(page, server, "rita")
    page.goto(f"{server.url}/frames/{frame}")
    open_review(page)
    page.keyboard.press("x")
    _brush(page, 12)
    _stroke(page, (100, 100), (150, 100))
    _stroke(page, (300, 160), (340, 160))  # beyond the first stroke's box and its margin
    x, y, w, h = _objects(page)["spatter 1"]["bbox"]
    assert (x, y) == (94, 94) and abs(x + w - 347) <= 1 and abs(y + h - 167) <= 1
    page.wait_for_timeout(100)  # the next animation frame draws it
    shown = [_shown(page, *p) for p in [(125, 100), (320, 160), (600, 500)]]
    page.locator(
        "[data-testid=layer-row][data-class=spatter] [data-testid=layer-visible]"
    ).uncheck()
    page.wait_for_timeout(100)
    hidden = [_shown(page, *p) for p in [(125, 100), (320, 160), (600, 500)]]
    assert shown[0] != hidden[0] and shown[1] != hidden[1]  # both strokes drawn
    assert shown[2] == hidden[2]  # nothing drawn where nothing was painted
    held = page.evaluate("async () => (await import('/static/js/review/layers.js')).heldBytes()")
    overlay = held - 1280 * 800  # less the mask's own bytes
    assert 0 < overlay < 1280 * 800 * 8 / 10  # a full-frame canvas and image hold 8 bytes a pixel
    page.uncheck("#advance")
    page.click("[data-testid=save]")
    page.locator("[data-testid=toast-ok]", has_text="Saved as corrected").wait_for()
    region = _region(server.api("GET", f"/frames/{frame}/label").json()["objects"][0])
    assert region[100, 125] and region[160, 320] and not region[130, 220]


def _box(x: int, y: int, size: int = 60) -> list[list[list[int]]]:
    return [[[x, y], [x + size, y], [x + size, y + size], [x, y + size]]]


def _classes_apart(page: Any) -> list[str]:
    box = page.locator("[data-testid=conflict-classes]")
    wait_for_js(
        page, "() => !!document.querySelector('[data-testid=conflict-classes]').dataset.classes"
    )
    names: list[str] = json.loads(box.get_attribute("data-classes"))
    return names


def test_conflict_keeps_or_takes_every_class(page: Any, server: LiveServer, classes: None) -> None:
    """Only the pool edited here while ada changed the other classes and the tags: "overwrite
    with mine" puts back my wire and tag (not only my pool), "take theirs" loads her objects."""
    frame = add_frame(server, 317)
    wire = {"class": "wire", "polygons": _box(100, 100)}
    first = {"status": "accepted", "base_revision": 0, "objects": [wire], "tags": ["humping"]}
    assert server.api("PUT", f"/frames/{frame}/label", "ada", json=first).status_code == 200
    login(page, server, "rita")
    page.goto(f"{server.url}/frames/{frame}")
    open_review(page)
    page.uncheck("#advance")
    assert list(_objects(page)) == ["wire"]
    page.keyboard.press("4")  # the brush, on the pool: nothing else changes here
    _stroke(page, (600, 100), (700, 100))

    spatter = {"class": "spatter", "polygons": _box(900, 500)}
    theirs = {
        "status": "accepted",
        "base_revision": 1,
        "objects": [spatter],
        "tags": ["arc unstable"],
    }
    assert server.api("PUT", f"/frames/{frame}/label", "ada", json=theirs).status_code == 200
    page.click("[data-testid=save]")
    page.locator("[data-testid=conflict-dialog]").wait_for()
    assert _classes_apart(page) == ["pool", "spatter", "wire", "tags"]
    assert "spatter, wire, tags" in page.inner_text("[data-testid=conflict-classes]")
    assert page.inner_text("[data-testid=conflict-mine-others]") == "wire · tags humping"
    assert page.inner_text("[data-testid=conflict-theirs-others]") == "spatter · tags arc unstable"
    shoot(page, "conflict-classes")
    page.click("[data-testid=conflict-overwrite]")
    page.locator("[data-testid=toast-ok]", has_text="revision 3").wait_for()
    label = server.api("GET", f"/frames/{frame}/label").json()
    assert label["revision"] == 3 and label["tags"] == ["humping"]
    assert [o["class"] for o in label["objects"]] == ["wire"]  # hers is gone, mine is back
    assert _region(label["objects"][0])[130, 130]

    tip = {"class": "wire tip", "points": {"tip": [640, 400]}}
    again = {"status": "accepted", "base_revision": 3, "objects": [spatter, tip], "tags": []}
    assert server.api("PUT", f"/frames/{frame}/label", "ada", json=again).status_code == 200
    page.click("[data-testid=frame-tag][data-tag=humping]")  # a change of mine: the tag off
    page.click("[data-testid=save]")
    page.locator("[data-testid=conflict-dialog]").wait_for()
    assert _classes_apart(page) == ["pool", "spatter", "wire", "wire tip"]  # tags now alike
    page.click("[data-testid=conflict-reload]")
    wait_for_js(
        page, "() => document.querySelector('[data-testid=frame-canvas]').dataset.revision === '4'"
    )
    assert sorted(_objects(page)) == ["spatter 1", "wire tip"]
    assert _objects(page)["wire tip"]["points"]["tip"] == [640, 400]
    assert page.is_hidden("[data-testid=dirty]")
    assert server.api("GET", f"/frames/{frame}/label").json()["revision"] == 4


def test_agreement_of_every_class(page: Any, server: LiveServer, classes: None) -> None:
    """Anna and ada label one frame apart: rita's panel shows each class's agreement and the
    tag and attribute that differ; anna's page loads her own objects and her "Save my label"
    keeps them with the tag she adds."""
    import numpy as np

    from tests.helpers import mask_b64

    frame = add_frame(server, 314, teacher=False)
    ids = {u["username"]: u["id"] for u in server.api("GET", "/users", "ada").json()}
    given = {"frame_ids": [frame], "user_ids": [ids["anna"], ids["ada"]]}
    assert server.api("POST", "/frames/overlap", json=given).status_code == 200
    pool = np.zeros((800, 1280), bool)
    pool[300:500, 500:800] = True
    tip = {"class": "wire tip", "points": {"tip": [640, 400]}}
    anna = {
        "mask_png": mask_b64(pool),
        "objects": [
            {"class": "wire", "polygons": _box(100, 100)},
            {"class": "spatter", "polygons": _box(900, 500, 30)},
            {"class": "spatter", "polygons": _box(1000, 600, 30)},
            tip,
        ],
        "tags": ["humping"],
        "attributes": {"visibility": "good"},
    }
    ada = {
        "mask_png": mask_b64(pool),
        "objects": [
            {"class": "wire", "polygons": _box(130, 100)},
            {"class": "spatter", "polygons": _box(900, 500, 30)},
            {"class": "wire tip", "points": {"tip": [643, 404]}},  # (3, 4) off: 5 px
        ],
        "attributes": {"visibility": "poor"},
    }
    for user, body in (("anna", anna), ("ada", ada)):
        saved = server.api("PUT", f"/frames/{frame}/overlap/mine", user, json=body)
        assert saved.status_code == 200, saved.text
    measured = server.api("GET", f"/frames/{frame}/overlap").json()
    wire_iou = next(c["iou"] for c in measured["classes"] if c["class"] == "wire")

    login(page, server, "rita")
    page.goto(f"{server.url}/frames/{frame}")
    page.locator("[data-testid=agreement-classes]").wait_for()
    rows = page.locator("[data-testid=agreement-class]")
    texts = dict(
        zip(
            rows.evaluate_all("rows => rows.map(r => r.dataset.class)"),
            rows.all_inner_texts(),
            strict=True,
        )
    )
    assert list(texts) == ["pool", "spatter", "wire", "wire tip"]
    assert "IoU 1.000" in texts["pool"]
    assert "1 object apart" in texts["spatter"]
    assert f"IoU {wire_iou:.3f}" in texts["wire"] and 0 < wire_iou < 1
    assert "tip 5.0 px" in texts["wire tip"]
    differ = page.inner_text("[data-testid=agreement-differ]")
    assert "tag “humping” and attribute “visibility”" in differ
    shoot(page, "agreement-classes")

    page.context.clear_cookies()
    login(page, server, "anna")
    page.goto(f"{server.url}/frames/{frame}")
    page.locator("[data-testid=agreement-own]").wait_for()
    wait_for_js(
        page,
        "() => JSON.parse(document.querySelector('[data-testid=frame-canvas]')"
        ".dataset.objects).length === 4",
    )
    assert sorted(_objects(page)) == ["spatter 1", "spatter 2", "wire", "wire tip"]
    page.click("[data-testid=frame-tag][data-tag='arc unstable']")
    page.uncheck("#advance")
    page.click("[data-testid=save]")
    page.locator("[data-testid=toast-ok]", has_text="Your label is saved").wait_for()
    own = server.api("GET", f"/frames/{frame}/overlap", "anna").json()["labels"][0]
    assert [o["class"] for o in own["objects"]] == ["wire", "spatter", "spatter", "wire tip"]
    assert own["objects"][3]["points"] == {"tip": [640.0, 400.0]}
    assert own["tags"] == ["arc unstable", "humping"] and own["attributes"] == {
        "visibility": "good"
    }
    shoot(page, "agreement-own-classes")
