"""Labels of several classes in the browser: the frames list filtered by class, tag and frame
attribute from its controls (the server's sentence for a value it does not know), the
timeline's class series and tag marks, and the metrics page's per-class figures."""

from __future__ import annotations

from typing import Any

import pytest

from tests.factories import synthetic_png
from tests.helpers import corrected_label
from tests.pages import login, shoot, wait_for_js
from tests.web.server import LiveServer
from weldpool_core.synth import SynthParams, synth_frame

pytestmark = [pytest.mark.browser, pytest.mark.slow]

LAB = {
    "classes": [
        {"name": "wire", "kind": "mask", "color": "#00aaff"},
        {"name": "spatter", "kind": "instances", "color": "#ff0000"},
        {"name": "wire tip", "kind": "points", "point_names": ["tip"]},
    ],
    "frame_tags": ["humping", "arc unstable"],
    "frame_attributes": [{"name": "joint", "type": "choice", "options": ["butt", "fillet"]}],
}
FRAMES = 12


def _box(x: int, y: int, size: int) -> list[list[int]]:
    return [[x, y], [x + size, y], [x + size, y + size], [x, y + size]]


def _objects(i: int) -> list[dict[str, Any]]:
    """Frame ``i``'s objects: a wire on even frames, ``i % 4`` spatters, a wire tip."""
    objects: list[dict[str, Any]] = [
        {"class": "spatter", "polygons": [_box(100 + 60 * k, 100 + 10 * i, 10 + 4 * k)]}
        for k in range(i % 4)
    ]
    if i % 2 == 0:
        objects.append(
            {"class": "wire", "polygons": [[[600, 0], [680, 0], [660, 300], [620, 300]]]}
        )
    objects.append({"class": "wire tip", "points": {"tip": [640, 300 + 5 * i]}})
    return objects


def _tags(i: int) -> list[str]:
    return ["humping"] if i in (3, 4, 9) else ["arc unstable"] if i == 6 else []


@pytest.fixture(scope="module")
def run(server: LiveServer) -> Any:
    """A run of 12 frames, 10 labelled with wires, spatters, tips, tags and joints, under its
    own label configuration (the previous one is put back after)."""
    before = server.api("GET", "/label-config", user="ada").json()
    saved = server.api(
        "PUT", "/label-config", user="ada", json=LAB | {"version": before["version"]}
    )
    assert saved.status_code == 200, saved.text
    run_id = server.api("POST", "/sequences", json={"name": "classes run"}).json()["id"]
    files = [
        ("files", (f"c{i:02d}.png", synthetic_png(500 + i), "image/png")) for i in range(FRAMES)
    ]
    stored = server.api("POST", "/frames", files=files, data={"sequence_id": str(run_id)})
    ids = [f["id"] for f in stored.json()["stored"]]
    for i, frame_id in enumerate(ids[:10]):
        mask = synth_frame(seed=500 + i, params=SynthParams(1280, 800)).mask
        body = corrected_label(mask) | {"objects": _objects(i), "tags": _tags(i)}
        body["attributes"] = {"joint": "butt" if i < 5 else "fillet"}
        label = server.api("PUT", f"/frames/{frame_id}/label", json=body)
        assert label.status_code == 200, label.text
    yield run_id, ids
    back = {k: before[k] for k in ("classes", "frame_tags", "frame_attributes") if k in before} | {
        "version": saved.json()["version"],
        "force": True,
    }
    assert server.api("PUT", "/label-config", user="ada", json=back).status_code == 200


def _rows(page: Any) -> list[int]:
    page.wait_for_load_state("networkidle")
    return [
        int(row.get_attribute("data-frame-id"))
        for row in page.locator("[data-testid=frame-row]").all()
    ]


def test_the_frames_list_filters_by_class_tag_and_attribute(
    page: Any, server: LiveServer, run: Any
) -> None:
    run_id, ids = run
    login(page, server)
    page.goto(f"{server.url}/?sequence_id={run_id}&status=all&order=id")
    page.wait_for_selector("body[data-ready]")
    assert _rows(page) == ids
    options = page.locator("[data-testid=filter-class] option").all_text_contents()
    assert options[:2] == ["any", "pool (a pool mask)"] and "spatter (instances)" in options
    page.select_option("[data-testid=filter-class]", "wire")
    wait_for_js(page, "document.querySelectorAll('[data-testid=frame-row]').length === 5")
    assert _rows(page) == [ids[i] for i in (0, 2, 4, 6, 8)]
    assert "class=wire" in page.url  # the URL keeps the filter
    page.select_option("[data-testid=filter-tag]", "humping")
    wait_for_js(page, "document.querySelectorAll('[data-testid=frame-row]').length === 1")
    assert _rows(page) == [ids[4]]  # a wire and humping: frame 4 alone
    page.select_option("[data-testid=filter-class]", "")
    page.select_option("[data-testid=filter-tag]", "")
    page.fill("[data-testid=filter-attr]", "joint:butt")
    page.press("[data-testid=filter-attr]", "Enter")
    wait_for_js(page, "document.querySelectorAll('[data-testid=frame-row]').length === 5")
    assert _rows(page) == ids[:5]
    page.select_option("[data-testid=filter-class]", "spatter")
    wait_for_js(page, "document.querySelectorAll('[data-testid=frame-row]').length === 3")
    assert _rows(page) == [ids[i] for i in (1, 2, 3)]
    shoot(page, "frames-class-filter", idle=True)
    page.reload()  # the filters come back from the URL
    page.wait_for_selector("body[data-ready]")
    assert page.input_value("[data-testid=filter-class]") == "spatter"
    assert _rows(page) == [ids[i] for i in (1, 2, 3)]
    page.fill("[data-testid=filter-attr]", "joint:lap")
    page.press("[data-testid=filter-attr]", "Enter")
    page.locator("td.error", has_text="its options: 'butt', 'fillet'").wait_for()


def test_the_timeline_plots_a_class_and_marks_tagged_frames(
    page: Any, server: LiveServer, run: Any
) -> None:
    run_id, _ = run
    login(page, server)
    page.goto(f"{server.url}/sequences/{run_id}")
    page.wait_for_selector("body[data-ready]")
    tagged = page.locator("[data-testid=strip-cell].tagged")
    assert tagged.count() == 4
    assert "tags: humping" in (tagged.first.get_attribute("title") or "")
    page.select_option("[data-testid=tag-mark]", "arc unstable")
    assert page.locator("[data-testid=strip-cell].tagged").count() == 1
    series = page.locator("[data-testid=class-series] option").all_text_contents()
    assert series[:2] == ["wire: area", "wire: objects"] and "wire tip: tip y" in series
    page.select_option("[data-testid=class-series]", "spatter|count")
    dots = page.locator("[data-testid=class-chart] circle")
    assert dots.count() == 10  # one per labelled frame, none for the two without a label
    page.select_option("[data-testid=tag-mark]", "")
    page.locator("[data-testid=class-chart]").scroll_into_view_if_needed()
    shoot(page, "timeline-class-series", full_page=True)


def test_the_metrics_page_counts_each_class(page: Any, server: LiveServer, run: Any) -> None:
    login(page, server)
    page.goto(f"{server.url}/metrics")
    page.wait_for_selector("[data-testid=class-table]")
    figures = server.api("GET", "/metrics/classes").json()
    rows = page.locator("[data-testid=class-table] tbody tr").all_inner_texts()
    wire = next(c for c in figures["classes"] if c["name"] == "wire")
    assert any(r.startswith("wire\tmask\t") and f"\t{wire['frames']}\t" in r for r in rows), rows
    assert wire["frames"] >= 5 and wire["objects"] >= 5  # the server is shared
    page.locator("[data-testid=class-figures]").scroll_into_view_if_needed()
    shoot(page, "metrics-classes")
