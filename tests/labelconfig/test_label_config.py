"""The label configuration through the REST API, on SQLite and PostgreSQL: versions, its
checks, the conflicts; and the other classes' objects, tags and attributes on a label."""

from __future__ import annotations

import base64

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.core.models import Role
from tests.factories import frame_ids
from tests.helpers import auth, corrected_label, mask_b64
from weldpool_core.outline import rle_mask

LAB = {
    "classes": [
        {"name": "wire", "kind": "mask", "color": "#00aaff", "hotkey": "w"},
        {
            "name": "wire tip",
            "kind": "points",
            "hotkey": "t",
            "point_names": ["tip"],
        },
        {
            "name": "spatter",
            "kind": "instances",
            "color": "#ff0000",
            "hotkey": "x",
            "attributes": [
                {"name": "size", "type": "choice", "options": ["small", "large"]},
                {"name": "hot", "type": "flag"},
                {"name": "speed", "type": "number", "min": 0, "max": 10},
            ],
        },
    ],
    "frame_tags": ["arc unstable", "humping"],
    "frame_attributes": [{"name": "note", "type": "text"}],
}
W, H = 40, 30


@pytest.fixture
def people(make_user) -> dict[str, str]:
    return {"admin": make_user("ada", Role.admin)[1], "anna": make_user("anna")[1]}


def _put(client: TestClient, token: str, body: dict, version: int, **extra) -> object:
    return client.put(
        "/api/v1/label-config", json=body | {"version": version} | extra, headers=auth(token)
    )


def _frame(client: TestClient, token: str) -> int:
    _, data = cv2.imencode(".png", np.full((H, W, 3), 90, np.uint8))
    return frame_ids(client, token, [("f.png", data.tobytes())])[0]


def _pool() -> np.ndarray:
    mask = np.zeros((H, W), bool)
    mask[10:20, 10:25] = True
    return mask


def test_the_pool_alone_until_an_admin_saves_a_version(client: TestClient, people) -> None:
    first = client.get("/api/v1/label-config", headers=auth(people["anna"])).json()
    assert first["version"] == 0
    assert [(c["name"], c["kind"]) for c in first["classes"]] == [("pool", "mask")]
    refused = _put(client, people["anna"], LAB, 0)
    assert refused.status_code == 403
    saved = _put(client, people["admin"], LAB, 0)
    assert saved.status_code == 200, saved.text
    body = saved.json()
    assert body["version"] == 1 and body["updated_by"] == "ada"
    assert [c["name"] for c in body["classes"]] == ["pool", "wire", "wire tip", "spatter"]
    assert client.get("/api/v1/label-config", headers=auth(people["anna"])).json() == body
    stale = _put(client, people["admin"], {"classes": []}, 0)  # edited from version 0
    assert stale.status_code == 409 and stale.json()["version"] == 1
    assert "version 1" in stale.json()["detail"]
    again = _put(client, people["admin"], LAB | {"frame_tags": ["humping"]}, 1).json()
    assert again["version"] == 2 and again["frame_tags"] == ["humping"]


@pytest.mark.parametrize(
    ("change", "words"),
    [
        (
            {"classes": [{"name": "wire", "kind": "mask"}, {"name": "Wire", "kind": "mask"}]},
            "named",
        ),
        ({"classes": [{"name": "pool", "kind": "points"}]}, "'pool' keeps"),
        ({"classes": [{"name": "Pool", "kind": "mask"}]}, "'pool' keeps"),
        ({"classes": [{"name": "wire", "kind": "lines"}]}, "kind"),
        ({"classes": [{"name": "wire", "kind": "mask", "color": "blue"}]}, "color"),
        ({"classes": [{"name": "wire", "kind": "mask", "hotkey": "ww"}]}, "hotkey"),
        ({"classes": [{"name": "wire", "kind": "mask", "hotkey": "S"}]}, "review page's own"),
        ({"classes": [{"name": "wire", "kind": "mask", "hotkey": "["}]}, "review page's own"),
        (
            {
                "classes": [
                    {"name": "a", "kind": "mask", "hotkey": "x"},
                    {"name": "b", "kind": "mask", "hotkey": "x"},
                ]
            },
            "hotkeys",
        ),
        (
            {
                "classes": [
                    {"name": "a", "kind": "mask", "attributes": [{"name": "s", "type": "choice"}]}
                ]
            },
            "needs its options",
        ),
        (
            {
                "classes": [
                    {
                        "name": "a",
                        "kind": "mask",
                        "attributes": [{"name": "s", "type": "flag", "options": ["x"]}],
                    }
                ]
            },
            "only a choice",
        ),
        ({"classes": [{"name": " a", "kind": "mask"}]}, "name"),
        ({"frame_tags": ["x", "X"]}, "frame tags"),
        ({"classes": [{"name": "humping", "kind": "mask"}], "frame_tags": ["Humping"]}, "or frame"),
        ({"classes": [{"name": "Weld_Pool", "kind": "mask"}]}, "exports give the pool"),
        ({"frame_tags": ["frame_attributes"]}, "the frame's attributes"),
        ({"classes": [{"name": "a", "kind": "mask", "point_names": ["p"]}]}, "points class"),
    ],
)
def test_a_configuration_that_does_not_hold_is_refused(
    client: TestClient, people, change: dict, words: str
) -> None:
    response = _put(client, people["admin"], change, 0)
    assert response.status_code in (400, 422), response.text
    assert words in str(response.json()["detail"]), response.json()


def test_a_saved_hotkey_the_page_took_later_still_reads() -> None:
    """The review page's keys hold a new configuration only: one saved before still reads."""
    from app.labelconfig.schemas import LabelConfigIn, LabelConfigOut

    saved = {"classes": [{"name": "wire", "kind": "mask", "hotkey": "s"}], "version": 3}
    assert LabelConfigOut.model_validate(saved).classes[1].hotkey == "s"
    with pytest.raises(ValueError, match="review page's own shortcuts"):
        LabelConfigIn.model_validate(saved)


def test_the_review_keys_are_the_keys_the_review_page_handles() -> None:
    """``REVIEW_KEYS`` (the rule) and the page's handlers (``review.js``) name the same keys: a
    shortcut added to the page without the rule would let a class take it."""
    import re

    from app.labelconfig.schemas import REVIEW_KEYS
    from tests.helpers import REPO

    script = (REPO / "static" / "js" / "review" / "review.js").read_text()
    tools = re.search(r"TOOL_KEYS = \{([^}]*)\}", script)
    actions = re.search(r"const actions = \{(.*?)\n  \};", script, re.S)
    assert tools and actions
    handled = set(re.findall(r"(\d):", tools.group(1)))
    names = re.findall(r'^\s+"?([^\s"]+?)"?: ', actions.group(1), re.M)
    handled |= {name for name in names if len(name) == 1}
    handled.add(" ")  # held for panning
    assert handled == set(REVIEW_KEYS)


def test_objects_tags_and_attributes_are_stored_with_the_label(client: TestClient, people) -> None:
    admin, anna = people["admin"], people["anna"]
    assert _put(client, admin, LAB, 0).status_code == 200
    frame = _frame(client, anna)
    wire = np.zeros((H, W), bool)
    wire[0:5, :] = True
    objects = [
        {"class": "wire", "mask_png": mask_b64(wire)},
        {"class": "wire tip", "points": {"tip": [39.5, 4]}},
        {
            "class": "spatter",
            "polygons": [[[2, 25], [6, 25], [6, 28], [2, 28]]],
            "attributes": {"size": "small", "hot": True, "speed": 2.5},
        },
    ]
    body = corrected_label(_pool()) | {
        "objects": objects,
        "tags": ["humping"],
        "attributes": {"note": "drop at 3 s"},
    }
    saved = client.put(f"/api/v1/frames/{frame}/label", json=body, headers=auth(anna))
    assert saved.status_code == 200, saved.text
    label = client.get(f"/api/v1/frames/{frame}/label", headers=auth(anna)).json()
    assert [o["class"] for o in label["objects"]] == ["wire", "wire tip", "spatter"]
    assert np.array_equal(rle_mask(label["objects"][0]["rle"]), wire)
    assert label["objects"][0]["area"] == 5 * W and label["objects"][0]["bbox"] == [0, 0, W, 5]
    assert label["objects"][1]["points"] == {"tip": [39.5, 4.0]}
    spatter = label["objects"][2]
    assert spatter["area"] == 5 * 4 and spatter["bbox"] == [2, 25, 5, 4]  # vertices included
    assert spatter["attributes"] == {"size": "small", "hot": True, "speed": 2.5}
    assert label["tags"] == ["humping"] and label["attributes"] == {"note": "drop at 3 s"}
    pool = base64.b64decode(label["mask_png"])  # the pool's mask is as it was sent
    assert np.array_equal(cv2.imdecode(np.frombuffer(pool, np.uint8), 0) > 0, _pool())
    # a save that says nothing of them keeps them; an empty list removes the objects
    kept = corrected_label(_pool(), base_revision=1)
    assert (
        client.put(f"/api/v1/frames/{frame}/label", json=kept, headers=auth(anna)).json()["objects"]
        == label["objects"]
    )
    cleared = corrected_label(_pool(), base_revision=2) | {"objects": []}
    after = client.put(f"/api/v1/frames/{frame}/label", json=cleared, headers=auth(anna)).json()
    assert after["objects"] == [] and after["tags"] == ["humping"]
    history = client.get(f"/api/v1/frames/{frame}/label/history", headers=auth(anna)).json()
    assert [len(r["objects"]) for r in history] == [3, 3, 0]  # each revision its own
    assert history[0]["objects"] == label["objects"] and history[0]["tags"] == ["humping"]


@pytest.mark.parametrize(
    ("objects", "words"),
    [
        ([{"class": "droplet", "polygons": [[[1, 1], [3, 1], [3, 3]]]}], "no class 'droplet'"),
        ([{"class": "pool", "polygons": [[[1, 1], [3, 1], [3, 3]]]}], "not one of its objects"),
        ([{"class": "wire tip", "points": {"tip": [41, 3]}}], "outside the 40×30 frame"),
        ([{"class": "wire tip", "points": {"base": [1, 3]}}], "no point 'base'"),
        ([{"class": "wire", "rle": {"size": [3, 3], "counts": "9"}}], "size"),
        ([{"class": "wire"}], "one of rle, mask_png or polygons"),
        (
            [
                {
                    "class": "spatter",
                    "polygons": [[[1, 1], [3, 1], [3, 3]]],
                    "attributes": {"size": "huge"},
                }
            ],
            "'small', 'large'",
        ),
        (
            [
                {
                    "class": "spatter",
                    "polygons": [[[1, 1], [3, 1], [3, 3]]],
                    "attributes": {"speed": 11},
                }
            ],
            "from 0 to 10",
        ),
        (
            [{"class": "spatter", "polygons": [[[1, 1], [3, 1], [3, 3]]], "attributes": {"x": 1}}],
            "no attribute 'x'",
        ),
        ([{"class": "wire tip", "points": {"tip": [True, 3]}}], "is not [x, y]"),
        ([{"class": "wire", "rle": {"size": 5, "counts": "x"}}], "compressed"),
        (
            [
                {
                    "class": "spatter",
                    "polygons": [[[1, 1], [3, 1], [3, 3]]],
                    "attributes": {"speed": 10**400},
                }
            ],
            "from 0 to 10",
        ),
        (
            [{"class": "spatter", "polygons": [[[1, 1], [3, 1], [3, 3]]], "attributes": "x"}],
            "not an object",
        ),
    ],
)
def test_objects_the_configuration_does_not_allow_are_refused(
    client: TestClient, people, objects: list, words: str
) -> None:
    assert _put(client, people["admin"], LAB, 0).status_code == 200
    frame = _frame(client, people["anna"])
    body = corrected_label(_pool()) | {"objects": objects}
    response = client.put(f"/api/v1/frames/{frame}/label", json=body, headers=auth(people["anna"]))
    assert response.status_code == 400, response.text
    assert words in response.json()["detail"]
    assert (
        client.get(f"/api/v1/frames/{frame}/label", headers=auth(people["anna"])).status_code == 404
    )


def test_an_unknown_tag_is_refused(client: TestClient, people) -> None:
    frame = _frame(client, people["anna"])
    body = corrected_label(_pool()) | {"tags": ["humping"]}
    response = client.put(f"/api/v1/frames/{frame}/label", json=body, headers=auth(people["anna"]))
    assert response.status_code == 400 and "no frame tag 'humping'" in response.json()["detail"]


def test_removing_a_class_labels_hold_is_a_conflict_unless_forced(
    client: TestClient, people
) -> None:
    admin, anna = people["admin"], people["anna"]
    _put(client, admin, LAB, 0)
    frame = _frame(client, anna)
    body = corrected_label(_pool()) | {
        "objects": [{"class": "wire tip", "points": {"tip": [1, 1]}}]
    }
    assert (
        client.put(f"/api/v1/frames/{frame}/label", json=body, headers=auth(anna)).status_code
        == 200
    )
    without = {"classes": [c for c in LAB["classes"] if c["name"] != "wire tip"]}
    refused = _put(client, admin, without, 1)
    assert refused.status_code == 409
    assert refused.json()["detail"].startswith("1 label(s) hold objects of the class 'wire tip'")
    retyped = {
        "classes": [
            c | {"kind": "mask", "point_names": None} if c["name"] == "wire tip" else c
            for c in LAB["classes"]
        ]
    }
    assert _put(client, admin, retyped, 1).status_code == 409  # a changed kind orphans them too
    removed_unused = {"classes": [c for c in LAB["classes"] if c["name"] != "wire"]}
    assert _put(client, admin, removed_unused, 1).status_code == 200  # nobody drew a wire
    forced = _put(client, admin, without, 2, force=True)
    assert forced.status_code == 200 and forced.json()["version"] == 3
    label = client.get(f"/api/v1/frames/{frame}/label", headers=auth(anna)).json()
    assert label["objects"] == [{"class": "wire tip", "points": {"tip": [1.0, 1.0]}}]  # kept


def test_two_admins_saving_one_version_at_once_one_wins(
    client: TestClient, people, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The second of two saves that both read version 0 meets the first's row (the version is
    the key): a 409 naming version 1, and nothing of the second is kept."""
    from app.labelconfig import service

    assert _put(client, people["admin"], LAB, 0).status_code == 200
    real, calls = service.current, []

    def read_before_the_other_saved(session):  # type: ignore[no-untyped-def]
        calls.append(1)
        return service.Current(0, service.builtin()) if len(calls) == 1 else real(session)

    monkeypatch.setattr(service, "current", read_before_the_other_saved)
    late = _put(client, people["admin"], {"classes": [{"name": "bead", "kind": "mask"}]}, 0)
    assert late.status_code == 409 and late.json()["version"] == 1, late.text
    monkeypatch.undo()
    now = client.get("/api/v1/label-config", headers=auth(people["anna"])).json()
    assert now["version"] == 1 and "bead" not in [c["name"] for c in now["classes"]]


def test_an_import_keeps_the_attributes_a_class_allows() -> None:
    from app.labelconfig.service import valid_attributes

    spatter = LAB["classes"][2]
    given = {"size": "small", "hot": "yes", "speed": 20, "colour": "red"}
    assert valid_attributes(spatter, given) == {"size": "small"}
    assert valid_attributes(spatter, {"hot": True, "speed": 9.5}) == {"hot": True, "speed": 9.5}
