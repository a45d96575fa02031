"""Bounded work per request: coordinates and counts in a body are checked against the frame
and documented caps, so the work follows the frame's size; a bad value is a one-sentence 4xx."""

from __future__ import annotations

import base64

import cv2
import numpy as np
from fastapi.testclient import TestClient

from app.core.models import Role
from tests.factories import frame_ids, synthetic_images
from tests.helpers import auth
from weldpool_core.io import decode_mask_png

WIDTH, HEIGHT = 160, 100
FRAME = synthetic_images([("f.png", 0)], width=WIDTH, height=HEIGHT)  # one synthetic frame
MAX_VERTICES = 10_000  # weldpool_core.outline.MAX_VERTICES, the documented cap


def _fill(client: TestClient, token: str, frame_id: int, polygons: list[dict]):  # type: ignore[no-untyped-def]
    return client.post(
        f"/api/v1/frames/{frame_id}/outline/mask", json={"polygons": polygons}, headers=auth(token)
    )


def test_an_outline_far_outside_the_frame_is_refused_in_one_sentence(
    client: TestClient, make_user
) -> None:
    """The attack that took 82 s of CPU (the fill walked every row from y = −3e9) and gave area
    0: eight triangles at ±3e9 are refused, naming the vertex and the frame."""
    token = make_user("anna", Role.annotator)[1]
    (frame_id,) = frame_ids(
        client, token, synthetic_images([("f.png", 0)], width=WIDTH, height=HEIGHT)
    )
    attack = [{"points": [[0, -3e9], [WIDTH, 3e9], [WIDTH / 2, HEIGHT / 2]]} for _ in range(8)]
    refused = _fill(client, token, frame_id, attack)
    assert refused.status_code == 400
    assert refused.json()["detail"] == (
        "The vertex (0, -3e+09) lies more than one frame width or height outside the 160×100 "
        "frame; keep the outline on the frame."
    )
    just_beyond = [{"points": [[0, 0], [3 * WIDTH + 1, 0], [0, HEIGHT]]}]
    assert _fill(client, token, frame_id, just_beyond).status_code == 400


def test_an_outline_within_one_frame_size_is_clipped_to_the_frame(
    client: TestClient, make_user
) -> None:
    """Vertices up to one frame width or height outside are kept and clipped by the fill: two
    triangles between the far corners of that margin cover the whole frame."""
    token = make_user("anna", Role.annotator)[1]
    (frame_id,) = frame_ids(
        client, token, synthetic_images([("f.png", 0)], width=WIDTH, height=HEIGHT)
    )
    corners = [
        [-WIDTH, -HEIGHT],
        [2 * WIDTH, -HEIGHT],
        [-WIDTH, 2 * HEIGHT],
        [2 * WIDTH, 2 * HEIGHT],
    ]
    cover = _fill(
        client,
        token,
        frame_id,
        [{"points": corners[:2] + corners[3:]}, {"points": corners[:1] + corners[2:]}],
    )
    assert cover.status_code == 200, cover.text
    assert cover.json()["area"] == WIDTH * HEIGHT
    mask = decode_mask_png(base64.b64decode(cover.json()["mask_png"]))
    assert mask.shape == (HEIGHT, WIDTH) and mask.all()


def test_an_outline_has_at_most_10_000_vertices_in_all(client: TestClient, make_user) -> None:
    token = make_user("anna", Role.annotator)[1]
    (frame_id,) = frame_ids(
        client, token, synthetic_images([("f.png", 0)], width=WIDTH, height=HEIGHT)
    )

    def squares(count: int) -> list[dict]:
        """``count`` vertices as 1-px squares along the frame's rows (4 each, the rest in a
        triangle), none crossing another."""
        polygons = []
        for index in range(count // 4):
            x, y = 2 * (index % 75), 2 * (index // 75 % 45)
            polygons.append({"points": [[x, y], [x + 1, y], [x + 1, y + 1], [x, y + 1]]})
        polygons.append({"points": [[150, 95], [155, 95], [150, 99]] + [[151, 97]] * (count % 4)})
        return polygons

    at_cap = _fill(client, token, frame_id, squares(MAX_VERTICES - 3))
    assert at_cap.status_code == 200, at_cap.text
    over = _fill(client, token, frame_id, squares(MAX_VERTICES - 2))
    assert over.status_code == 422
    assert over.json()["detail"] == (
        f"The request: an outline has at most {MAX_VERTICES:,} vertices in all."
    )
    one_polygon = [{"points": [[x % WIDTH, x // WIDTH % HEIGHT] for x in range(MAX_VERTICES + 1)]}]
    assert _fill(client, token, frame_id, one_polygon).status_code == 422


def test_a_mask_that_traces_beyond_an_outline_s_cap_is_a_400_naming_the_tolerance(
    client: TestClient, make_user
) -> None:
    """The outline of a checkerboard mask (one region, 7,742 one-pixel holes) has more than an
    edited outline may, so the trace is refused (it was a 500), not sent only to be refused on
    the way back; a pool's outline is traced as before."""
    token = make_user("anna", Role.annotator)[1]
    (frame_id,) = frame_ids(
        client, token, synthetic_images([("f.png", 0)], width=WIDTH, height=HEIGHT)
    )

    def trace(mask: np.ndarray) -> object:
        png = base64.b64encode(cv2.imencode(".png", mask.astype(np.uint8) * 255)[1]).decode()
        return client.post(
            f"/api/v1/frames/{frame_id}/outline",
            json={"mask_png": png, "tolerance": 0},
            headers=auth(token),
        )

    checkerboard = np.indices((HEIGHT, WIDTH)).sum(axis=0) % 2 == 0
    refused = trace(checkerboard)
    assert refused.status_code == 400
    assert refused.json()["detail"] == (
        "The mask traces to 31,482 vertices in 7,743 polygons at tolerance 0, more than an "
        f"outline may have ({MAX_VERTICES:,} vertices, 3,333 polygons); raise the tolerance or "
        "edit the mask with the brush."
    )
    pool = np.zeros((HEIGHT, WIDTH), bool)
    pool[20:80, 30:130] = True
    traced = trace(pool)
    assert traced.status_code == 200 and len(traced.json()["polygons"]) == 1


def test_a_segment_box_outside_the_frame_is_refused(client: TestClient, make_user) -> None:
    """A box is checked against the frame like a click, before SAM2 sees it."""
    token = make_user("rita", Role.reviewer)[1]
    (frame_id,) = frame_ids(
        client, token, synthetic_images([("f.png", 0)], width=WIDTH, height=HEIGHT)
    )
    for box, corner in (
        ([0, 0, 3e9, 3e9], "(3e+09, 3e+09)"),
        ([-3e9, 10, 50, 60], "(-3e+09, 10)"),
        ([10, 10, 50, HEIGHT + 1], f"(50, {HEIGHT + 1})"),
    ):
        refused = client.post(
            f"/api/v1/frames/{frame_id}/segment", json={"box": box}, headers=auth(token)
        )
        assert refused.status_code == 400, refused.text
        assert refused.json()["detail"] == (
            f"The box corner {corner} lies outside the {WIDTH}×{HEIGHT} frame."
        )
    edges = client.post(
        f"/api/v1/frames/{frame_id}/segment",
        json={"box": [0, 0, WIDTH, HEIGHT]},
        headers=auth(token),
    )
    assert edges.status_code == 200, edges.text
    assert decode_mask_png(base64.b64decode(edges.json()["mask_png"])).shape == (HEIGHT, WIDTH)
    assert np.isfinite(edges.json()["score"])
