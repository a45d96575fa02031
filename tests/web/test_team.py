"""The team in the browser: the users and account pages, the API page, assignments, the review
stage, and the first click on a frame."""

from __future__ import annotations

import json
from typing import Any

import pytest

from tests.factories import synthetic_png
from tests.pages import accept_dialogs, login, shoot, wait_for_js
from tests.web.server import PASSWORD, LiveServer

pytestmark = [pytest.mark.browser, pytest.mark.slow]


def _row(page: Any, name: str) -> Any:
    return page.locator(f"[data-testid=user-row][data-username='{name}']")


def _toast(page: Any, kind: str, text: str) -> str:
    toast = page.locator(f"[data-testid=toast-{kind}]", has_text=text).last
    toast.wait_for()
    return str(toast.inner_text())


def _login_as(browser: Any, server: LiveServer, name: str, password: str) -> Any:
    context = browser.new_context(viewport={"width": 1280, "height": 800})
    tab = context.new_page()
    tab.goto(f"{server.url}/login")
    tab.fill("input[name=username]", name)
    tab.fill("input[name=password]", password)
    tab.click("[data-testid=login-submit]")
    return tab


def test_an_admin_adds_a_user_changes_role_password_and_activity(
    page: Any, browser: Any, server: LiveServer
) -> None:
    """From the Users link: add a user, make them a reviewer, give them a new password (they
    log in with it, not the old one), deactivate (they cannot log in) and reactivate them; the
    last admin's demotion is refused with the server's sentence and the role shown stays."""
    dialogs = accept_dialogs(page)
    login(page, server, "ada")
    page.click("[data-testid=nav-users]")
    page.wait_for_url(f"{server.url}/users")
    page.wait_for_selector("body[data-ready]")
    page.fill("[data-testid=new-username]", "tess")
    page.select_option("[data-testid=new-role]", "annotator")
    page.fill("[data-testid=new-user-password]", "first-password")
    page.click("[data-testid=add-user]")
    _toast(page, "ok", "tess added as annotator")
    tess = _row(page, "tess")
    tess.wait_for()
    assert "never" in tess.locator("[data-testid=last-login]").inner_text()

    tess.locator("[data-testid=user-role]").select_option("reviewer")
    _toast(page, "ok", "tess is now reviewer")
    users = {u["username"]: u for u in server.api("GET", "/users", user="ada").json()}
    assert users["tess"]["role"] == "reviewer" and users["tess"]["is_active"]

    _row(page, "tess").locator("[data-testid=set-password]").click()
    page.fill("[data-testid=set-password-input]", "second-password")
    page.click("[data-testid=set-password-save]")
    _toast(page, "ok", "tess has a new password")
    old = _login_as(browser, server, "tess", "first-password")
    assert "Wrong user name or password" in old.inner_text("body")
    old.context.close()
    new = _login_as(browser, server, "tess", "second-password")
    new.wait_for_url(f"{server.url}/")
    new.context.close()
    page.reload()
    page.wait_for_selector("body[data-ready]")
    assert "never" not in _row(page, "tess").locator("[data-testid=last-login]").inner_text()

    _row(page, "tess").locator("[data-testid=deactivate-user]").click()
    _toast(page, "ok", "tess is deactivated")
    assert dialogs and "Deactivate tess?" in dialogs[-1]
    _row(page, "tess").locator(".badge.deactivated").wait_for()
    shoot(page, "users")
    locked = _login_as(browser, server, "tess", "second-password")
    assert "Wrong user name or password" in locked.inner_text("body")
    locked.context.close()
    _row(page, "tess").locator("[data-testid=reactivate-user]").click()
    _toast(page, "ok", "tess is active again")
    _row(page, "tess").locator(".badge.active").wait_for()

    # the instance's first admin out of the way for a moment: ada is the last active admin
    first = {u["username"]: u for u in server.api("GET", "/users", user="ada").json()}["admin"]
    server.api("PATCH", f"/users/{first['id']}", user="ada", json={"is_active": False})
    try:
        page.reload()
        page.wait_for_selector("body[data-ready]")
        _row(page, "ada").locator("[data-testid=user-role]").select_option("reviewer")
        refusal = _toast(page, "error", "no active admin")
        assert refusal == "This would leave no active admin; promote another user first."
        page.wait_for_timeout(300)  # the list is read again after the refusal
        assert _row(page, "ada").locator("[data-testid=user-role]").input_value() == "admin"
        assert server.api("GET", "/users/me", user="ada").json()["role"] == "admin"
    finally:
        server.api("PATCH", f"/users/{first['id']}", user="ada", json={"is_active": True})


def test_a_user_changes_their_own_password_on_the_account_page(
    page: Any, browser: Any, server: LiveServer
) -> None:
    """From one's name in the header: a wrong current password is refused in one sentence,
    two different new ones are caught before sending, then the change works: another browser
    of the same user is logged out, this one stays, the new password logs in."""
    server.api("POST", "/users", user="ada", json={"username": "uwe", "password": PASSWORD})
    elsewhere = _login_as(browser, server, "uwe", PASSWORD)
    elsewhere.wait_for_url(f"{server.url}/")
    login(page, server, "uwe")
    page.click("[data-testid=current-user]")
    page.wait_for_url(f"{server.url}/account")
    page.wait_for_selector("body[data-ready]")  # the token list beside the form
    page.fill("[data-testid=current-password]", "not-my-password")
    page.fill("[data-testid=new-password]", "uwe-new-password")
    page.fill("[data-testid=repeat-password]", "uwe-new-password")
    page.click("[data-testid=change-password]")
    assert _toast(page, "error", "current password") == "The current password is not right."
    page.fill("[data-testid=current-password]", PASSWORD)
    page.fill("[data-testid=repeat-password]", "uwe-other-password")
    page.click("[data-testid=change-password]")
    _toast(page, "error", "two new passwords differ")
    page.fill("[data-testid=repeat-password]", "uwe-new-password")
    page.click("[data-testid=change-password]")
    result = page.locator("[data-testid=password-result]")
    result.wait_for()
    assert "1 other browser session was logged out" in result.inner_text()
    shoot(page, "account")
    elsewhere.goto(f"{server.url}/jobs")
    assert "/login" in elsewhere.url  # that browser's session ended
    elsewhere.context.close()
    page.goto(f"{server.url}/jobs")
    assert page.url == f"{server.url}/jobs"  # this one stays
    again = _login_as(browser, server, "uwe", "uwe-new-password")
    again.wait_for_url(f"{server.url}/")
    again.context.close()


def _operation(page: Any, operation: str) -> Any:
    block = page.locator(f"#operations-users-{operation}")
    block.wait_for()
    if not block.locator(".opblock-body").count():  # a reload opens the deep-linked one itself
        block.locator(".opblock-summary").first.click()
    block.locator("button.try-out__btn").click()
    return block


def _execute(block: Any) -> tuple[str, str]:
    block.locator("button.execute").click()
    status = block.locator(".live-responses-table tbody .response-col_status").first
    status.wait_for()
    body = block.locator(".live-responses-table tbody .response-col_description pre").first
    return status.inner_text().strip(), body.inner_text()


def test_the_api_page_writes_with_the_session_and_with_an_authorized_token(
    page: Any, server: LiveServer
) -> None:
    """Swagger UI's "Try it out": a write with the browser's session works (the CSRF token is
    sent); a token given under Authorize is used instead, and kept across a reload; the bar
    leads back to the app."""
    login(page, server, "rita")
    page.goto(f"{server.url}/docs")
    page.wait_for_selector(".swagger-ui .opblock-tag")
    assert "Logged in as rita" in page.inner_text(".docs-bar")
    create = _operation(page, "create_token_api_v1_tokens_post")
    create.locator("textarea.body-param__text").fill('{"name": "from the API page"}')
    status, body = _execute(create)
    assert status == "201", body
    assert "from the API page" in body
    names = [t["name"] for t in server.api("GET", "/tokens", user="rita").json()]
    assert "from the API page" in names

    page.locator(".auth-wrapper button.authorize").click()
    page.locator(".modal-ux input").first.fill(server.tokens["anna"])
    page.locator(".modal-ux button.authorize").click()
    page.locator(".modal-ux button.btn-done").click()
    status, body = _execute(_operation(page, "me_api_v1_users_me_get"))
    assert status == "200" and '"username": "anna"' in body  # the token, not the session
    shoot(page, "docs-try")
    page.reload()
    page.wait_for_selector(".swagger-ui .opblock-tag")
    status, body = _execute(_operation(page, "me_api_v1_users_me_get"))
    assert status == "200" and '"username": "anna"' in body  # still authorized
    page.click("[data-testid=back-to-app]")
    page.wait_for_url(f"{server.url}/")


def test_a_reviewer_hands_frames_to_an_annotator_who_starts_on_them(
    page: Any, server: LiveServer
) -> None:
    """A reviewer assigns a selection and the next frame of a run's queue to anna; the list
    names her; anna's frames page opens on "assigned to me", the review page names her as the
    assignee, and its Next stays within her frames."""
    sequence = server.api("POST", "/sequences", json={"name": "Handed-out run"}).json()
    files = [("files", (f"h{i}.png", synthetic_png(700 + i), "image/png")) for i in range(5)]
    stored = server.api("POST", "/frames", files=files, data={"sequence_id": sequence["id"]})
    ids = [f["id"] for f in stored.json()["stored"]]
    anna = next(u for u in server.api("GET", "/users/assignable").json() if u["username"] == "anna")

    login(page, server, "rita")
    page.goto(f"{server.url}/?sequence_id={sequence['id']}&status=all&order=id")
    page.wait_for_selector("body[data-ready]")
    page.select_option("[data-testid=assign-to]", str(anna["id"]))
    for frame_id in ids[:2]:
        page.check(f"[data-testid=frame-row][data-frame-id='{frame_id}'] input[type=checkbox]")
    page.click("[data-testid=assign-selection]")
    page.locator("[data-testid=toast-ok]", has_text="2 frames assigned to anna").wait_for()
    assert page.inner_text("#selection-count") == "0 selected"
    page.fill("[data-testid=assign-count]", "1")
    page.click("[data-testid=assign-next]")
    page.locator("[data-testid=toast-ok]", has_text="1 frame assigned to anna").wait_for()
    wait_for_js(
        page,
        "[...document.querySelectorAll('[data-testid=frame-assignee]')]"
        ".filter((cell) => cell.textContent === 'anna').length === 3",
    )
    shoot(page, "frames-assigned")
    mine = [f for f in ids if server.api("GET", f"/frames/{f}").json()["assignee"] == "anna"]
    assert len(mine) == 3 and set(ids[:2]) <= set(mine)

    page.context.clear_cookies()
    login(page, server, "anna")
    page.wait_for_selector("body[data-ready]")
    assert page.input_value("[data-testid=filter-assignee]") == "work"
    page.locator("[data-testid=toast-info]", has_text="3 frames handed to you").wait_for()
    wait_for_js(page, "document.querySelectorAll('[data-testid=frame-row]').length > 0")
    listed = [
        int(row.get_attribute("data-frame-id"))
        for row in page.locator("[data-testid=frame-row]").all()
    ]
    assert sorted(listed) == sorted(mine)
    page.click("[data-testid=start-review]")
    page.wait_for_selector("[data-testid=frame-canvas]")
    wait_for_js(page, "document.getElementById('frame-meta').textContent.includes('assigned to')")
    assert "assigned to anna" in page.inner_text("#frame-meta")
    wait_for_js(
        page, "document.getElementById('queue-position').textContent.includes('of 3 in this queue')"
    )


def test_the_review_stage_from_awaiting_to_sent_back_to_approved(
    browser: Any, tmp_path: Any
) -> None:
    """With WELDPOOL_REVIEW_STAGE on: an annotator's saved label waits; the reviewer finds it
    under "Review: awaiting review", sends it back with a comment the annotator then reads on
    the page, and approves the corrected one; the history names who decided."""
    from tests.helpers import corrected_label
    from weldpool_core.synth import SynthParams, synth_frame

    server = LiveServer(tmp_path / "home", env={"WELDPOOL_REVIEW_STAGE": "true"}).start()
    context = browser.new_context(viewport={"width": 1280, "height": 800})
    page = context.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda error: errors.append(str(error)))
    try:
        files = [("files", (f"s{i}.png", synthetic_png(800 + i), "image/png")) for i in range(2)]
        ids = [f["id"] for f in server.api("POST", "/frames", files=files).json()["stored"]]
        mask = synth_frame(seed=800, params=SynthParams(1280, 800)).mask
        saved = server.api(
            "PUT", f"/frames/{ids[0]}/label", user="anna", json=corrected_label(mask)
        )
        assert saved.json()["review"] == "awaiting"

        login(page, server, "rita")
        page.goto(f"{server.url}/?status=all&review=awaiting")
        page.wait_for_selector("body[data-ready]")
        rows = page.locator("[data-testid=frame-row]")
        wait_for_js(page, "document.querySelectorAll('[data-testid=frame-row]').length === 1")
        assert rows.first.get_attribute("data-frame-id") == str(ids[0])
        rows.first.locator("a.frame-link").click()
        page.wait_for_selector("[data-testid=frame-canvas][data-ready]")
        assert "Awaiting a reviewer's approval" in page.inner_text("[data-testid=review-state]")
        page.click("[data-testid=send-back]")
        page.fill("[data-testid=review-comment]", "The wire tip is inside the mask.")
        page.click("[data-testid=send-back-submit]")
        page.locator("[data-testid=toast-ok]", has_text="Sent back").wait_for()
        state = page.inner_text("[data-testid=review-state]")
        assert "Sent back by rita" in state and "The wire tip is inside the mask." in state
        shoot(page, "review-sent-back")

        anna = browser.new_context(viewport={"width": 1280, "height": 800}).new_page()
        login(anna, server, "anna")
        anna.goto(f"{server.url}/frames/{ids[0]}")
        anna.wait_for_selector("[data-testid=frame-canvas][data-ready]")
        assert "The wire tip is inside the mask." in anna.inner_text("[data-testid=review-state]")
        assert anna.is_hidden("[data-testid=approve]")  # annotators do not approve
        anna.context.close()
        again = server.api(
            "PUT",
            f"/frames/{ids[0]}/label",
            user="anna",
            json=corrected_label(mask, base_revision=2),
        )
        assert again.json()["review"] == "awaiting"

        page.reload()
        page.wait_for_selector("[data-testid=frame-canvas][data-ready]")
        page.click("[data-testid=approve]")
        page.locator("[data-testid=toast-ok]", has_text="Approved").wait_for()
        assert "Approved by rita" in page.inner_text("[data-testid=review-state]")
        assert page.is_hidden("[data-testid=approve]")
        history = page.locator("#history")
        history.locator("li", has_text="approved").first.wait_for()
        assert "sent back" in history.inner_text()
        shoot(page, "review-approved")
        label = server.api("GET", f"/frames/{ids[0]}/label").json()
        assert label["review"] == "approved" and label["updated_by"] == "rita"
    finally:
        context.close()
        server.stop()
    assert not errors, errors


def test_the_first_click_after_the_page_prepared_it_reads_the_embedding_from_memory(
    page: Any, server: LiveServer
) -> None:
    """The review page asks for its frame's embedding as it opens and shows it being made;
    once "clicks ready", the first click is answered from memory and names the proposal's
    mask instead of sending a PNG of it."""
    from tests.factories import add_frame
    from tests.pages import CANVAS, to_page

    frame_id = add_frame(server, 901)
    login(page, server)
    sent: list[dict[str, Any]] = []
    page.on(
        "request",
        lambda request: (
            sent.append(json.loads(request.post_data or "{}"))
            if request.url.endswith(f"/frames/{frame_id}/segment")
            else None
        ),
    )
    page.goto(f"{server.url}/frames/{frame_id}")
    page.wait_for_selector(f"{CANVAS}[data-ready]")
    page.wait_for_selector("[data-testid=embed-state][data-state=ready]", timeout=60_000)
    with page.expect_response(lambda r: r.url.endswith(f"/frames/{frame_id}/segment")) as answer:
        page.mouse.click(*to_page(page, 640, 420))
    body = answer.value.json()
    assert body["embedding"] == "memory"
    assert len(sent) == 1 and "mask_png" not in sent[0]
    assert sent[0]["mask_from"]["proposal_id"] > 0


def test_the_jobs_page_shows_the_embedding_cache_and_an_admin_clears_it(
    page: Any, server: LiveServer
) -> None:
    """The cache line names its size and limit; Clear (admins only) empties it after asking."""
    from tests.factories import add_frame

    frame_id = add_frame(server, 902, teacher=False)
    click = {"points": [{"x": 640, "y": 400, "positive": True}]}
    assert server.api("POST", f"/frames/{frame_id}/segment", json=click).status_code == 200
    login(page, server, "anna")
    page.goto(f"{server.url}/jobs")
    line = page.locator("[data-testid=embedding-cache]")
    line.locator("text=/\\d+ frames?, /").wait_for()
    assert page.locator("[data-testid=cache-clear]").count() == 0  # not an annotator's to clear
    page.context.clear_cookies()
    dialogs = accept_dialogs(page)
    login(page, server, "ada")
    page.goto(f"{server.url}/jobs")
    line.locator("text=/\\d+ frames?, /").wait_for()
    shoot(page, "jobs-cache")
    page.click("[data-testid=cache-clear]")
    page.locator("[data-testid=toast-ok]", has_text="Cleared").wait_for()
    assert dialogs and dialogs[-1].startswith("Clear the embedding cache?")
    line.locator("text=0 frames,").wait_for()
    assert server.api("GET", "/system/embedding-cache").json()["files"] == 0


@pytest.mark.parametrize(
    ("low", "high"), [(0.9812, 0.9815), (0.0, 1.0), (12.0, 12.4), (1e-4, 5e-4), (0.5, 0.5004)]
)
def test_a_charts_score_axis_labels_its_ticks_distinctly(
    page: Any, server: LiveServer, low: float, high: float
) -> None:
    """The charts' tick labels carry the decimals their step needs (a close mIoU range read
    "0.981" on every tick), and read back as the ticks' values."""
    login(page, server)
    labels = page.evaluate(
        "async ([low, high]) => { const m = await import('/static/js/chart.js');"
        " const t = m.ticks(low, high); return t.map((v) => [v, m.format(v, t[1] - t[0])]); }",
        [low, high],
    )
    texts = [text for _, text in labels]
    assert len(labels) >= 2 and len(set(texts)) == len(texts), labels
    step = labels[1][0] - labels[0][0]
    for value, text in labels:
        assert abs(float(text) - value) < step / 100, (value, text)


def test_a_rejected_frame_shows_no_proposal(page: Any, server: LiveServer) -> None:
    """A frame rejected as "no pool" opens empty: the teacher's mask and keypoints it rejected
    are not drawn over it again."""
    from tests.factories import add_frame
    from tests.pages import CANVAS, canvas_data

    frame_id = add_frame(server, 903)
    rejected = server.api(
        "PUT", f"/frames/{frame_id}/label", json={"status": "rejected", "base_revision": 0}
    )
    assert rejected.status_code == 200, rejected.text
    login(page, server)
    page.goto(f"{server.url}/frames/{frame_id}")
    page.wait_for_selector(f"{CANVAS}[data-ready]")
    assert canvas_data(page, "mask-area") == 0
    assert page.locator("#keypoint-list li:not(.plain)").count() == 0


def test_the_upload_target_is_explicit_and_a_copy_in_another_run_is_named(
    page: Any, server: LiveServer
) -> None:
    """The dropzone's own run select follows the list's Sequence filter, and can be set apart
    from it; a frame whose content another run holds is stored and says where else it is."""
    first = server.api("POST", "/sequences", json={"name": "Upload run A"}).json()
    second = server.api("POST", "/sequences", json={"name": "Upload run B"}).json()
    image = synthetic_png(904)
    files = [("files", ("pool.png", image, "image/png"))]
    original = server.api("POST", "/frames", files=files, data={"sequence_id": first["id"]})
    original_id = original.json()["stored"][0]["id"]

    login(page, server)
    page.goto(f"{server.url}/?sequence_id={first['id']}")
    page.wait_for_selector("body[data-ready]")
    assert page.input_value("[data-testid=upload-sequence]") == str(first["id"])  # followed
    page.select_option("[data-testid=upload-sequence]", str(second["id"]))
    page.set_input_files(
        "[data-testid=upload-input]",
        files=[{"name": "pool-again.png", "mimeType": "image/png", "buffer": image}],
    )
    item = page.locator("[data-testid=upload-item][data-name='pool-again.png'][data-state=ok]")
    item.wait_for()
    assert f"also in run “Upload run A” as frame #{original_id}" in item.inner_text()
    shoot(page, "upload-also-in")
    stored = server.api("GET", "/frames", params={"sequence_id": second["id"]}).json()["items"]
    assert [f["original_name"] for f in stored] == ["pool-again.png"]
    assert page.input_value("[data-testid=upload-sequence]") == str(second["id"])  # kept


def test_a_keypoint_added_takes_its_place_in_the_order_and_a_deletion_renumbers_nothing(
    page: Any, server: LiveServer
) -> None:
    """Delete keypoint 2 of the teacher's four: the others stay 1, 3, 4; a click where it was
    adds number 2 back (its place in the order rule), second in the list the label saves."""
    from tests.factories import add_frame
    from tests.pages import CANVAS, canvas_data, to_page

    frame_id = add_frame(server, 905)
    login(page, server)
    page.goto(f"{server.url}/frames/{frame_id}")
    page.wait_for_selector(f"{CANVAS}[data-ready]")
    before = canvas_data(page, "keypoints")
    assert len(before) == 4

    def numbers() -> list[str]:
        items = page.locator("#keypoint-list li[data-number]")
        return [str(item.get_attribute("data-number")) for item in items.all()]

    assert numbers() == ["1", "2", "3", "4"]
    page.locator("#keypoint-list li[data-number='2'] button").click()
    wait_for_js(page, "document.querySelectorAll('#keypoint-list li[data-number]').length === 3")
    assert numbers() == ["1", "3", "4"]  # nothing renumbered
    page.click("[data-testid=tool-keypoint]")
    x, y = before[1]
    page.mouse.click(*to_page(page, x + 3, y + 3))
    wait_for_js(page, "document.querySelectorAll('#keypoint-list li[data-number]').length === 4")
    assert numbers() == ["1", "2", "3", "4"]
    after = canvas_data(page, "keypoints")
    assert abs(after[1][0] - (x + 3)) < 2 and abs(after[1][1] - (y + 3)) < 2  # second in order
    assert after[0] == before[0] and after[2:] == before[2:]


def test_the_timeline_colours_what_its_charts_count_on_one_x_range(
    page: Any, server: LiveServer
) -> None:
    """A frame whose proposal has no confidence (a student's) is coloured as proposed, as the
    geometry charts count it; every chart shares one x range; a run with only a scale set
    says so in its header instead of "no process parameters"."""
    sequence = server.api("POST", "/sequences", json={"name": "Timeline run"}).json()
    server.api("PATCH", f"/sequences/{sequence['id']}", json={"mm_per_px": 0.05})
    files = [("files", (f"t{i}.png", synthetic_png(910 + i), "image/png")) for i in range(3)]
    stored = server.api("POST", "/frames", files=files, data={"sequence_id": sequence["id"]})
    ids = [f["id"] for f in stored.json()["stored"]]
    job = server.api("POST", "/teacher/runs", json={"frame_ids": ids[:2]}).json()
    assert server.wait_for_job(job["job_id"])["status"] == "succeeded"

    def as_a_student_proposal(route: Any) -> None:  # the second frame's proposal: a student's
        body = route.fetch().json()
        for row in body["frames"]:
            if row["frame_id"] == ids[1]:
                row["source"], row["confidence"] = "student", None
        route.fulfill(json=body)

    page.route(f"**/api/v1/sequences/{sequence['id']}/geometry*", as_a_student_proposal)
    login(page, server)
    page.goto(f"{server.url}/sequences/{sequence['id']}")
    cells = page.locator("[data-testid=strip-cell]")
    cells.nth(2).wait_for()
    classes = [str(cells.nth(i).get_attribute("class")) for i in range(3)]
    assert "proposed" in classes[0] and "proposed" in classes[1] and "none" in classes[2]
    header = page.inner_text("#run-process")
    assert "scale 0.05 mm/px" in header and "no process parameters" not in header
    ranges = page.locator("#charts svg.chart").evaluate_all(
        "(charts) => charts.map((c) => [...c.querySelectorAll('.grid text[text-anchor=middle]')]"
        ".map((t) => t.textContent).join(' '))"
    )
    assert len(ranges) == 4 and len(set(ranges)) == 1, ranges  # the confidence chart too
    shoot(page, "timeline-one-range")
