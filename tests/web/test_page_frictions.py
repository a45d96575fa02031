"""Frictions of the models, timeline, review and live pages (issue 58): a forced promotion said
once; a training started elsewhere shown, the train button waiting for it; a warning before a
training the gate could not measure; axes over a physical least span with whole tick labels;
the polygon tool's Tolerance; the live view's placeholders and its outputs' final states. One
server of their own, so the state they build is theirs."""

from __future__ import annotations

import datetime as dt
import shutil
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tests.factories import add_version, synthetic_png
from tests.helpers import corrected_label, image_bytes, write_video
from tests.mqtt import clear_retained, unique_topic
from tests.pages import login, shoot, wait_for_js, wait_until
from tests.web.server import LiveServer

pytestmark = [pytest.mark.browser, pytest.mark.slow]

CANVAS = "[data-testid=frame-canvas]"


@pytest.fixture(scope="module")
def own(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LiveServer]:
    live = LiveServer(tmp_path_factory.mktemp("frictions") / "home").start()
    yield live
    live.stop()


def _labelled(server: LiveServer, mask: np.ndarray, png: bytes, name: str, **form: str) -> int:
    files = [("files", (name, png, "image/png"))]
    stored = server.api("POST", "/frames", files=files, data=form)
    assert stored.status_code == 201, stored.text
    frame_id: int = stored.json()["stored"][0]["id"]
    saved = server.api("PUT", f"/frames/{frame_id}/label", json=corrected_label(mask))
    assert saved.status_code == 200, saved.text
    return frame_id


def test_models_page_forced_version_training_elsewhere_and_too_few_labels(
    page: Any, own: LiveServer
) -> None:
    reason = "the student's masks reach mIoU 0.412 on 2 frames (needs mIoU ≥ 0.7 and none missed)"
    gate = {
        "usable": False,
        "promote": False,
        "reason": f"Not promoted: {reason}.",
        "frames": [1, 2],
    }
    add_version(own, name="forced-v1", is_promoted=True, gate=gate)
    mask = np.zeros((100, 160), bool)
    mask[30:70, 20:120] = True
    _labelled(own, mask, image_bytes(160, 100, seed=5), "one.png")
    login(page, own, "rita")
    dialogs: list[str] = []

    def dismiss(dialog: Any) -> None:
        dialogs.append(dialog.message)
        dialog.dismiss()

    page.on("dialog", dismiss)
    page.goto(f"{own.url}/models")
    page.wait_for_selector("body[data-ready]")
    card = page.locator("[data-testid=model-card]").first
    print(card.evaluate("c => c.outerHTML")[:3000])
    print(
        page.evaluate(
            "fetch('/static/js/models.js').then(r => r.text()).then(t => t.includes('forced'))"
        )
    )
    # Promoted by force, said once: one badge, one sentence, no "promoted" + "not usable" pair.
    assert card.locator(".badge").all_inner_texts() == ["promoted by force"]
    assert card.locator("[data-testid=gate]").inner_text() == (
        f"promoted by force although the promotion gate found it not usable: {reason}. "
        "(2 held-out frames)"
    )
    assert "not usable (" not in card.inner_text() and "Not promoted" not in card.inner_text()
    shoot(page, "models-forced")

    # One label, no validation frame: the page warns before training, with the counts.
    page.click("[data-testid=train-button]")
    wait_until(page, lambda: dialogs)
    assert dialogs[0].startswith(
        "Only 1 label to train on and no frame in the validation split: the promotion gate "
        "measures a version on labels held out from its training, which takes at least 3 labels"
    )
    assert dialogs[0].endswith("Train on 1 label anyway?")
    page.wait_for_timeout(300)
    assert own.api("GET", "/jobs", params={"kind": "train_student"}).json()["total"] == 0
    assert page.is_enabled("[data-testid=train-button]")

    # A training another person started shows here, with its progress; the button waits.
    started = own.api("POST", "/student/train", user="ada", json={"epochs": 1000})
    assert started.status_code == 202 and started.json()["warning"].startswith("Only 1 label")
    job_id = started.json()["job_id"]
    wait_for_js(page, "document.querySelector('[data-testid=train-button]').disabled")
    state = page.inner_text("[data-testid=train-state]")
    assert state.startswith(f"Training job #{job_id} (started by ada): ")
    title = page.get_attribute("[data-testid=train-button]", "title")
    assert title.startswith(f"Training job #{job_id} is ")
    assert title.endswith("one training runs at a time: wait for it to finish.")
    wait_for_js(
        page, "/running/.test(document.querySelector('[data-testid=train-state]').textContent)"
    )
    shoot(page, "models-training-elsewhere")
    own.api("POST", f"/jobs/{job_id}/cancel", user="ada")
    assert own.wait_for_job(job_id)["status"] == "cancelled"
    wait_for_js(page, "!document.querySelector('[data-testid=train-button]').disabled")
    page.wait_for_selector(
        f"[data-testid=toast-error]:has-text('Training job #{job_id} cancelled')"
    )


def test_timeline_axes_keep_a_physical_span_and_whole_tick_labels(
    page: Any, own: LiveServer
) -> None:
    run = own.api("POST", "/sequences", json={"name": "steady run", "mm_per_px": 0.01})
    assert run.status_code == 201, run.text
    for i in range(4):  # a steady pool, one pixel of noise: 0.01 mm
        mask = np.zeros((100, 160), bool)
        mask[30:70, 20 : 120 + (i % 2)] = True
        png = image_bytes(160, 100, seed=20 + i)
        _labelled(own, mask, png, f"s{i}.png", sequence_id=str(run.json()["id"]))
    login(page, own, "rita")
    page.goto(f"{own.url}/sequences/{run.json()['id']}")
    page.wait_for_selector("body[data-ready]")
    charts = page.locator("[data-testid=geometry-charts] svg.chart")
    spans = {}
    for i in range(3):
        chart = charts.nth(i)
        low, high = map(float, chart.get_attribute("data-y-domain").split())
        spans[chart.get_attribute("aria-label")] = high - low
    # length ~1 mm, width 0.4 mm, area 0.4 mm²: at least 0.5 mm (1 mm²) or a tenth of the mean
    assert spans["Length along travel"] == pytest.approx(0.5)
    assert spans["Width across travel"] == pytest.approx(0.5)
    assert spans["Pool area"] == pytest.approx(1.0)
    shoot(page, "timeline-steady", full_page=True)
    # Every tick label inside its chart, on this page and for large numbers (px² of a big pool).
    outside = page.evaluate(
        """async () => {
          const { lineChart } = await import("/static/js/chart.js");
          const big = lineChart({ title: "Pool area", unit: "px²", xLabel: "frame", width: 420,
            height: 180, series: [{ name: "a", colour: "#000",
              points: [[0, 1234567.5], [1, 1234890.25], [2, 1235001]] }] });
          document.querySelector("[data-testid=geometry-charts]").append(big);
          const cut = [];
          for (const svg of document.querySelectorAll("[data-testid=geometry-charts] svg.chart")) {
            const width = svg.viewBox.baseVal.width;
            for (const text of svg.querySelectorAll("text")) {
              const box = text.getBBox();
              if (box.x < 0 || box.x + box.width > width + 0.5) cut.push(text.textContent);
            }
          }
          return cut;
        }"""
    )
    assert outside == []


def test_the_polygon_tools_advice_names_a_control_of_the_page(page: Any, own: LiveServer) -> None:
    mask = np.zeros((800, 1280), bool)
    for bar in range(10):  # combed edges: ~24,000 vertices at tolerance 1, 40 at 3
        y = 40 + bar * 70
        mask[y : y + 40, 40:1240] = True
        mask[y - 3 : y, 40:1240:2] = True
        mask[y + 40 : y + 43, 40:1240:2] = True
    frame_id = _labelled(own, mask, synthetic_png(90), "comb.png")
    login(page, own, "rita")
    page.goto(f"{own.url}/frames/{frame_id}")
    page.wait_for_selector("body[data-ready]")
    page.wait_for_selector(f"{CANVAS}[data-ready]")
    assert not page.is_visible("[data-testid=outline-tolerance]")  # the polygon tool's only
    page.keyboard.press("7")
    page.wait_for_selector("[data-testid=toast-error]:has-text('raise the tolerance')")
    tolerance = page.locator("[data-testid=outline-tolerance]")
    assert tolerance.is_visible() and tolerance.input_value() == "1"
    label = page.locator("#outline-tolerance-group").inner_text()
    assert label.startswith("Tolerance")  # the word the advice uses
    tolerance.fill("4")
    tolerance.press("Enter")
    wait_for_js(
        page,
        f"JSON.parse(document.querySelector('{CANVAS}').dataset.outline || '[]').length === 10",
    )
    outline = page.evaluate(f"JSON.parse(document.querySelector('{CANVAS}').dataset.outline)")
    assert sum(len(p["points"]) for p in outline) <= 80
    shoot(page, "review-polygon-tolerance")


def test_live_view_placeholders_and_its_outputs_final_state(
    page: Any, own: LiveServer, tmp_path: Path, mqtt_broker: tuple[str, int]
) -> None:
    from tests.core.student.common import TINY_STUDENT, synthetic_frames, tiny_config
    from weldpool_core.student.train import train_student

    folder = tmp_path / "student"
    train_student(synthetic_frames(4), folder, TINY_STUDENT, tiny_config(epochs=1))
    shutil.copytree(folder, own.home / "models" / "live-v1")
    version = add_version(own, name="live-v1", checkpoint_path="models/live-v1")
    login(page, own, "rita")

    # A first start, while the student is exported for ONNX Runtime (the answer held there).
    fake = {
        "id": 999,
        "source": "/videos/run.avi",
        "model_name": "live-v1",
        "model_id": version,
        "gate": None,
        "started_by": "rita",
        "started_at": dt.datetime.now(dt.UTC).isoformat(),
        "state": "starting",
        "message": "exporting model.onnx for ONNX Runtime",
        "frames": 0,
        "dropped": 0,
        "fps": None,
        "latency_p50_ms": None,
        "latency_p99_ms": None,
        "smooth": True,
        "sequential": False,
        "int8": False,
        "mm_per_px": None,
        "last": None,
        "outputs": [],
    }
    page.route("**/api/v1/live", lambda route: route.fulfill(json=[fake]))
    page.route("**/api/v1/live/999/**", lambda route: route.fulfill(json={"records": []}))
    page.goto(f"{own.url}/live?model_id={version}")
    placeholder = page.locator("[data-testid=live-placeholder]")
    placeholder.wait_for()
    text = placeholder.inner_text()
    assert text.startswith("Preparing the student (exporting it to ONNX)…")
    assert "exports it for ONNX Runtime once: " in text and " s so far" in text
    assert not page.is_visible("[data-testid=live-frame]")
    shoot(page, "live-preparing")
    page.unroute("**/api/v1/live")
    page.unroute("**/api/v1/live/999/**")

    # A real view with an MQTT output, stopped by hand: a placeholder, not a broken image, and
    # the output reads disconnected (the broker never went away).
    host, port = mqtt_broker
    topic = unique_topic("live-stop")
    video = write_video(tmp_path / "steady run.avi", 400, fps=20.0)
    page.goto(f"{own.url}/live?model_id={version}")
    page.wait_for_selector("body[data-ready]")
    wait_for_js(page, "document.querySelector('[data-testid=live-model]').options.length > 1")
    page.fill("[data-testid=live-source]", str(video))
    page.click("[data-testid=live-outputs-form] summary")
    page.fill("[data-testid=live-mqtt]", f"mqtt://{host}:{port}/{topic}")
    page.click("[data-testid=live-start]")
    card = page.locator("[data-testid=live-card][data-state=running]")
    card.wait_for(timeout=60_000)
    wait_for_js(page, "document.querySelector('[data-testid=live-frame]').naturalWidth > 0")
    assert not placeholder.first.is_visible()
    wait_for_js(
        page,
        "/connected/.test(document.querySelector('[data-testid=live-output-mqtt]').textContent)",
    )
    card.locator("[data-testid=live-stop]").click()
    stopped = page.locator("[data-testid=live-card][data-state=stopped]")
    stopped.wait_for()
    image = stopped.locator("[data-testid=live-frame]")
    assert image.get_attribute("src") is None and not image.is_visible()
    assert stopped.locator("[data-testid=live-placeholder]").inner_text() == (
        "Stopped\nThis view is stopped: it no longer runs. Start it again above."
    )
    output = stopped.locator("[data-testid=live-output-mqtt]").inner_text()
    assert " · disconnected · " in output and "reconnecting" not in output
    # Its curves, as the timeline's: a steady pool's width over a tenth of its mean at least.
    low, high = map(
        float, stopped.locator("svg[aria-label=Width]").get_attribute("data-y-domain").split()
    )
    assert high - low >= 5
    shoot(page, "live-stopped")
    clear_retained(host, port, f"{topic}/status")
