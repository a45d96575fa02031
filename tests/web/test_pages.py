"""The pages one by one in a real browser: login redirects, roles, the 409 dialog, undo / redo
and shortcuts, the unsaved-changes warning, jobs with live progress and cancel, video upload,
the models page; and the screenshots a reviewer looks at."""

from __future__ import annotations

import base64
import re
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from tests.factories import add_frame, synthetic_png
from tests.helpers import corrected_label, image_bytes, write_video
from tests.mqtt import free_port
from tests.pages import (
    CANVAS,
    accept_dialogs,
    canvas_data,
    fixed,
    login,
    open_review,
    shoot,
    to_page,
    wait_for_js,
    wait_for_mask_change,
    wait_until,
)
from tests.web.server import LiveServer
from weldpool_core.synth import SynthParams, synth_frame

pytestmark = [pytest.mark.browser, pytest.mark.slow]


def save_true_label(
    server: LiveServer, frame_id: int, seed: int, width: int = 1280, height: int = 800
) -> np.ndarray:
    """Save a synthetic frame's true pool mask as its corrected label, as a reviewer would;
    returns the mask."""
    mask = synth_frame(seed=seed, params=SynthParams(width, height)).mask
    saved = server.api("PUT", f"/frames/{frame_id}/label", json=corrected_label(mask))
    assert saved.status_code == 200, saved.text
    return mask


def stroke(page: Any, start: tuple[float, float], end: tuple[float, float]) -> None:
    page.mouse.move(*to_page(page, *start))
    page.mouse.down()
    page.mouse.move(*to_page(page, *end), steps=8)
    page.mouse.up()


def test_pages_redirect_to_login(browser: Any, server: LiveServer) -> None:
    context = browser.new_context()
    try:
        page = context.new_page()
        for path in ("/", "/frames/1", "/jobs", "/models"):
            page.goto(f"{server.url}{path}")
            assert page.url == f"{server.url}/login?next={path}"
            assert page.is_visible("input[name=username]")
    finally:
        context.close()


def test_the_api_page_works_offline_under_the_content_security_policy(
    page: Any, server: LiveServer
) -> None:
    """Swagger UI comes from static/, not a CDN: with every other host unreachable it renders
    the schema; the page fixture fails on anything the CSP blocks."""
    elsewhere: list[str] = []

    def only_this_server(route: Any) -> None:
        if route.request.url.startswith(server.url):
            route.continue_()
        else:
            elsewhere.append(route.request.url)
            route.abort()

    page.route("**/*", only_this_server)
    login(page, server, "rita")
    response = page.goto(f"{server.url}/docs")
    assert "frame-ancestors 'none'" in response.headers["content-security-policy"]
    page.wait_for_selector(".swagger-ui .opblock-tag", timeout=20_000)
    assert page.locator(".swagger-ui .title").first.inner_text().startswith("weldpool")
    assert elsewhere == []
    shoot(page, "docs")


def test_screenshots_of_review_and_models(page: Any, server: LiveServer) -> None:
    """A reviewed frame as a reviewer sees it (the synthetic ground truth saved as its label),
    and the models page; written to test-artifacts/screenshots/."""
    seed = 7
    frame_id = add_frame(server, seed)
    truth = save_true_label(server, frame_id, seed)

    login(page, server, "rita")
    page.goto(f"{server.url}/frames/{frame_id}")
    open_review(page)
    assert canvas_data(page, "mask-area") == int(truth.sum())
    assert len(canvas_data(page, "keypoints")) == 4
    page.wait_for_selector("[data-testid=label-history] .badge.corrected")
    shoot(page, "review")
    page.check("[data-testid=show-heatmap]")
    page.wait_for_selector(f"{CANVAS}[data-heatmap=loaded]")
    shoot(page, "review-heatmap")

    page.goto(f"{server.url}/")
    page.wait_for_selector("body[data-ready]")
    shoot(page, "frames")
    page.goto(f"{server.url}/jobs")
    page.wait_for_selector("body[data-ready]")
    # A finished job says what it did in words (no raw result fields, no progress line).
    teacher_row = page.locator("[data-testid=job-row]", has_text="teacher").first
    assert teacher_row.locator("td.message").inner_text() == "1 frame proposed"
    shoot(page, "jobs")
    page.goto(f"{server.url}/models")
    page.wait_for_selector("body[data-ready]")
    assert page.is_visible("[data-testid=train-button]")
    shoot(page, "models")


def test_models_page_shows_a_trained_version_and_promotes_it(page: Any, server: LiveServer) -> None:
    """A real student version (4 reviewed frames, 2 epochs on the live server) as the API
    returns it: its card, metrics, curves and the gate's verdict; then Promote through the
    real endpoint, forcing it when the gate refuses (both dialogs accepted)."""
    for seed in range(410, 414):
        save_true_label(server, add_frame(server, seed), seed)
    job = server.api("POST", "/student/train", json={"epochs": 2}).json()
    assert server.wait_for_job(job["job_id"], timeout=300)["status"] == "succeeded"
    models = server.api("GET", "/models").json()
    newest = models[0]

    login(page, server, "rita")
    dialogs = accept_dialogs(page)
    page.goto(f"{server.url}/models")
    page.wait_for_selector("[data-testid=model-card]")
    cards = page.locator("[data-testid=model-card]")
    assert cards.count() == len(models)
    card = page.locator(f"[data-testid=model-card][data-model-id='{newest['id']}']")
    text = card.inner_text()
    assert newest["name"] in text and f"trained on {newest['train_label_count']} labels" in text
    assert f"{fixed(newest['metrics']['mIoU'], 3)}" in text
    assert card.locator("svg.chart").count() >= 2  # loss and mIoU curves at least
    # One way to write numbers: no long decimals, counts as integers, mED_k in px, whole epochs
    # (a chart's tick labels carry what their step needs: distinct, checked below).
    words = card.evaluate(
        "(c) => { const k = c.cloneNode(true);"
        " k.querySelectorAll('svg').forEach((s) => s.remove()); return k.textContent; }"
    )
    assert not re.search(r"\d\.\d{4,}", words), words
    assert re.search(r"keypoints missed\s+\d+\n", text)
    assert re.search(r"mED per keypoint \(1, 2, …\)\s+[\d.]+ px ·", text)
    assert not re.search(r"mED_k|mED_penalised|best_epoch", words), words  # words, not keys
    ticks = card.locator("svg.chart .grid text[text-anchor=middle]").evaluate_all(
        "nodes => nodes.map((n) => n.textContent)"
    )
    assert ticks and all(t.isdigit() for t in ticks), ticks
    svg_texts = "(nodes) => nodes.map((n) => n.textContent)"
    axis = card.locator("svg.chart .axis-label").evaluate_all(svg_texts)
    assert axis and set(axis) == {"round"}  # as the training job says it
    for chart in card.locator("svg.chart").all():  # every score axis: distinct labels
        labels = chart.locator(".y-tick").evaluate_all(svg_texts)
        assert len(labels) == len(set(labels)), labels
    page.goto(f"{server.url}/metrics")
    student_row = page.locator("[data-testid=student-table] tr", has_text=newest["name"])
    assert f"{fixed(newest['metrics']['mIoU'], 3)}" in student_row.inner_text()
    page.goto(f"{server.url}/models")
    page.wait_for_selector(f"[data-testid=model-card][data-model-id='{newest['id']}']")
    gate = card.locator("[data-testid=gate]").inner_text()
    assert newest["gate"]["reason"] in gate
    assert ("not usable" in gate) != newest["gate"]["usable"]
    shoot(page, "models-trained", full_page=True)
    if newest["is_promoted"]:
        assert card.locator("[data-testid=promote]").count() == 0
        assert card.locator(".badge.promoted").count() == 1
        return
    card.locator("[data-testid=promote]").click()
    wait_until(
        page,
        lambda: server.api("GET", f"/models/{newest['id']}").json()["is_promoted"],
        timeout=60_000,
    )
    assert dialogs[0].startswith(f"Promote {newest['name']}?")
    assert len(dialogs) == (1 if newest["gate"]["usable"] else 2)  # a refusal asks to force
    if not newest["gate"]["usable"]:  # in words for people, not the API's force=true
        assert dialogs[1].startswith(f"{newest['name']} did not pass the promotion gate: ")
        assert "force=true" not in dialogs[1] and "Promote it anyway?" in dialogs[1]
    page.wait_for_selector(
        f"[data-testid=model-card][data-model-id='{newest['id']}'] .badge.promoted"
    )


def test_annotator_saves_corrections_and_uploads_a_video(
    page: Any, server: LiveServer, tmp_path: Path
) -> None:
    frame_id = add_frame(server, 301)
    login(page, server, "anna")
    page.goto(f"{server.url}/frames/{frame_id}")
    open_review(page)
    assert page.is_disabled("[data-testid=accept]") and page.is_disabled("[data-testid=reject]")
    page.uncheck("#advance")
    page.keyboard.press("4")
    assert page.get_attribute("[data-testid=tool-brush]", "aria-pressed") == "true"
    before = canvas_data(page, "mask-area")
    stroke(page, (100, 700), (600, 700))
    assert canvas_data(page, "mask-area") > before
    page.keyboard.press("s")
    page.wait_for_selector("[data-testid=toast-ok]:has-text('corrected')")
    label = server.api("GET", f"/frames/{frame_id}/label").json()
    assert (label["status"], label["updated_by"]) == ("corrected", "anna")
    assert page.is_hidden("[data-testid=dirty]")

    page.goto(f"{server.url}/models")
    page.wait_for_selector("body[data-ready]")
    assert page.locator("[data-testid=train-button]").count() == 0

    video = tmp_path / "run.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10, (64, 48))
    for index in range(6):
        image = np.full((48, 64, 3), 30, np.uint8)
        cv2.circle(image, (10 + 4 * index, 24), 6, (200, 120, 40), -1)
        writer.write(image)
    writer.release()
    page.goto(f"{server.url}/")
    page.wait_for_selector("body[data-ready]")
    assert page.input_value("[data-testid=every-nth]") == "10"  # not every frame by default
    assert page.inner_text("[data-testid=every-nth-text]") == "every 10th frame"
    page.fill("#every-nth", "2")
    assert page.inner_text("[data-testid=every-nth-text]") == "every 2nd frame"
    page.set_input_files("[data-testid=upload-input]", str(video))
    # Nothing is sent before "Import": the header's frame count gives the estimate first.
    offer = page.locator("[data-testid=upload-item][data-name='run.avi'][data-state=offered]")
    estimate = offer.locator("[data-testid=video-estimate]")
    wait_until(page, lambda: "→ 3 frames kept" in estimate.inner_text())
    assert estimate.inner_text() == "6 frames at 10.0 fps (0.6 s) → 3 frames kept"
    offer.locator("[data-testid=video-every-nth]").fill("4")
    assert estimate.inner_text().endswith("→ 2 frames kept")
    shoot(page, "video-estimate")
    offer.locator("[data-testid=video-import]").click()
    item = page.locator("[data-testid=upload-item][data-name='run.avi'][data-state=ok]")
    item.wait_for(timeout=60_000)
    assert "extracted 2 frames" in item.inner_text()  # as estimated
    page.reload()  # the step is remembered for the next upload
    page.wait_for_selector("body[data-ready]")
    assert page.input_value("[data-testid=every-nth]") == "2"


def test_the_video_estimate_reads_an_mp4_header_as_opencv_does(
    page: Any, server: LiveServer, tmp_path: Path
) -> None:
    """The upload's frame estimate for an MP4 (the video track's sample count and duration,
    read in the browser before anything is sent) agrees with OpenCV's probe of the same file;
    a file that is no video gives no estimate rather than a wrong one."""
    video = tmp_path / "run.mp4"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"mp4v"), 25.0, (64, 48))
    for index in range(37):
        writer.write(np.full((48, 64, 3), 5 * index, np.uint8))
    writer.release()
    capture = cv2.VideoCapture(str(video))
    frames, fps = int(capture.get(cv2.CAP_PROP_FRAME_COUNT)), capture.get(cv2.CAP_PROP_FPS)
    capture.release()
    assert frames == 37
    login(page, server, "rita")
    page.wait_for_selector("body[data-ready]")
    probe = """async ([b64, name]) => {
      const { probeVideo } = await import('/static/js/video.js');
      const bytes = Uint8Array.from(atob(b64), (c) => c.charCodeAt(0));
      return await probeVideo(new File([bytes], name));
    }"""
    found = page.evaluate(probe, [base64.b64encode(video.read_bytes()).decode(), "run.mp4"])
    assert found["frames"] == frames
    assert found["fps"] == pytest.approx(fps, rel=1e-3)
    assert found["duration_s"] == pytest.approx(frames / fps, rel=1e-3)
    not_video = base64.b64encode(b"\x00\x00\x00\x18ftypisom" + bytes(64)).decode()
    assert page.evaluate(probe, [not_video, "broken.mp4"]) is None


def test_conflict_dialog_overwrite_and_reload(page: Any, server: LiveServer) -> None:
    frame_id = add_frame(server, 401)
    login(page, server, "rita")
    page.goto(f"{server.url}/frames/{frame_id}")
    open_review(page)
    page.uncheck("#advance")

    # Someone else accepts while the page is open; our reject meets a 409: overwrite.
    other = server.api(
        "PUT", f"/frames/{frame_id}/label", "ada", json={"status": "accepted", "base_revision": 0}
    )
    assert other.json()["revision"] == 1
    page.click("[data-testid=reject]")
    dialog = page.locator("[data-testid=conflict-dialog]")
    dialog.wait_for()
    assert "ada saved this frame's label" in dialog.inner_text()
    assert "revision 1" in dialog.inner_text()
    # Their version beside mine: its status and author.
    wait_until(
        page, lambda: "Theirs: accepted by ada" in page.inner_text("[data-testid=conflict-theirs]")
    )
    assert page.inner_text("[data-testid=conflict-mine]") == "Yours: rejected (no pool)"
    shoot(page, "conflict-dialog")
    page.click("[data-testid=conflict-overwrite]")
    page.wait_for_selector("[data-testid=toast-ok]:has-text('rejected')")
    label = server.api("GET", f"/frames/{frame_id}/label").json()
    assert (label["status"], label["revision"]) == ("rejected", 2)

    # Again, with an unsaved brush stroke: reload takes their label and drops ours.
    server.api(
        "PUT", f"/frames/{frame_id}/label", "ada", json={"status": "accepted", "base_revision": 2}
    )
    page.click("[data-testid=tool-brush]")
    stroke(page, (100, 100), (300, 120))
    page.click("[data-testid=save]")
    dialog.wait_for()
    # Theirs is the proposal as accepted; mine has the stroke: the difference is counted.
    wait_until(
        page, lambda: "differs from yours in" in page.inner_text("[data-testid=conflict-theirs]")
    )
    theirs = page.inner_text("[data-testid=conflict-theirs]")
    assert int(re.search(r"differs from yours in (\d+) px", theirs).group(1)) > 500  # type: ignore[union-attr]
    page.click("[data-testid=conflict-reload]")
    wait_for_js(page, "(sel) => document.querySelector(sel)?.dataset.revision === '3'", arg=CANVAS)
    open_review(page)
    assert page.is_hidden("[data-testid=dirty]")
    assert page.locator("#frame-state .badge").inner_text() == "accepted"


def test_teacher_button_undo_redo_zoom_and_unsaved_warning(page: Any, server: LiveServer) -> None:
    frame_id = add_frame(server, 501, teacher=False)
    login(page, server, "rita")
    page.goto(f"{server.url}/frames/{frame_id}")
    open_review(page)
    assert page.is_visible("[data-testid=run-teacher]")
    assert page.is_disabled("[data-testid=show-heatmap]")
    with page.expect_navigation(timeout=120_000):  # the page reloads with the proposal
        page.click("[data-testid=run-teacher]")
    open_review(page)
    assert page.is_hidden("[data-testid=run-teacher]")
    assert "teacher proposal" in page.inner_text("#frame-state")

    # Undo and redo a brush stroke, with the keyboard.
    start = canvas_data(page, "mask-area")
    page.keyboard.press("4")
    page.keyboard.press("]")
    stroke(page, (200, 650), (700, 660))
    painted = canvas_data(page, "mask-area")
    assert painted > start
    page.keyboard.press("Control+z")
    assert canvas_data(page, "mask-area") == start
    assert page.is_hidden("[data-testid=dirty]")
    page.keyboard.press("Control+y")
    assert canvas_data(page, "mask-area") == painted
    assert page.is_visible("[data-testid=dirty]")

    # Zoom with the wheel at the cursor, fit again with F.
    fitted = canvas_data(page, "view")["scale"]
    page.mouse.move(*to_page(page, 640, 400))
    page.mouse.wheel(0, -400)
    wait_for_js(
        page,
        "([sel, s]) => JSON.parse(document.querySelector(sel).dataset.view).scale > s * 1.5",
        arg=[CANVAS, fitted],
    )
    page.keyboard.press("f")
    assert canvas_data(page, "view")["scale"] == pytest.approx(fitted)

    # Leaving with unsaved changes asks first (beforeunload); staying keeps the work.
    dialogs: list[str] = []

    def answer(dialog: Any) -> None:
        dialogs.append(dialog.type)
        dialog.dismiss()

    page.on("dialog", answer)
    page.click("nav >> text=Frames")
    wait_until(page, lambda: "beforeunload" in dialogs)
    assert re.search(rf"/frames/{frame_id}$", page.url)
    assert canvas_data(page, "mask-area") == painted
    # Next asks too (a confirm); dismissing it stays.
    page.click("[data-testid=next]")
    wait_until(page, lambda: "confirm" in dialogs)
    assert re.search(rf"/frames/{frame_id}$", page.url)


def test_jobs_page_live_progress_and_cancel(page: Any, server: LiveServer) -> None:
    job = server.api("POST", "/jobs/diagnostic", "ada", json={"seconds": 30}).json()
    login(page, server, "rita")
    page.goto(f"{server.url}/jobs")
    row = page.locator(f"[data-testid=job-row][data-job-id='{job['job_id']}']")
    row.locator(".badge.running").wait_for(timeout=20_000)
    wait_for_js(
        page,
        "(id) => Number(document.querySelector(`[data-job-id='${id}'] [role=progressbar]`)"
        ".getAttribute('aria-valuenow')) > 0",
        arg=job["job_id"],
    )
    assert "live" in page.inner_text("[data-testid=poll-state]")
    # the table is updated in place: the Cancel button stays the same element across polls
    button = row.locator("[data-testid=cancel-job]").element_handle()
    shown = row.locator("[role=progressbar]").get_attribute("aria-valuenow")
    wait_for_js(
        page,
        "([id, shown]) => document.querySelector(`[data-job-id='${id}'] [role=progressbar]`)"
        ".getAttribute('aria-valuenow') !== shown",
        arg=[job["job_id"], shown],
    )
    assert button.evaluate("(b) => b.isConnected")
    assert row.locator("[data-testid=job-owner]").inner_text() == "ada"
    assert re.fullmatch(r"\d+ s", row.locator("[data-testid=job-duration]").inner_text())
    asked: list[str] = []
    page.once("dialog", lambda dialog: (asked.append(dialog.message), dialog.dismiss()))
    row.locator("[data-testid=cancel-job]").click()  # asks first; dismissed: nothing happens
    wait_until(page, lambda: bool(asked))
    assert asked[0].startswith(f"Cancel job #{job['job_id']} (diagnostic")
    assert server.api("GET", f"/jobs/{job['job_id']}").json()["cancel_requested"] is False
    page.once("dialog", lambda dialog: dialog.accept())
    row.locator("[data-testid=cancel-job]").click()
    page.locator(f"[data-job-id='{job['job_id']}'][data-status=cancelled]").wait_for(timeout=20_000)
    assert server.api("GET", f"/jobs/{job['job_id']}").json()["status"] == "cancelled"

    run = server.api("POST", "/sequences", json={"name": "Scope run"}).json()
    files = [("files", ("scope.png", synthetic_png(671), "image/png"))]
    server.api("POST", "/frames", files=files, data={"sequence_id": run["id"]})
    teacher = server.api("POST", "/teacher/runs", json={"sequence_id": run["id"]}).json()
    scope = page.locator(f"[data-job-id='{teacher['job_id']}'] [data-testid=job-scope]")
    scope.wait_for(timeout=20_000)
    assert scope.inner_text() == "run “Scope run”, 1 frame"  # its name, not its number


def test_box_negative_click_and_keypoint_removal(page: Any, server: LiveServer) -> None:
    frame_id = add_frame(server, 601)
    login(page, server, "rita")
    page.goto(f"{server.url}/frames/{frame_id}")
    open_review(page)

    area = canvas_data(page, "mask-area")
    page.click("[data-testid=tool-box]")
    stroke(page, (300, 250), (1000, 700))
    wait_for_js(
        page,
        "([sel, before]) => { const c = document.querySelector(sel);"
        " return c.dataset.pending === '0' && Number(c.dataset.maskArea) !== before; }",
        arg=[CANVAS, area],
        timeout=60_000,
    )

    # Shift+click with the positive tool is a negative click in the same session.
    page.click("[data-testid=tool-positive]")
    page.keyboard.down("Shift")
    page.mouse.click(*to_page(page, 650, 450))
    page.keyboard.up("Shift")
    assert canvas_data(page, "clicks") == 1
    wait_for_js(page, "(sel) => document.querySelector(sel).dataset.pending === '0'", arg=CANVAS)
    assert "SAM2 IoU" in page.inner_text("[data-testid=last-click]")
    page.keyboard.press("Escape")  # end the click session, keep the mask
    assert canvas_data(page, "clicks") == 0

    # Keypoints: add one with the keypoint tool, remove it with a right-click, and another
    # with the Delete key.
    page.keyboard.press("6")
    count = len(canvas_data(page, "keypoints"))
    page.mouse.click(*to_page(page, 100, 100))
    assert len(canvas_data(page, "keypoints")) == count + 1
    page.mouse.click(*to_page(page, 100, 100), button="right")
    assert len(canvas_data(page, "keypoints")) == count
    if count:
        x, y = canvas_data(page, "keypoints")[0]
        page.mouse.click(*to_page(page, x, y))
        page.keyboard.press("Delete")
        assert len(canvas_data(page, "keypoints")) == count - 1


def test_a_session_ended_mid_edit_saves_after_a_login_in_another_tab(
    page: Any, server: LiveServer
) -> None:
    """Logged out in another tab while a stroke is unsaved: the save says to log in again in
    another tab (not the API's sentence for scripts); after that login the same page saves,
    fetching the new session's CSRF token (it was refused as a wrong CSRF header) — but not
    while another user is the one logged in."""
    frame_id = add_frame(server, 402)
    login(page, server, "rita")
    page.goto(f"{server.url}/frames/{frame_id}")
    open_review(page)
    page.uncheck("#advance")
    page.click("[data-testid=tool-brush]")
    stroke(page, (100, 100), (300, 120))
    other = page.context.new_page()
    other.goto(f"{server.url}/")
    other.click("[data-testid=logout]")
    other.wait_for_url(f"{server.url}/login*")
    page.click("[data-testid=save]")
    page.wait_for_selector("[data-testid=toast-error]:has-text('log in again in another tab')")
    shoot(page, "session-ended-toast")
    assert not page.is_hidden("[data-testid=dirty]")  # the stroke is still there, unsaved
    # Someone else logs in in this browser: the page does not save rita's work in ada's name.
    login(other, server, "ada")
    page.click("[data-testid=save]")
    page.wait_for_selector(
        "[data-testid=toast-error]:has-text('ada has logged in in this browser')"
    )
    assert server.api("GET", f"/frames/{frame_id}/label").status_code == 404
    other.click("[data-testid=logout]")
    login(other, server, "rita")
    page.click("[data-testid=save]")
    page.wait_for_selector("[data-testid=toast-ok]")
    label = server.api("GET", f"/frames/{frame_id}/label").json()
    assert (label["status"], label["revision"], label["updated_by"]) == ("corrected", 1, "rita")


def test_validation_keypoints_saved_meanwhile_are_overwritten_or_loaded_by_choice(
    page: Any, server: LiveServer
) -> None:
    """Someone saves a frame's validation keypoints while the page places its own: the save
    asks (was: theirs silently replaced); OK overwrites theirs, Cancel loads theirs."""
    frame_id = add_frame(server, 403, teacher=False)
    url = f"/frames/{frame_id}/validation-keypoints"
    theirs = [[100.0, 100.0], [200.0, 100.0], [200.0, 200.0], [100.0, 200.0]]
    login(page, server, "rita")
    page.goto(f"{server.url}/frames/{frame_id}")
    open_review(page)
    page.click("[data-testid=validation-mode]")
    mine = [(500, 300), (700, 320), (720, 500), (480, 520)]
    for px, py in mine:
        page.mouse.click(*to_page(page, px, py))
    first = server.api("PUT", url, "ada", json={"keypoints": theirs, "base_revision": 0})
    assert first.json()["revision"] == 1
    answers: list[str] = []

    def answer(dialog: Any) -> None:
        answers.append(dialog.message)
        dialog.accept() if len(answers) == 1 else dialog.dismiss()

    page.on("dialog", answer)
    page.click("[data-testid=save-validation]")
    page.wait_for_selector("[data-testid=toast-ok]:has-text('Validation keypoints saved')")
    assert answers[0].startswith("ada saved this frame's validation keypoints while you placed")
    stored = server.api("GET", url).json()
    assert stored["revision"] == 2
    assert [c for p in stored["keypoints"] for c in p] == pytest.approx(
        [c for p in mine for c in p], abs=1.5
    )
    # Again: theirs saved over mine, mine moved; Cancel loads theirs and saves nothing.
    server.api("PUT", url, "ada", json={"keypoints": theirs, "base_revision": 2})
    page.click("#clear-validation")
    for px, py in mine:
        page.mouse.click(*to_page(page, px + 10, py))
    page.click("[data-testid=save-validation]")
    wait_until(page, lambda: len(answers) == 2)
    page.wait_for_selector("#validation-state:has-text('loaded')")
    shoot(page, "validation-theirs-loaded")
    assert server.api("GET", url).json()["revision"] == 3
    assert page.inner_text("[data-testid=manual-count]") == "4 of 4 placed"
    assert page.is_disabled("[data-testid=save-validation]")  # theirs, as stored: nothing to save


def test_the_timeline_of_a_missing_run_offers_nothing_to_run(page: Any, server: LiveServer) -> None:
    """Its buttons threw on a null timeline and its CSV link fetched a 404."""
    login(page, server, "rita")
    page.goto(f"{server.url}/sequences/999999")
    page.wait_for_selector("body[data-ready]")
    assert "There is no sequence 999999." in page.inner_text("[data-testid=geometry-charts]")
    assert page.is_disabled("#embed-run") and page.is_disabled("#propagate-run")
    assert page.is_hidden("[data-testid=geometry-csv]")
    shoot(page, "timeline-missing-run")


def test_a_reject_clears_the_mask_and_h_without_a_proposal_says_why(
    page: Any, server: LiveServer
) -> None:
    """A rejected frame shows no pool at once (it showed the rejected mask until a reload), and
    H on a frame without a proposal leaves the greyed-out heatmap box alone."""
    frame_id = add_frame(server, 404)
    login(page, server, "rita")
    page.goto(f"{server.url}/frames/{frame_id}")
    open_review(page)
    page.uncheck("#advance")
    assert canvas_data(page, "mask-area") > 0 and len(canvas_data(page, "keypoints")) == 4
    page.keyboard.press("r")
    page.wait_for_selector("[data-testid=toast-ok]:has-text('rejected')")
    assert canvas_data(page, "mask-area") == 0 and canvas_data(page, "keypoints") == []
    assert page.is_hidden("[data-testid=dirty]")

    bare = add_frame(server, 405, teacher=False)
    page.goto(f"{server.url}/frames/{bare}")
    open_review(page)
    assert page.is_disabled("#show-heatmap")
    page.keyboard.press("h")
    page.wait_for_selector("[data-testid=toast-info]:has-text('no heatmap')")
    assert not page.is_checked("#show-heatmap")


def test_accept_or_save_of_an_untouched_label_writes_nothing(page: Any, server: LiveServer) -> None:
    """A stored label without a proposal, left as it is: A and S say nothing changed (A saved
    it again as "corrected", a new revision in the presser's name)."""
    frame_id = add_frame(server, 406, teacher=False)
    mask = np.zeros((800, 1280), bool)
    mask[300:500, 400:800] = True
    stored = server.api("PUT", f"/frames/{frame_id}/label", "ada", json=corrected_label(mask))
    assert stored.json()["revision"] == 1
    login(page, server, "rita")
    page.goto(f"{server.url}/frames/{frame_id}")
    open_review(page)
    page.uncheck("#advance")
    for key in ("a", "s"):
        page.keyboard.press(key)
        page.wait_for_selector(
            "[data-testid=toast-info]:has-text('Nothing changed: the label stays corrected')"
        )
    label = server.api("GET", f"/frames/{frame_id}/label").json()
    assert (label["revision"], label["updated_by"]) == (1, "ada")
    page.click("[data-testid=tool-brush]")
    stroke(page, (100, 100), (300, 120))
    page.keyboard.press("s")  # a change is saved
    page.wait_for_selector("[data-testid=toast-ok]:has-text('revision 2')")


def test_a_wrong_address_is_a_page_with_a_way_back(page: Any, server: LiveServer) -> None:
    """A browser got the API's JSON for an unknown page or a malformed id; the API still does."""
    login(page, server, "rita")
    for path, status, words in (
        ("/nonexistent-page", 404, "There is no page at /nonexistent-page."),
        ("/frames/abc", 422, "This address is not valid: frame_id: Input should be a valid"),
    ):
        answer = page.goto(f"{server.url}{path}")
        assert answer.status == status
        assert words in page.inner_text("[data-testid=error-page]")
        assert page.is_visible("[data-testid=current-user]")  # the header, logged in
    shoot(page, "error-page")
    page.click("text=Back to the frames")
    page.wait_for_url(f"{server.url}/")
    assert server.api("GET", "/frames/abc").json()["detail"].startswith("frame_id: ")


def test_missing_frame_says_so(page: Any, server: LiveServer) -> None:
    login(page, server, "rita")
    page.goto(f"{server.url}/frames/999999")
    message = page.locator("#stage-message.error")
    message.wait_for()
    assert "There is no frame 999999." in message.inner_text()
    assert page.is_disabled("[data-testid=accept]")


def test_review_pages_ask_for_nothing_that_is_absent(page: Any, server: LiveServer) -> None:
    """A frame without label, proposal or validation keypoints, and one with a proposal: no
    request of the page answers 4xx (no 404 for an absent label, no missing favicon)."""
    bare = add_frame(server, 620, teacher=False)
    proposed = add_frame(server, 621)
    failures: list[str] = []
    page.on(
        "response",
        lambda response: (
            failures.append(f"{response.status} {response.url}") if response.status >= 400 else None
        ),
    )
    login(page, server, "rita")
    for frame_id in (bare, proposed):
        page.goto(f"{server.url}/frames/{frame_id}")
        open_review(page)
        page.wait_for_load_state("networkidle")
    assert page.locator("link[rel=icon]").count() == 1
    assert failures == []


def test_frame_list_filters_pages_and_drop_upload(page: Any, server: LiveServer) -> None:
    sequence = server.api("POST", "/sequences", json={"name": "Pagination run"}).json()
    files = [
        ("files", (f"small-{i}.png", image_bytes(seed=1000 + i), "image/png")) for i in range(53)
    ]
    stored = server.api("POST", "/frames", files=files, data={"sequence_id": sequence["id"]})
    assert len(stored.json()["stored"]) == 53

    login(page, server, "rita")
    page.goto(f"{server.url}/?sequence_id={sequence['id']}")
    page.wait_for_selector("body[data-ready]")
    assert page.inner_text("[data-testid=page-info]") == "1–50 of 53"
    assert page.locator("[data-testid=frame-row]").count() == 50
    asked: list[str] = []
    page.on("request", lambda r: asked.append(r.url) if "/api/v1/frames?" in r.url else None)
    page.click("#next-page")
    wait_for_js(
        page, "document.querySelector('[data-testid=page-info]').textContent === '51–53 of 53'"
    )
    assert "offset=50" in page.url
    assert page.locator("[data-testid=frame-row]").count() == 3
    assert any("after=" in url and "offset" not in url for url in asked), asked  # by cursor
    shoot(page, "frames-page-2", full_page=True, idle=True)
    page.select_option("select[name=status]", "accepted")
    wait_for_js(
        page, "document.querySelector('[data-testid=page-info]').textContent === '0 frames'"
    )
    page.select_option("select[name=status]", "all")
    wait_for_js(
        page, "document.querySelector('[data-testid=page-info]').textContent === '1–50 of 53'"
    )

    # Dropping files on the drop zone uploads them, each with its own progress bar.
    page.evaluate(
        """async (pngs) => {
          const transfer = new DataTransfer();
          pngs.forEach((b64, i) => transfer.items.add(new File(
            [Uint8Array.from(atob(b64), (c) => c.charCodeAt(0))], `dropped-${i}.png`,
            { type: "image/png" })));
          document.getElementById("dropzone").dispatchEvent(
            new DragEvent("drop", { dataTransfer: transfer, bubbles: true, cancelable: true }));
        }""",
        [base64.b64encode(image_bytes(seed=2000 + i)).decode() for i in range(2)],
    )
    for i in range(2):
        page.wait_for_selector(
            f"[data-testid=upload-item][data-name='dropped-{i}.png'][data-state=ok]"
        )
    wait_for_js(
        page, "document.querySelector('[data-testid=page-info]').textContent === '1–50 of 55'"
    )


def test_the_queue_shows_only_frames_still_to_review(page: Any, server: LiveServer) -> None:
    """The frames page and "Review queue" start on frames still to review (new, proposed);
    the status filter brings back the reviewed ones."""
    sequence = server.api("POST", "/sequences", json={"name": "Queue run"}).json()
    files = [("files", (f"q{i}.png", synthetic_png(500 + i), "image/png")) for i in range(3)]
    stored = server.api("POST", "/frames", files=files, data={"sequence_id": sequence["id"]})
    ids = [f["id"] for f in stored.json()["stored"]]
    truth = save_true_label(server, ids[0], 500)

    login(page, server, "rita")
    page.goto(f"{server.url}/?sequence_id={sequence['id']}")
    page.wait_for_selector("body[data-ready]")
    assert page.input_value("[data-testid=filter-status]") == "unreviewed"
    wait_for_js(
        page, "document.querySelector('[data-testid=page-info]').textContent === '1–2 of 2'"
    )
    shown = {
        int(r.get_attribute("data-frame-id")) for r in page.locator("[data-testid=frame-row]").all()
    }
    assert shown == set(ids[1:])
    # The queue says why its scores need not decrease (look-alikes are spread apart).
    assert "frames that look alike are spread apart" in page.inner_text("[data-testid=order-note]")
    shoot(page, "queue")
    page.select_option("select[name=order]", "id")
    page.wait_for_selector("[data-testid=order-note]", state="hidden")
    page.select_option("select[name=order]", "uncertainty")
    page.wait_for_selector("[data-testid=order-note]")
    page.click("[data-testid=start-review]")
    page.wait_for_url(re.compile(r"/frames/\d+"))
    assert int(re.search(r"/frames/(\d+)", page.url).group(1)) in ids[1:]  # type: ignore[union-attr]
    assert "status=unreviewed" in page.url

    page.goto(f"{server.url}/?sequence_id={sequence['id']}")
    page.wait_for_selector("body[data-ready]")
    page.select_option("[data-testid=filter-status]", "all")
    wait_for_js(
        page, "document.querySelector('[data-testid=page-info]').textContent === '1–3 of 3'"
    )
    for frame_id in ids[1:]:
        saved = server.api("PUT", f"/frames/{frame_id}/label", json=corrected_label(truth))
        assert saved.status_code == 200
    page.select_option("[data-testid=filter-status]", "unreviewed")
    page.wait_for_selector("[data-testid=frames-empty]")
    assert "Nothing left to review" in page.inner_text("[data-testid=frames-empty]")


def test_real_model_version_on_the_models_and_metrics_pages(
    page: Any, server: LiveServer, tmp_path: Path
) -> None:
    """A student trained for real on the live server shows on /models and /metrics, and runs
    live on a recorded weld from its card."""
    params = SynthParams(width=320, height=200)
    for seed in (901, 902, 903):
        truth = synth_frame(seed=seed, params=params)
        data = cv2.imencode(".png", truth.image)[1].tobytes()
        frame = server.api(
            "POST", "/frames", files=[("files", (f"m{seed}.png", data, "image/png"))]
        ).json()["stored"][0]
        label = server.api("PUT", f"/frames/{frame['id']}/label", json=corrected_label(truth.mask))
        assert label.status_code == 200, label.text
    job = server.api("POST", "/student/train", json={"epochs": 1, "size": "light"})
    assert job.status_code == 202, job.text
    assert server.wait_for_job(job.json()["job_id"], timeout=300)["status"] == "succeeded"
    name = server.api("GET", "/models").json()[0]["name"]

    login(page, server, "rita")
    page.goto(f"{server.url}/models")
    card = page.locator(f"[data-testid=model-card]:has-text('{name}')")
    card.wait_for()
    assert card.locator("svg.chart").count() >= 2
    page.goto(f"{server.url}/metrics")
    page.wait_for_selector("[data-testid=student-table]")
    assert name in page.inner_text("[data-testid=student-table]")
    assert "corrected" in page.inner_text("[data-testid=acceptance]")
    # Two different counts, each said for what it is: current labels vs saves per day.
    assert page.inner_text("[data-testid=acceptance]").startswith("Current labels:")
    assert "counts twice" in page.inner_text("[data-testid=review-table-note]")
    assert page.locator("svg.chart").count() == 2  # the learning curve: mIoU and mED
    shoot(page, "metrics", full_page=True)

    # The version live on a recorded weld (a file on the server, played at its frame rate).
    video = write_video(tmp_path / "weld.avi", 200, fps=20.0, size=(320, 200))
    page.goto(f"{server.url}/models")
    card.locator("[data-testid=live-view]").wait_for()
    shoot(page, "models-version")
    gate = card.locator("[data-testid=gate]").inner_text()
    usable = server.api("GET", "/models").json()[0]["gate"]["usable"]
    assert ("not usable" not in gate) == usable
    card.locator("[data-testid=live-view]").click()
    page.wait_for_url(re.compile(r"/live\?model_id=\d+"))
    wait_for_js(page, "document.querySelector('[data-testid=live-model]').options.length > 1")
    chosen = page.locator("[data-testid=live-model] option:checked").inner_text()
    assert chosen.startswith(name) and ("not usable" in chosen) == (not usable)
    page.fill("[data-testid=live-source]", str(video))
    page.click("[data-testid=live-outputs-form] summary")  # the cell's outputs, from the form
    opc_port, zmq_port = free_port(), free_port()
    page.fill("[data-testid=live-opcua]", f"opc.tcp://127.0.0.1:{opc_port}")
    page.fill("[data-testid=live-zeromq]", f"tcp://127.0.0.1:{zmq_port}")
    page.click("[data-testid=live-start]")
    live = page.locator("[data-testid=live-card][data-state=running]")
    live.wait_for(timeout=60_000)
    wait_for_js(page, "document.querySelector('[data-testid=live-frame]').naturalWidth === 320")
    wait_for_js(page, "/fps/.test(document.querySelector('[data-testid=live-stats]').textContent)")
    wait_for_js(
        page,
        "/sent/.test(document.querySelector('[data-testid=live-output-opcua]')?.textContent)",
    )
    opc = live.locator("[data-testid=live-output-opcua]").inner_text()
    assert opc.startswith(f"OPC UA opc.tcp://127.0.0.1:{opc_port} · serving · 0 subscriptions")
    assert "0 subscribers" in live.locator("[data-testid=live-output-zeromq]").inner_text()
    assert live.locator("[data-testid=live-keypoints]").count() == 1
    assert live.locator("[data-testid=gate]").inner_text() == gate  # the verdict, as on /models
    assert live.locator("svg.chart").count() == 3  # area, length, width scrolling
    shoot(page, "live")
    live.locator("[data-testid=live-stop]").click()
    page.locator("[data-testid=live-card][data-state=stopped]").wait_for()


def test_review_switches_between_proposals_and_records_the_one_accepted(
    page: Any, server: LiveServer
) -> None:
    """Two teacher runs on one frame: both proposals are listed, P shows the other one, and
    the accepted label records the proposal it started from, unchanged."""
    frame_id = add_frame(server, 11)
    again = server.api("POST", "/teacher/runs", json={"frame_ids": [frame_id], "force": True})
    assert server.wait_for_job(again.json()["job_id"])["status"] == "succeeded"
    listed = server.api("GET", f"/frames/{frame_id}/proposals").json()["items"]
    newest, oldest = (item["id"] for item in listed)
    assert listed[0]["chosen"] and not listed[1]["chosen"]

    login(page, server, "rita")
    page.goto(f"{server.url}/frames/{frame_id}")
    open_review(page)
    options = page.locator("[data-testid=proposal-option]")
    assert options.count() == 2
    assert options.nth(0).get_attribute("aria-pressed") == "true"
    assert "chosen" in options.nth(0).inner_text()
    shoot(page, "review-proposals")
    page.locator(CANVAS).focus()
    page.keyboard.press("p")
    page.wait_for_selector(f"[data-proposal-id='{oldest}'][aria-pressed=true]")
    assert page.is_hidden("[data-testid=dirty]")  # no label yet: showing another is no edit
    page.uncheck("#advance")  # stay on this frame after saving
    page.click("[data-testid=accept]")
    page.wait_for_selector("[data-testid=toast-ok]")
    label = server.api("GET", f"/frames/{frame_id}/label").json()
    assert label["status"] == "accepted" and label["proposal_id"] == oldest
    assert label["mask_changed"] is False and newest != oldest


def test_token_page_creates_shows_once_and_revokes(page: Any, server: LiveServer) -> None:
    """From the user name in the header (the account page): create a token (shown once, and it
    works), see it listed, revoke it after confirming (then it no longer works)."""
    import httpx

    login(page, server, "anna")
    page.click("[data-testid=current-user]")
    page.wait_for_url(f"{server.url}/account")
    page.wait_for_selector("body[data-ready]")
    page.fill("[data-testid=token-name]", "robot cell 3")
    page.click("[data-testid=create-token]")
    page.wait_for_selector("[data-testid=created-token]:not([hidden])")
    token = page.inner_text("[data-testid=created-token-text]").strip()
    shoot(page, "tokens")
    me = httpx.get(f"{server.url}/api/v1/users/me", headers={"Authorization": f"Bearer {token}"})
    assert me.status_code == 200 and me.json()["username"] == "anna"
    row = page.locator("[data-testid=token-row]", has_text="robot cell 3")
    row.wait_for()
    assert token[:10] in row.inner_text()
    dialogs: list[str] = []
    page.once("dialog", lambda dialog: (dialogs.append(dialog.message), dialog.accept()))
    row.locator("[data-testid=revoke-token]").click()
    page.wait_for_selector("[data-testid=token-row]:has-text('robot cell 3') .badge.revoked")
    assert dialogs and "Revoke the token" in dialogs[0]
    gone = httpx.get(f"{server.url}/api/v1/users/me", headers={"Authorization": f"Bearer {token}"})
    assert gone.status_code == 401


def test_missing_weights_show_a_banner_and_teacher_buttons_say_why(
    browser: Any, tmp_path: Path
) -> None:
    """A new install without the teacher's weights: every page says so and how to fix it;
    the teacher buttons are disabled with that reason instead of failing on click."""
    bare = LiveServer(tmp_path / "home", with_weights=False).start()
    context = browser.new_context(viewport={"width": 1280, "height": 800})
    try:
        assert bare.api("GET", "/health").json()["status"] == "degraded"
        frame = bare.api(
            "POST", "/frames", files=[("files", ("w.png", synthetic_png(630), "image/png"))]
        ).json()["stored"][0]["id"]
        page = context.new_page()
        login(page, bare, "rita")
        page.wait_for_selector("body[data-ready]")
        # A reviewer cannot install weights: asked to get an admin, not told to run commands.
        banner = page.inner_text("[data-testid=teacher-banner]")
        assert "weights are missing" in banner and "Ask an admin" in banner
        assert "weldpool weights fetch" not in banner
        sequence_button = page.locator("[data-testid=teacher-sequence]")
        assert sequence_button.count() == 0 or sequence_button.first.is_disabled()
        page.check("[data-testid=frame-row] input[type=checkbox]")
        assert page.is_disabled("[data-testid=teacher-selection]")
        assert "weights are missing" in page.get_attribute(
            "[data-testid=teacher-selection]", "title"
        )
        page.goto(f"{bare.url}/frames/{frame}")
        page.wait_for_selector("body[data-ready]")
        assert page.is_visible("[data-testid=teacher-banner]")
        assert "weldpool weights fetch" not in page.inner_text("[data-testid=teacher-banner]")
        assert page.is_disabled("[data-testid=run-teacher]")
        assert "weights are missing" in page.get_attribute("[data-testid=run-teacher]", "title")
        # The tools that ask SAM2 for a mask say why they cannot; painting still works.
        for tool in ("positive", "negative", "box"):
            assert page.is_disabled(f"[data-testid=tool-{tool}]")
            title = page.get_attribute(f"[data-testid=tool-{tool}]", "title")
            assert title.startswith("Clicks, boxes and propagation need SAM2")
        assert page.get_attribute("[data-testid=tool-brush]", "aria-pressed") == "true"
        assert "with the brush or the polygon tool" in page.inner_text("#no-proposal")
        page.locator(CANVAS).focus()
        page.keyboard.press("1")  # the positive click's key: refused, with the reason
        page.wait_for_selector("[data-testid=toast-error]:has-text('need SAM2')")
        assert page.get_attribute("[data-testid=tool-brush]", "aria-pressed") == "true"
        shoot(page, "no-weights-review")
        page.goto(bare.url)
        page.wait_for_selector("body[data-ready]")
        shoot(page, "no-weights-frames")
        # An admin, who can install them, is told how.
        page.click("[data-testid=logout]")
        login(page, bare, "ada")
        page.wait_for_selector("body[data-ready]")
        assert page.inner_text("[data-testid=teacher-banner] code") == "weldpool weights fetch"
    finally:
        context.close()
        bare.stop()


def test_export_menu_downloads_the_sequence_labels(page: Any, server: LiveServer) -> None:
    """The frames page's Export (a job, then a download): COCO of the chosen sequence (RLE
    masks that read back exactly) and YOLO segmentation; a sequence with nothing reviewed says
    so instead of downloading."""
    import io
    import json
    import zipfile

    from pycocotools import mask as coco_mask

    sequence = server.api("POST", "/sequences", json={"name": "Export run"}).json()
    empty = server.api("POST", "/sequences", json={"name": "Nothing reviewed"}).json()
    files = [("files", ("e.png", synthetic_png(640), "image/png"))]
    frame_id = server.api(
        "POST", "/frames", files=files, data={"sequence_id": sequence["id"]}
    ).json()["stored"][0]["id"]
    truth = save_true_label(server, frame_id, 640)

    login(page, server, "anna")
    page.goto(f"{server.url}/?sequence_id={sequence['id']}&status=all")
    page.wait_for_selector("body[data-ready]")
    page.select_option("[data-testid=export-format]", "coco")
    shoot(page, "export-menu")
    with page.expect_download() as download:
        page.click("[data-testid=export]")
    archive = zipfile.ZipFile(io.BytesIO(Path(download.value.path()).read_bytes()))
    coco = json.loads(archive.read("annotations.json"))
    assert [a["image_id"] for a in coco["annotations"]] == [frame_id]
    back = coco_mask.decode(
        {
            **coco["annotations"][0]["segmentation"],
            "counts": coco["annotations"][0]["segmentation"]["counts"].encode(),
        }
    ).astype(bool)
    assert np.array_equal(back, truth)
    # The same menu, YOLO segmentation: the frame's region as one polygon line.
    page.select_option("[data-testid=export-format]", "yolo")
    with page.expect_download() as download:
        page.click("[data-testid=export]")
    archive = zipfile.ZipFile(io.BytesIO(Path(download.value.path()).read_bytes()))
    assert archive.read("data.yaml").startswith(b"path: .")
    # Named after the uploaded file (e.png), so a re-import finds the frame by its name.
    (line,) = archive.read("labels/train/e.txt").decode().splitlines()
    assert line.startswith("0 ") and len(line.split()) > 7
    # LabelMe: the JSON beside the image, the pool a mask shape.
    page.select_option("[data-testid=export-format]", "labelme")
    shoot(page, "export-menu-labelme")
    with page.expect_download() as download:
        page.click("[data-testid=export]")
    archive = zipfile.ZipFile(io.BytesIO(Path(download.value.path()).read_bytes()))
    labelme = json.loads(archive.read("images/e.json"))
    assert labelme["imagePath"] == "e.png" and "images/e.png" in archive.namelist()
    assert labelme["shapes"][0]["shape_type"] == "mask"

    page.goto(f"{server.url}/?sequence_id={empty['id']}&status=all")
    page.wait_for_selector("body[data-ready]")
    page.click("[data-testid=export]")
    page.wait_for_selector("[data-testid=toast-error]")
    assert "no accepted or corrected labels" in page.inner_text("[data-testid=toast-error]")


def test_delete_selected_frames_and_a_weld_run_after_confirming(
    page: Any, server: LiveServer
) -> None:
    """A wrong upload is not permanent: a reviewer deletes selected frames (asked twice when a
    reviewed label would go too), then the weld run; annotators see no delete buttons."""
    sequence = server.api("POST", "/sequences", json={"name": "Oops run"}).json()
    files = [("files", (f"x{i}.png", synthetic_png(650 + i), "image/png")) for i in range(3)]
    ids = [
        f["id"]
        for f in server.api(
            "POST", "/frames", files=files, data={"sequence_id": sequence["id"]}
        ).json()["stored"]
    ]
    save_true_label(server, ids[0], 650)

    login(page, server, "anna")
    page.goto(f"{server.url}/?sequence_id={sequence['id']}&status=all")
    page.wait_for_selector("body[data-ready]")
    assert page.is_hidden("[data-testid=delete-selection]")
    assert page.locator("[data-testid=delete-sequence]").count() == 0

    context = page.context
    context.clear_cookies()
    login(page, server, "rita")
    page.goto(f"{server.url}/?sequence_id={sequence['id']}&status=all")
    page.wait_for_selector("body[data-ready]")
    asked = accept_dialogs(page)
    for frame_id in ids[:2]:
        page.check(f"[data-testid=frame-row][data-frame-id='{frame_id}'] input[type=checkbox]")
    shoot(page, "delete-selection")
    page.click("[data-testid=delete-selection]")
    page.wait_for_selector("[data-testid=toast-ok]")
    assert asked[0].startswith("Delete 2 selected frames")
    assert "1 frame of the selection has reviewed labels" in asked[1]
    for frame_id in ids[:2]:
        assert server.api("GET", f"/frames/{frame_id}").status_code == 404
    wait_for_js(
        page, "document.querySelector('[data-testid=page-info]').textContent === '1–1 of 1'"
    )
    assert page.inner_text("#selection-count") == "0 selected"  # the deleted are not selected
    page.click(f"li[data-sequence-id='{sequence['id']}'] [data-testid=delete-sequence]")
    wait_until(page, lambda: server.api("GET", f"/sequences/{sequence['id']}").status_code == 404)
    assert asked[2].startswith("Delete the weld run “Oops run” with its 1 frame,")
    assert server.api("GET", f"/frames/{ids[2]}").status_code == 404
    page.locator(
        "[data-testid=toast-ok]", has_text="Deleted the weld run “Oops run” with its 1 frame."
    ).wait_for()

    empty = server.api("POST", "/sequences", json={"name": "Empty run"}).json()
    page.reload()
    page.wait_for_selector("body[data-ready]")
    page.click(f"li[data-sequence-id='{empty['id']}'] [data-testid=delete-sequence]")
    page.locator("[data-testid=toast-ok]", has_text="Deleted the weld run “Empty run”.").wait_for()
    assert asked[3] == "Delete the empty weld run “Empty run”?"  # no "0 frames"


def test_a_new_weld_run_asks_for_its_process_parameters(page: Any, server: LiveServer) -> None:
    login(page, server, "anna")
    page.wait_for_selector("body[data-ready]")
    page.fill("#new-sequence input[name=name]", "Fresh run")
    page.click("#new-sequence button[type=submit]")
    page.wait_for_selector("[data-testid=sequence-dialog][open]")
    assert page.input_value("[data-testid=seq-name]") == "Fresh run"
    page.fill("[data-testid=seq-wire]", "8")
    shoot(page, "weld-run-new")
    page.click("[data-testid=seq-save]")
    wait_until(
        page,
        lambda: any(
            s["name"] == "Fresh run" and s["wire_feed_m_min"] == 8
            for s in server.api("GET", "/sequences").json()
        ),
    )


def test_edit_a_weld_run_name_process_parameters_and_scale(page: Any, server: LiveServer) -> None:
    sequence = server.api("POST", "/sequences", json={"name": "Run to edit"}).json()
    server.api("POST", "/sequences", json={"name": "Taken name"})
    login(page, server, "anna")
    page.goto(f"{server.url}/?sequence_id={sequence['id']}")
    page.wait_for_selector("body[data-ready]")
    item = page.locator(f"li[data-sequence-id='{sequence['id']}']")
    item.locator("[data-testid=edit-sequence]").click()
    page.fill("[data-testid=seq-name]", "Taken name")
    page.click("[data-testid=seq-save]")
    error = page.locator("[data-testid=sequence-error]")
    error.wait_for()
    assert "already a sequence named 'Taken name'" in error.inner_text()
    page.fill("[data-testid=seq-name]", "Fillet T-joint, 6.5 m/min")
    assert error.is_hidden()  # the error was about the name sent: editing it clears it
    page.fill("[data-testid=seq-wire]", "6.5")
    page.fill("[data-testid=seq-voltage]", "22.5")
    page.fill("[data-testid=seq-current]", "180")
    page.fill("[data-testid=seq-speed]", "40")
    # The scale from a known length: a 1.2 mm wire spans 24 px → 0.05 mm per pixel.
    page.fill("[data-testid=scale-mm]", "1.2")
    page.fill("[data-testid=scale-px]", "24")
    assert page.input_value("[data-testid=seq-scale]") == "0.05"
    shoot(page, "weld-run-edit")
    page.click("[data-testid=seq-save]")
    page.wait_for_selector("[data-testid=toast-ok]")
    stored = server.api("GET", f"/sequences/{sequence['id']}").json()
    assert stored["name"] == "Fillet T-joint, 6.5 m/min"
    assert (stored["wire_feed_m_min"], stored["voltage_v"], stored["current_a"]) == (6.5, 22.5, 180)
    assert (stored["robot_speed_cm_min"], stored["mm_per_px"]) == (40, 0.05)
    line = item.locator("[data-testid=process-line]").inner_text()
    assert line == "6.5 m/min · 22.5 V · 180 A · 40 cm/min · 0.05 mm/px"
    shoot(page, "weld-run-process-line")
    item.locator("[data-testid=edit-sequence]").click()  # the dialog shows what is stored
    assert page.input_value("[data-testid=seq-voltage]") == "22.5"
    page.fill("[data-testid=seq-voltage]", "")  # cleared: no longer known
    page.click("[data-testid=seq-save]")
    wait_until(
        page, lambda: server.api("GET", f"/sequences/{sequence['id']}").json()["voltage_v"] is None
    )


def test_display_controls_change_only_the_view_and_are_remembered(
    page: Any, server: LiveServer
) -> None:
    """Brightness, contrast, gamma, mask opacity and keypoints change what the canvas shows,
    not the label; they, the tool and the brush size stay for the next frame."""
    first, second = add_frame(server, 660), add_frame(server, 661)
    login(page, server, "rita")
    page.goto(f"{server.url}/frames/{first}")
    open_review(page)
    centre = (
        "() => { const c = document.querySelector('canvas[data-ready]');"
        " const x = Math.floor(c.width / 2), y = Math.floor(c.height / 3);"
        " const d = c.getContext('2d').getImageData(x, y, 1, 1).data;"
        " return d[0] + d[1] + d[2]; }"
    )
    page.uncheck("#show-mask")
    page.wait_for_timeout(100)
    before = page.evaluate(centre)
    area = canvas_data(page, "mask-area")
    page.fill("[data-testid=display-brightness]", "2")
    page.dispatch_event("[data-testid=display-brightness]", "input")
    wait_for_js(page, f"({centre})() > {before}")
    page.fill("[data-testid=display-gamma]", "0.5")
    page.dispatch_event("[data-testid=display-gamma]", "input")
    page.uncheck("[data-testid=display-keypoints]")
    display = canvas_data(page, "display")
    assert display == display | {"brightness": 2, "gamma": 0.5, "keypoints": False}
    assert canvas_data(page, "mask-area") == area  # the label is untouched
    shoot(page, "review-display")
    page.keyboard.press("4")  # brush
    page.fill("[data-testid=brush-size]", "40")
    page.dispatch_event("[data-testid=brush-size]", "input")

    page.goto(f"{server.url}/frames/{second}")
    open_review(page)
    assert canvas_data(page, "display") == display
    assert page.get_attribute("[data-testid=tool-brush]", "aria-pressed") == "true"
    assert page.input_value("[data-testid=brush-size]") == "40"
    page.click("[data-testid=display-reset]")
    assert canvas_data(page, "display")["brightness"] == 1


IMAGE_PIXEL = (
    "([x, y]) => { const c = document.querySelector('canvas[data-ready]'); const r = c.width / "
    "c.getBoundingClientRect().width; const v = JSON.parse(c.dataset.view);"
    " const d = c.getContext('2d').getImageData(Math.round((v.tx + x * v.scale) * r),"
    " Math.round((v.ty + y * v.scale) * r), 1, 1).data; return [d[0], d[1], d[2]]; }"
)
"""The canvas's colour at frame pixel (x, y), through the view's transform."""


def test_contrast_opacity_long_names_and_a_view_bar_that_never_covers_the_frame(
    page: Any, server: LiveServer
) -> None:
    """Contrast spreads grey levels apart; mask opacity blends the mask from invisible to
    full; long names wrap inside their boxes; at 1280, 1440 and 1920 wide the fitted frame
    lies wholly clear of the Mask / Heatmap / Fit bar."""
    long_run = "Fillet_T-joint_cell3_torch15deg_wire1.2mm_" * 3
    long_file = "weld_2026_11_29_cell3_torch_angle_15deg_wire_1.2mm_exposure_long_f000123.png"
    sequence = server.api("POST", "/sequences", json={"name": long_run}).json()
    files = [("files", (long_file, synthetic_png(675), "image/png"))]
    frame_id = server.api(
        "POST", "/frames", files=files, data={"sequence_id": sequence["id"]}
    ).json()["stored"][0]["id"]
    mask = np.zeros((800, 1280), np.uint8)
    mask[300:501, 400:801] = 255
    assert server.api("PUT", f"/frames/{frame_id}/label", json=corrected_label(mask)).status_code
    login(page, server, "rita")
    page.goto(f"{server.url}/frames/{frame_id}")
    open_review(page)

    def pixel(x: int, y: int) -> list[int]:
        page.wait_for_timeout(120)  # the next animation frame has drawn
        return page.evaluate(IMAGE_PIXEL, [x, y])

    def set_slider(name: str, value: float) -> None:
        page.fill(f"[data-testid=display-{name}]", str(value))
        page.dispatch_event(f"[data-testid=display-{name}]", "input")

    shown = pixel(600, 400)
    page.uncheck("#show-mask")
    bare = pixel(600, 400)
    page.check("#show-mask")
    assert shown != bare
    set_slider("opacity", 0)
    assert pixel(600, 400) == bare  # an invisible mask: the frame as it is
    set_slider("opacity", 0.5)
    half = pixel(600, 400)
    for channel in range(3):  # half way between, to the rounding of one blend
        assert abs(2 * half[channel] - shown[channel] - bare[channel]) <= 3
    set_slider("opacity", 1)
    assert pixel(600, 400) == shown
    page.uncheck("#show-mask")
    # Contrast 1.5 spreads grey levels away from mid-grey: v → 128 + 1.5 (v − 128). Checked
    # on frame pixels below and above the middle that stay inside 0..255.
    grid = [(x, y) for x in range(40, 1280, 120) for y in range(40, 800, 95)]
    levels = {point: page.evaluate(IMAGE_PIXEL, list(point)) for point in grid}
    below = next(p for p, v in levels.items() if 50 <= v[0] <= 110)
    above = next(p for p, v in levels.items() if 150 <= v[0] <= 210)
    set_slider("contrast", 1.5)
    for point in (below, above):
        expected = [128 + 1.5 * (v - 128) for v in levels[point]]
        assert np.abs(np.array(pixel(*point)) - expected).max() <= 3, point
    page.click("[data-testid=display-reset]")
    page.check("#show-mask")

    overflowing = (
        "(selector) => [...document.querySelectorAll(selector)]"
        ".filter((e) => e.scrollWidth > e.clientWidth + 1).length"
    )
    assert long_file in page.inner_text("#frame-meta")
    assert page.evaluate(overflowing, "#frame-meta, aside, aside *") == 0
    for width, height in ((1280, 800), (1440, 900), (1920, 1080)):
        page.set_viewport_size({"width": width, "height": height})
        page.keyboard.press("f")  # fit the frame to the canvas
        page.wait_for_timeout(150)
        clear = page.evaluate(
            """() => {
              const c = document.querySelector('canvas[data-ready]');
              const v = JSON.parse(c.dataset.view), box = c.getBoundingClientRect();
              const bar = document.querySelector('.viewbar').getBoundingClientRect();
              const image = { left: box.left + v.tx, top: box.top + v.ty,
                              right: box.left + v.tx + 1280 * v.scale,
                              bottom: box.top + v.ty + 800 * v.scale };
              return bar.top >= image.bottom || bar.bottom <= image.top
                || bar.left >= image.right || bar.right <= image.left;
            }"""
        )
        assert clear, f"the view bar covers the frame at {width}×{height}"
    page.set_viewport_size({"width": 1280, "height": 800})
    page.goto(f"{server.url}/?sequence_id={sequence['id']}&status=all")
    page.wait_for_selector("body[data-ready]")
    item = f"li[data-sequence-id='{sequence['id']}']"
    assert page.evaluate(overflowing, f"{item}, {item} *") == 0
    assert page.evaluate(overflowing, "[data-testid=frame-row] td") == 0
    assert page.evaluate(overflowing, "main, section") == 0  # the frame table fits its panel
    shoot(page, "long-names")


def test_polygon_tool_drags_adds_and_removes_vertices_with_undo(
    page: Any, server: LiveServer
) -> None:
    """The outline as polygons: a corner dragged sweeps the triangle it should, undo and redo
    restore mask and outline together, a vertex added on an edge and removed again, and what is
    saved is what the canvas shows. Outline-only shows the frame under the mask."""
    frame_id = add_frame(server, 670, teacher=False)
    mask = np.zeros((800, 1280), np.uint8)
    mask[300:501, 400:801] = 255
    saved = server.api("PUT", f"/frames/{frame_id}/label", json=corrected_label(mask))
    assert saved.status_code == 200, saved.text
    login(page, server, "rita")
    page.goto(f"{server.url}/frames/{frame_id}")
    open_review(page)
    page.keyboard.press("7")
    assert page.get_attribute("[data-testid=tool-polygon]", "aria-pressed") == "true"
    wait_for_js(
        page, f"JSON.parse(document.querySelector('{CANVAS}').dataset.outline).length === 1"
    )
    (outline,) = canvas_data(page, "outline")
    assert sorted(map(tuple, outline["points"])) == [(400, 300), (400, 500), (800, 300), (800, 500)]
    area = canvas_data(page, "mask-area")
    assert area == 201 * 401

    def outline_points() -> list[tuple[float, float]]:
        return sorted(tuple(p) for p in canvas_data(page, "outline")[0]["points"])

    # Drag the bottom-right corner 40 px right: a triangle of 200 × 40 / 2 px² is added.
    stroke(page, (800, 500), (840, 500))
    dragged = wait_for_mask_change(page, area)
    assert dragged - area == pytest.approx(4000, abs=250)
    assert (840, 500) in outline_points()
    page.keyboard.press("Control+z")
    wait_for_js(page, f"document.querySelector('{CANVAS}').dataset.maskArea === '{area}'")
    assert (800, 500) in outline_points()
    page.keyboard.press("Control+y")
    wait_for_js(page, f"document.querySelector('{CANVAS}').dataset.maskArea === '{dragged}'")
    shoot(page, "review-polygon")

    # A new vertex in the middle of the top edge, pulled 40 px up: 400 × 40 / 2 more.
    stroke(page, (600, 300), (600, 260))
    pulled = wait_for_mask_change(page, dragged)
    assert pulled - dragged == pytest.approx(8000, abs=450)
    assert len(outline_points()) == 5
    # Right-click removes it again: the same polygon as before, the same pixels.
    page.mouse.click(*to_page(page, 600, 260), button="right")
    wait_for_js(page, f"document.querySelector('{CANVAS}').dataset.maskArea === '{dragged}'")
    assert len(outline_points()) == 4
    # Select the bottom-left corner with a click, remove it with Delete: a triangle is left.
    page.mouse.click(*to_page(page, 400, 500))
    page.keyboard.press("Delete")
    triangle = wait_for_mask_change(page, dragged)
    assert outline_points() == [(400, 300), (800, 300), (840, 500)]
    assert triangle == pytest.approx(dragged - 200 * 400 / 2 - 4000, abs=450)

    # Outline only: the inside shows the frame as if the mask were hidden; the label is unchanged.
    page.keyboard.press("1")  # no outline handles in the way
    page.wait_for_timeout(150)
    filled = page.evaluate(IMAGE_PIXEL, [700, 350])
    page.check("[data-testid=display-outline]")
    page.wait_for_timeout(150)
    outlined = page.evaluate(IMAGE_PIXEL, [700, 350])
    shoot(page, "review-outline-only")
    page.uncheck("#show-mask")
    page.wait_for_timeout(150)
    assert outlined == page.evaluate(IMAGE_PIXEL, [700, 350]) != filled
    page.uncheck("[data-testid=display-outline]")
    page.check("#show-mask")
    assert canvas_data(page, "mask-area") == triangle

    page.uncheck("#advance")
    page.keyboard.press("s")
    wait_for_js(page, f"document.querySelector('{CANVAS}').dataset.revision === '2'")
    label = server.api("GET", f"/frames/{frame_id}/label").json()
    stored = cv2.imdecode(np.frombuffer(base64.b64decode(label["mask_png"]), np.uint8), 0)
    assert int((stored > 0).sum()) == triangle


def test_dropped_frames_get_ids_in_file_name_order(page: Any, server: LiveServer) -> None:
    """Several frames dropped at once are stored in natural name order (f2 before f10), so
    frame ids follow the camera's numbering, not which upload finished first."""
    sequence = server.api("POST", "/sequences", json={"name": "Order run"}).json()
    login(page, server, "rita")
    page.goto(f"{server.url}/?sequence_id={sequence['id']}")
    page.wait_for_selector("body[data-ready]")
    names = ["f10.png", "f2.png", "f1.png", "f9.png"]
    page.set_input_files(
        "[data-testid=upload-input]",
        files=[
            {"name": n, "mimeType": "image/png", "buffer": synthetic_png(700 + i, 320, 200)}
            for i, n in enumerate(names)
        ],
    )
    for name in names:
        page.wait_for_selector(f"[data-testid=upload-item][data-name='{name}'][data-state=ok]")
    listed = page.locator("[data-testid=upload-item] .name").all_inner_texts()[:4]
    assert listed == ["f1.png", "f2.png", "f9.png", "f10.png"]  # shown in the order sent
    frames = server.api(
        "GET", "/frames", params={"sequence_id": sequence["id"], "order": "id", "status": "all"}
    ).json()["items"]
    assert [f["original_name"] for f in frames] == ["f1.png", "f2.png", "f9.png", "f10.png"]


def test_propagate_from_a_corrected_frame_then_read_the_runs_timeline(
    page: Any, server: LiveServer
) -> None:
    """A reviewer corrects one frame of a run, propagates from it, reads the timeline (strip,
    geometry curves), opens a propagated frame from the strip, fixes it, and sees it reviewed."""
    sequence = server.api("POST", "/sequences", json={"name": "Propagation run"}).json()
    server.api("PATCH", f"/sequences/{sequence['id']}", json={"mm_per_px": 0.05})
    files = [
        ("files", (f"p{i}.png", synthetic_png(900 + i, 320, 200), "image/png")) for i in range(5)
    ]
    ids = [
        f["id"]
        for f in server.api(
            "POST", "/frames", files=files, data={"sequence_id": sequence["id"]}
        ).json()["stored"]
    ]
    save_true_label(server, ids[0], 900, 320, 200)

    login(page, server, "rita")
    page.goto(f"{server.url}/frames/{ids[0]}")
    open_review(page)
    page.fill("[data-testid=propagate-threshold]", "0")  # random weights: never stop early
    page.click("[data-testid=propagate]")
    page.wait_for_selector("[data-testid=toast-ok]:has-text('Propagation done')", timeout=120_000)
    assert "4 frames proposed" in page.inner_text("[data-testid=propagate-note]")
    page.click("[data-testid=propagate-note] [data-testid=timeline-link]")
    page.wait_for_url(re.compile(rf"/sequences/{sequence['id']}$"))
    page.wait_for_selector("body[data-ready]")
    assert page.inner_text("#run-name") == "Propagation run"
    cells = page.locator("[data-testid=strip-cell]")
    assert cells.count() == 5
    assert cells.nth(0).get_attribute("data-status") == "corrected"
    assert {cells.nth(i).get_attribute("data-status") for i in range(1, 5)} == {"proposed"}
    assert "confidence" in cells.nth(3).get_attribute("title")
    assert page.locator("[data-testid=geometry-charts] svg").count() == 4
    assert "0.05 mm per pixel" in page.inner_text("[data-testid=geometry-note]")
    with page.expect_download() as download:
        page.click("[data-testid=geometry-csv]")
    lines = Path(download.value.path()).read_text().splitlines()
    assert lines[0].startswith("frame_id,frame_index") and len(lines) == 6
    page.click("[data-testid=embed-run]")
    page.wait_for_selector("[data-testid=toast-ok]:has-text('Embeddings ready')", timeout=60_000)
    page.click("[data-testid=propagate-run]")  # from every reviewed frame of the run
    page.wait_for_selector("[data-testid=job-state]:has-text('Propagation done')", timeout=120_000)
    assert page.locator("[data-testid=strip-cell]").count() == 5

    # Open frame 4 from the strip: it shows where its mask came from; fix it and save.
    cells.nth(3).click()
    page.wait_for_url(re.compile(rf"/frames/{ids[3]}\?"))
    open_review(page)
    assert f"propagated from #{ids[0]}" in page.inner_text("[data-testid=proposal-source]")
    page.uncheck("#advance")
    page.click("[data-testid=tool-brush]")
    stroke(page, (100, 100), (200, 120))
    page.click("[data-testid=save]")
    page.wait_for_selector("[data-testid=toast-ok]:has-text('corrected')")
    page.goto(f"{server.url}/sequences/{sequence['id']}")
    page.wait_for_selector("body[data-ready]")
    assert (
        page.locator("[data-testid=strip-cell]").nth(3).get_attribute("data-status") == "corrected"
    )

    # From the first frame again, forward only and only as far as frame index 2 (of 0–4).
    page.goto(f"{server.url}/frames/{ids[0]}")
    open_review(page)
    assert page.locator("[data-testid=propagate-until]").is_disabled()  # "both ways": no end
    page.select_option("[data-testid=propagate-direction]", "forward")
    page.fill("[data-testid=propagate-until]", "2")
    shoot(page, "review-propagate")
    page.fill("[data-testid=propagate-threshold]", "0")
    page.click("[data-testid=propagate]")
    page.wait_for_selector("[data-testid=toast-ok]:has-text('Propagation done')", timeout=120_000)
    assert "2 frames proposed" in page.inner_text("[data-testid=propagate-note]")

    # An annotator sees both propagate buttons off, and why (the API refuses them: 403).
    page.context.clear_cookies()
    login(page, server, "anna")
    page.goto(f"{server.url}/frames/{ids[0]}")
    open_review(page)
    button = page.locator("[data-testid=propagate]")
    assert button.is_disabled() and "A reviewer propagates" in button.get_attribute("title")
    shoot(page, "review-propagate-annotator")
    page.goto(f"{server.url}/sequences/{sequence['id']}")
    page.wait_for_selector("body[data-ready]")
    button = page.locator("[data-testid=propagate-run]")
    assert button.is_disabled() and "A reviewer propagates" in button.get_attribute("title")
    shoot(page, "timeline-annotator")


def test_measure_a_runs_scale_from_two_points_on_a_frame(page: Any, server: LiveServer) -> None:
    """On the review page, "Measure scale" (L) takes two clicks on the frame and a length in
    mm; an end can be dragged; saving sets the run's mm per pixel (the length over the ends'
    separation), and the clicks never touch the mask."""
    sequence = server.api("POST", "/sequences", json={"name": "Scale run"}).json()
    files = [("files", ("s0.png", synthetic_png(950, 320, 200), "image/png"))]
    frame_id = server.api(
        "POST", "/frames", files=files, data={"sequence_id": sequence["id"]}
    ).json()["stored"][0]["id"]
    login(page, server, "rita")
    page.goto(f"{server.url}/frames/{frame_id}")
    open_review(page)
    page.wait_for_selector("[data-testid=scale-state]:has-text('No scale yet')")
    page.locator(CANVAS).focus()
    page.keyboard.press("l")
    assert page.get_attribute("[data-testid=measure-scale]", "aria-pressed") == "true"
    area = canvas_data(page, "mask-area")
    page.mouse.click(*to_page(page, 40, 20))
    assert "1 of 2 ends placed" in page.inner_text("[data-testid=scale-span]")
    page.mouse.click(*to_page(page, 240, 20))

    def span() -> float:  # the ends land to a screen pixel: a fraction of a frame pixel
        text = page.inner_text("[data-testid=scale-span]")
        return float(re.match(r"([\d.]+) px between the ends", text).group(1))  # type: ignore[union-attr]

    assert span() == pytest.approx(200, abs=0.6)
    stroke(page, (240, 20), (120, 170))  # the second end dragged: 80 across, 150 down
    assert span() == pytest.approx(170, abs=0.6)
    assert page.is_disabled("[data-testid=save-scale]")  # no length yet
    page.fill("[data-testid=scale-mm]", "17")
    assert "→ 0.1 mm per pixel" in page.inner_text("[data-testid=scale-span]")
    shoot(page, "review-scale")
    page.click("[data-testid=save-scale]")
    page.wait_for_selector("[data-testid=toast-ok]:has-text('mm per pixel')")
    assert page.is_hidden("[data-testid=scale-panel]")
    state = page.inner_text("[data-testid=scale-state]")
    assert re.search(r"Scale: 0\.(1|0999)\d* mm per pixel\.", state), state
    run = server.api("GET", f"/sequences/{sequence['id']}").json()
    assert run["mm_per_px"] == pytest.approx(0.1, abs=0.002)  # ends placed to the screen pixel
    assert canvas_data(page, "mask-area") == area and page.is_hidden("[data-testid=dirty]")
    # Esc puts the ruler away without saving anything.
    page.keyboard.press("l")
    page.mouse.click(*to_page(page, 10, 10))
    page.keyboard.press("Escape")
    assert page.is_hidden("[data-testid=scale-panel]")
    assert server.api("GET", f"/sequences/{sequence['id']}").json()["mm_per_px"] == run["mm_per_px"]


def test_a_versions_sequential_cell_from_the_models_page_to_a_live_view(
    page: Any, server: LiveServer, tmp_path: Path
) -> None:
    """A version's card says it has no sequential cell and offers to train one (confirmed, a
    job starts); once a cell is trained its measurement against the per-frame student shows on
    the card, and the live page lets that version run with it (and only that version)."""
    size = SynthParams(width=320, height=200)
    video = write_video(tmp_path / "cell run.avi", 40, fps=20.0, size=(320, 200))
    with open(video, "rb") as handle:
        uploaded = server.api(
            "POST",
            "/videos",
            files={"file": ("cell run.avi", handle, "video/avi")},
            data={"every_nth": "5"},
        ).json()
    assert server.wait_for_job(uploaded["job_id"], timeout=120)["status"] == "succeeded"
    frames = server.api(
        "GET",
        "/frames",
        params={"sequence_id": uploaded["video"]["sequence_id"], "order": "frame_index"},
    ).json()["items"]
    by_index = {f["frame_index"]: f["id"] for f in frames}
    for index in (10, 20, 30):  # write_video draws synthetic run index % 3
        mask = synth_frame(index % 3, size).mask
        saved = server.api("PUT", f"/frames/{by_index[index]}/label", json=corrected_label(mask))
        assert saved.status_code == 200, saved.text
    placed = server.api(
        "PUT", f"/frames/{by_index[30]}/validation-keypoints", json={"keypoints": [[160, 100]]}
    )
    assert placed.status_code == 200  # frame 30 joins the validation split
    login(page, server, "rita")
    dialogs = accept_dialogs(page)
    page.goto(f"{server.url}/models")
    page.wait_for_selector("body[data-ready]")
    page.fill("#train-form input[name=epochs]", "1")  # the form's own path to a version
    page.click("[data-testid=train-button]")
    page.wait_for_selector("[data-testid=toast-ok]:has-text('Training job')", timeout=300_000)
    assert "succeeded" in page.inner_text("[data-testid=train-state]")
    version = server.api("GET", "/models").json()[0]
    others = [m for m in server.api("GET", "/models").json() if m["id"] != version["id"]]
    if not others:  # alone: a second version, without a cell, for the live page's choice
        again = server.api("POST", "/student/train", json={"epochs": 1, "size": "light"})
        assert server.wait_for_job(again.json()["job_id"], timeout=300)["status"] == "succeeded"
        version, others = (
            server.api("GET", "/models").json()[1],
            [server.api("GET", "/models").json()[0]],
        )

    page.goto(f"{server.url}/models")
    card = page.locator(f"[data-testid=model-card][data-model-id='{version['id']}']")
    card.wait_for()
    assert card.locator("[data-testid=sequential]").inner_text() == "no sequential cell"
    button = card.locator("[data-testid=train-sequential]")
    assert button.inner_text() == "Train sequential cell"
    button.click()
    page.wait_for_selector("[data-testid=train-state] a")
    assert dialogs and dialogs[0].startswith(f"Train a sequential cell for {version['name']}?")
    clicked = int(page.inner_text("[data-testid=train-state] a").lstrip("#"))
    assert server.api("GET", f"/jobs/{clicked}").json()["kind"] == "train_sequential"
    server.api("POST", f"/jobs/{clicked}/cancel")  # 200 steps take minutes on a CPU
    assert server.wait_for_job(clicked, timeout=120)["status"] == "cancelled"

    short = server.api("POST", f"/models/{version['id']}/sequential", json={"steps": 5})
    assert short.status_code == 202, short.text
    assert server.wait_for_job(short.json()["job_id"], timeout=300)["status"] == "succeeded"
    measured = server.api("GET", f"/models/{version['id']}").json()["sequential"]["measured"]
    page.goto(f"{server.url}/models")
    card.locator("[data-testid=sequential] .badge").wait_for()
    line = card.locator("[data-testid=sequential]").inner_text()
    assert f"mask IoU {fixed(measured['sequential_iou'], 3)} against the per-frame" in line
    assert f"{fixed(measured['per_frame_iou'], 3)} on 1 validation frame" in line
    assert card.locator("[data-testid=train-sequential]").inner_text() == "Retrain sequential cell"
    shoot(page, "models-sequential", full_page=True)
    # The card's flag: a cell less accurate (by more than 0.01) or less steady is marked; one
    # with nothing measured is neither marked good nor bad.
    cases = [  # (per-frame IoU, sequential IoU, per-frame change, sequential change)
        (0.85, 0.845, 0.02, 0.01),
        (0.85, 0.83, 0.02, 0.01),
        (0.85, 0.85, 0.01, 0.02),
        (None, None, None, None),
    ]
    flags = page.evaluate(
        """async (cases) => {
          const { sequentialLine } = await import("/static/js/format.js");
          return cases.map(([a, b, c, d]) => sequentialLine({ measured: {
            frames: 3, windows: 9, per_frame_iou: a, sequential_iou: b,
            per_frame_change: c, sequential_change: d } }).className);
        }""",
        cases,
    )
    assert flags == ["gate ok", "gate warning", "gate warning", "gate muted"]

    page.goto(f"{server.url}/live?model_id={version['id']}")
    wait_for_js(page, "document.querySelector('[data-testid=live-model]').options.length > 1")
    box = page.locator("[data-testid=live-sequential]")
    assert box.is_enabled()
    page.select_option("[data-testid=live-model]", str(others[0]["id"]))
    assert box.is_disabled()  # a version without a cell
    assert "has no sequential cell" in (box.locator("xpath=..").get_attribute("title") or "")
    page.select_option("[data-testid=live-model]", str(version["id"]))
    assert box.is_enabled()
    box.check()
    page.fill("[data-testid=live-source]", str(video))
    page.click("[data-testid=live-start]")
    live = page.locator("[data-testid=live-card][data-state=running]")
    live.wait_for(timeout=60_000)
    assert f"{version['name']} (sequential) on" in live.locator("h2").inner_text()
    wait_for_js(page, "/fps/.test(document.querySelector('[data-testid=live-stats]').textContent)")
    shoot(page, "live-sequential")
    live.locator("[data-testid=live-stop]").click()


def test_an_int8_student_from_the_models_page_to_a_live_view(
    page: Any, tmp_path: Path, sure_student: Any
) -> None:
    """ "Make int8" on a version's card: the job calibrates on the project's frames, the card
    then says how its masks agree with the float student's and how much faster it is here, and
    the live page runs it (not with sequential). Its own server: the project's frames are the
    camera the int8 student is calibrated on. The student is the run's ``sure_student``
    (trained long enough for crisp masks: int8 can match it), copied into that home."""
    import shutil

    from app.core.db import create_db_engine, create_session_factory
    from app.core.models import ModelVersion

    own = LiveServer(tmp_path / "home").start()
    try:
        shutil.copytree(sure_student.model_dir, own.home / "models" / "student-v1")
        engine = create_db_engine(f"sqlite:///{(own.home / 'weldpool.sqlite3').resolve()}")
        with create_session_factory(engine)() as session:
            session.add(
                ModelVersion(
                    name="student-v1", checkpoint_path="models/student-v1", is_promoted=True
                )
            )
            session.commit()
        engine.dispose()
        params = SynthParams(width=96, height=64)
        files = [
            (
                "files",
                (f"c{s}.png", cv2.imencode(".png", synth_frame(s, params).image)[1].tobytes()),
            )
            for s in range(100, 112)
        ]
        assert own.api("POST", "/frames", files=files).status_code == 201
        login(page, own, "rita")
        dialogs = accept_dialogs(page)
        page.goto(f"{own.url}/models")
        card = page.locator("[data-testid=model-card]").first
        card.wait_for()
        assert card.locator("[data-testid=int8]").inner_text() == "no int8 student"
        assert card.locator("[data-testid=make-int8]").inner_text() == "Make int8"
        card.locator("[data-testid=make-int8]").click()
        page.wait_for_selector(
            "[data-testid=toast-ok]:has-text('int8 student job')", timeout=120_000
        )
        assert dialogs and dialogs[0].startswith("Make an int8 student for student-v1?")
        record = own.api("GET", "/models/1").json()["int8"]
        page.goto(f"{own.url}/models")
        card.locator("[data-testid=int8] .badge").wait_for()
        line = card.locator("[data-testid=int8]").inner_text()
        mean, worst = fixed(record["mean_iou"], 3), fixed(record["min_iou"], 3)
        assert f"at IoU {mean} ({worst} at worst) on 6 frames" in line
        int8_ms, float_ms = fixed(record["int8_ms"], 1), fixed(record["float_ms"], 1)
        assert f"{int8_ms} ms a frame against {float_ms} ms here" in line
        assert card.locator("[data-testid=make-int8]").inner_text() == "Remake int8"
        shoot(page, "models-int8", full_page=True)
        # The card's flag: an int8 student no faster here than the float one is marked.
        flags = page.evaluate(
            """async (cases) => {
              const { int8Line } = await import("/static/js/format.js");
              return cases.map(([float_ms, int8_ms]) => int8Line({ mean_iou: 0.99,
                min_iou: 0.98, check_frames: 6, keypoint_px: 1.0, float_ms, int8_ms }).className);
            }""",
            [[6.0, 3.9], [6.0, 6.5]],
        )
        assert flags == ["gate ok", "gate warning"]
        page.goto(f"{own.url}/jobs")
        page.wait_for_selector("body[data-ready]")
        row = page.locator("[data-testid=job-row]", has_text="quantize_student").first
        assert row.locator("[data-testid=job-scope]").inner_text() == "int8 student of model #1"
        assert row.locator("td.message").inner_text().startswith("student-v1: int8 student made")
        shoot(page, "jobs-int8")

        video = write_video(tmp_path / "int8 run.avi", 200, fps=20.0)
        page.goto(f"{own.url}/live?model_id=1")
        wait_for_js(page, "document.querySelector('[data-testid=live-model]').options.length > 1")
        int8, sequential = (
            page.locator("[data-testid=live-int8]"),
            page.locator("[data-testid=live-sequential]"),
        )
        assert int8.is_enabled() and sequential.is_disabled()  # no sequential cell
        assert "ms a frame against" in (int8.locator("xpath=..").get_attribute("title") or "")
        int8.check()
        page.fill("[data-testid=live-source]", str(video))
        page.click("[data-testid=live-start]")
        live = page.locator("[data-testid=live-card][data-state=running]")
        live.wait_for(timeout=60_000)
        assert "student-v1 (int8) on" in live.locator("h2").inner_text()
        wait_for_js(
            page, "/fps/.test(document.querySelector('[data-testid=live-stats]').textContent)"
        )
        shoot(page, "live-int8")
        live.locator("[data-testid=live-stop]").click()
    finally:
        own.stop()
