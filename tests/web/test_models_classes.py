"""The models page shows the classes a version learned beside the pool (issue 59): per class the
promotion gate's figure, the incumbent's on the same frames with the difference, and the
training's validation figure (IoU or point distance), kept apart from the pool's metrics; a
pool-only version shows no such table. One server of its own."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest

from tests.factories import add_version
from tests.pages import login, shoot
from tests.web.server import LiveServer

pytestmark = [pytest.mark.browser, pytest.mark.slow]


@pytest.fixture(scope="module")
def own(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LiveServer]:
    live = LiveServer(tmp_path_factory.mktemp("model-classes") / "home").start()
    yield live
    live.stop()


def test_the_models_page_shows_each_learned_class(page: Any, own: LiveServer) -> None:
    student = {
        "classes": [
            {"name": "wire", "kind": "mask", "points": []},
            {"name": "wire tip", "kind": "points", "points": ["tip"]},
            {"name": "spatter", "kind": "instances", "points": []},
        ]
    }
    gate = {
        "usable": True,
        "promote": True,
        "reason": "Better than v1 and the teacher on 3 held-out frames (mIoU 0.912).",
        "frames": [1, 2, 3],
        "incumbent": "v1",
        "classes": {
            "wire": {"kind": "mask", "frames": 3, "IoU": 0.6234},
            "wire tip": {"kind": "points", "frames": 2, "distance_px": 4.25, "missed": 1},
            "spatter": {"kind": "instances", "frames": 3, "IoU": 0.4},
        },
        "incumbent_classes": {
            "wire": {"kind": "mask", "frames": 3, "IoU": 0.5},
            "wire tip": {"kind": "points", "frames": 2, "distance_px": 2.0, "missed": 0},
            "spatter": None,
        },
    }
    metrics = {
        "mIoU": 0.91,
        "mED": 6.5,
        "classes": {"wire": {"kind": "mask", "frames": 1, "IoU": 0.7}},
    }
    learned = add_version(
        own, name="with-classes", config={"student": student}, gate=gate, metrics=metrics
    )
    add_version(own, name="pool-only", config={"student": {}}, metrics={"mIoU": 0.9})
    first_gate = {k: gate[k] for k in ("usable", "promote", "frames", "classes")}
    first_gate["reason"] = "Better than the teacher on 3 held-out frames (mIoU 0.912)."
    add_version(own, name="first-with-classes", config={"student": student}, gate=first_gate)
    login(page, own, "rita")
    page.goto(f"{own.url}/models")
    page.wait_for_selector("body[data-ready]")
    card = page.locator(f"[data-testid=model-card][data-model-id='{learned}']")
    table = card.locator("[data-testid=model-classes]")
    heads = table.locator("thead th").all_inner_texts()
    assert heads == ["learned class", "kind", "gate", "v1 (incumbent)", "difference", "validation"]
    rows = [row.split("\t") for row in table.locator("tbody tr").all_inner_texts()]
    assert rows[0] == [
        "wire",
        "mask",
        "IoU 0.623 on 3 frames",
        "IoU 0.500",
        "+0.123",
        "IoU 0.700 on 1 frame",
    ]
    assert rows[1] == [
        "wire tip (tip)",
        "points",
        "4.3 px on 2 frames · 1 point not found",
        "2.0 px",
        "+2.3 px",  # a longer distance: worse
        "–",
    ]
    assert rows[2] == [
        "spatter",
        "instances",
        "IoU 0.400 on 3 frames",
        "–",
        "–",
        "–",
    ]  # v1 lacks it
    verdicts = table.locator("td[data-verdict]")
    assert [verdicts.nth(i).get_attribute("data-verdict") for i in range(2)] == ["better", "worse"]
    assert "[object Object]" not in card.inner_text()  # the classes are not a pool metric
    plain = page.locator("[data-testid=model-card]:has-text('pool-only')")
    assert plain.locator("[data-testid=model-classes]").count() == 0
    alone = page.locator("[data-testid=model-card]:has-text('first-with-classes')")
    first = alone.locator("[data-testid=model-classes] thead th").all_inner_texts()
    assert first == ["learned class", "kind", "gate", "validation"]  # no incumbent at its gate
    card.scroll_into_view_if_needed()
    shoot(page, "models-classes")
