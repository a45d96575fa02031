"""The process map page and a run's stability on its timeline, in the browser."""

from __future__ import annotations

from typing import Any

import numpy as np

from tests.helpers import corrected_label, image_bytes
from tests.pages import login, shoot
from tests.web.server import LiveServer


def _run(server: LiveServer, name: str, amps: float, widths: list[int]) -> int:
    """A run at ``amps`` with a scale and one labelled frame per width (a 60 px long pool)."""
    run = server.api(
        "POST",
        "/sequences",
        json={"name": name, "voltage_v": 22.0, "current_a": amps, "robot_speed_cm_min": 40.0},
    ).json()
    assert server.api("PATCH", f"/sequences/{run['id']}", json={"mm_per_px": 0.1}).is_success
    seeds = [900 + 40 * i + int(amps) for i in range(len(widths))]
    files = [
        ("files", (f"{name}-{i}.png", image_bytes(160, 100, seed=seed), "image/png"))
        for i, seed in enumerate(seeds)
    ]
    stored = server.api("POST", "/frames", files=files, data={"sequence_id": run["id"]})
    for frame, width in zip(stored.json()["stored"], widths, strict=True):
        mask = np.zeros((100, 160), bool)
        mask[50 - width // 2 : 50 + width // 2, 40:120] = True
        saved = server.api("PUT", f"/frames/{frame['id']}/label", json=corrected_label(mask))
        assert saved.status_code == 200, saved.text
    return int(run["id"])


def test_the_map_draws_runs_with_their_fit_and_opens_a_runs_unstable_stretch(
    page: Any, server: LiveServer
) -> None:
    steady = [_run(server, f"map run {a:g} A", a, [20] * 8) for a in (150.0, 200.0)]
    shaky = _run(server, "map run shaky", 250.0, [24, 24, 24, 24, 16, 32, 14, 34, 16, 32, 24, 24])
    login(page, server)
    page.goto(f"{server.url}/process?x=current_a&y=width_mm")
    page.wait_for_selector("body[data-ready='1']")
    names = page.locator("[data-testid=process-run] td:first-child").all_inner_texts()
    assert {"map run 150 A", "map run 200 A", "map run shaky"} <= set(names)
    assert "Fit: width (mm)" in page.inner_text("[data-testid=fit]")
    shoot(page, "process-map", full_page=True)
    page.select_option("[data-testid=pick-y]", "width_cv")
    page.wait_for_function("() => location.search.includes('y=width_cv')")
    page.click("text=map run shaky")
    page.wait_for_url(f"{server.url}/sequences/{shaky}?frame=*")
    page.wait_for_selector("[data-testid=unstable-stretch]")
    assert page.locator(".strip .cell.unstable").count() >= 3
    assert page.locator(".strip .cell.wanted").count() == 1
    assert "1 stretch" in page.inner_text("[data-testid=signature]")
    shoot(page, "timeline-unstable-stretch", full_page=True)
    page.goto(f"{server.url}/sequences/{steady[0]}")
    page.wait_for_selector("body[data-ready='1']")
    assert "No unstable stretch" in page.inner_text("[data-testid=stability]")
    assert page.locator(".strip .cell.unstable").count() == 0
