"""The label configuration's other classes in training and at the gate (``app.training.classes``):
which classes a version learns, their labels as the student's truths, the gate's figures per
class, and that a class never decides a promotion."""

from __future__ import annotations

import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient
from safetensors.torch import load_file, save_file

from app.core.models import ModelVersion, Proposal, Role
from app.proposals.files import store_mask
from app.storage import LocalStorage
from app.training import classes, gate
from tests.core.student.common import TINY_STUDENT, synthetic_frames, tiny_config
from tests.factories import frame_ids, numbered, random_images
from tests.helpers import auth, corrected_label, mask_b64, wait_for_job
from tests.proposals.common import H, W
from weldpool_core.student.checkpoint import read_student_config
from weldpool_core.student.classes import LearnedClass
from weldpool_core.student.train import train_student

LAB = {
    "classes": [
        {"name": "wire", "kind": "mask"},
        {"name": "wire tip", "kind": "points", "point_names": ["tip"]},
        {"name": "spatter", "kind": "instances"},
    ]
}
LEARNED = (LearnedClass("wire", "mask"), LearnedClass("wire tip", "points", ("tip",)))


def _wire() -> np.ndarray:
    wire = np.zeros((H, W), bool)
    wire[0:10, 60:96] = True
    return wire


def _pool() -> np.ndarray:
    mask = np.ones((H, W), bool)
    mask[:2], mask[-2:], mask[:, :2], mask[:, -2:] = False, False, False, False
    return mask


def _labelled_frames(client: TestClient, token: str, admin: str, count: int, spatter: int) -> list:
    """``count`` frames whose labels hold the pool, the wire and its tip, the first ``spatter``
    of them two spatter instances; the teacher proposed a shrunk pool for each."""
    put = client.put("/api/v1/label-config", json=LAB | {"version": 0}, headers=auth(admin))
    assert put.status_code == 200, put.text
    images = random_images(numbered(count, first_seed=700), width=W, height=H)
    ids = frame_ids(client, token, images)
    for index, frame_id in enumerate(ids):
        objects = [
            {"class": "wire", "mask_png": mask_b64(_wire())},
            {"class": "wire tip", "points": {"tip": [60.0, 9.0]}},
        ]
        if index < spatter:
            objects += [
                {"class": "spatter", "polygons": [[[2, 40], [8, 40], [8, 46], [2, 46]]]},
                {"class": "spatter", "polygons": [[[20, 50], [26, 50], [26, 56], [20, 56]]]},
            ]
        body = corrected_label(_pool()) | {"objects": objects}
        saved = client.put(f"/api/v1/frames/{frame_id}/label", json=body, headers=auth(token))
        assert saved.status_code == 200, saved.text
    return ids


def test_classes_with_enough_labels_are_learned_with_their_labels_as_truths(
    client: TestClient, session_factory, make_user
) -> None:
    _, admin = make_user("admin", Role.admin)
    _, token = make_user("labeller", Role.reviewer)
    ids = _labelled_frames(client, token, admin, 3, spatter=2)
    with session_factory() as session:
        learned = classes.learned_classes(session, ids, 2)
        assert learned == (*LEARNED, LearnedClass("spatter", "instances"))
        assert classes.learned_classes(session, ids, 3) == LEARNED  # spatter on 2 frames only
        assert classes.learned_classes(session, ids, 0) == ()  # the setting's off switch
        # Counted with the held-out frames, which measure it; one label at least trains it.
        assert classes.learned_classes(session, ids, 3, training=ids[:1]) == LEARNED
        assert classes.learned_classes(session, ids, 2, training=ids[2:]) == LEARNED  # spatter
        truths = classes.class_truths(session, ids, learned)
    first = truths[ids[0]]
    assert np.array_equal(first["wire"].mask, _wire())
    assert first["wire tip"].points == {"tip": (60.0, 9.0)}
    assert first["spatter"].mask.sum() == 2 * 7 * 7  # the instances' union (vertices included)
    assert "spatter" not in truths[ids[2]]
    # Spatter made a points class with force: its stored regions are retired, no labels of it.
    spatter = {"name": "spatter", "kind": "points", "point_names": ["p"]}
    changed = {"classes": [*LAB["classes"][:2], spatter], "version": 1, "force": True}
    assert client.put("/api/v1/label-config", json=changed, headers=auth(admin)).is_success
    with session_factory() as session:
        assert classes.learned_classes(session, ids, 2) == LEARNED


@pytest.fixture(scope="module")
def class_model(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A student that learns the wire and its tip (its heads are set on purpose below)."""
    out = tmp_path_factory.mktemp("gate-classes") / "model"
    student = replace(TINY_STUDENT, keypoints="heatmap", classes=LEARNED)
    train_student(synthetic_frames(4), out, student, tiny_config(epochs=1))
    return out


def test_the_held_out_frames_count_towards_a_class(
    client: TestClient, session_factory, settings, make_user
) -> None:
    """Three labelled frames, two trained on and one held out: with three labels needed the
    classes are learned (ten labelled frames of a lab, two held out, learn theirs)."""
    _, admin = make_user("admin4", Role.admin)
    _, token = make_user("labeller4", Role.reviewer)
    ids = _labelled_frames(client, token, admin, 3, spatter=0)
    settings.student_class_min_labels = 3
    image = np.zeros((H, W), np.uint8)
    samples = [(frame_id, (image, _pool(), None)) for frame_id in ids]
    with session_factory() as session:
        student, training, held = classes.with_classes(
            session, settings, TINY_STUDENT, samples[:2], samples[2:]
        )
    assert student.classes == LEARNED
    assert [frame.classes["wire tip"].points for _, frame in training] == [{"tip": (60.0, 9.0)}] * 2
    assert np.array_equal(held[0].classes["wire"].mask, _wire())


def _version(
    settings, session_factory, base: Path, name: str, pool: float, wire: float, learned=None
) -> int:
    """A copy of ``base`` whose pool head draws (+30) or not (−30) the whole frame, finds no
    keypoint, and whose class head draws the wire everywhere (+30) or nowhere (−30); recorded
    as having learned ``learned`` (default: what it was trained with)."""
    folder = Path(settings.home) / "models" / name
    shutil.copytree(base, folder)
    weights = load_file(str(folder / "model.safetensors"))
    weights["decoder.head.bias"][0], weights["decoder.head.bias"][1] = pool, -30.0
    weights["decoder.class_head.2.bias"][:] = wire
    save_file(weights, str(folder / "model.safetensors"))
    student = read_student_config(folder)
    student = student if learned is None else replace(student, classes=learned)
    with session_factory() as session:
        version = ModelVersion(
            name=name,
            checkpoint_path=f"models/{name}",
            config={"student": student.as_dict()},
            train_frame_ids=[],
        )
        session.add(version)
        session.commit()
        return version.id


def _measure(settings, session_factory, candidate: int, incumbent: int) -> dict:
    with session_factory() as session:
        return gate.measure(
            session,
            LocalStorage(settings.home),
            session.get_one(ModelVersion, candidate),
            session.get_one(ModelVersion, incumbent),
            "cpu",
        )


def test_the_gate_reports_each_class_and_a_terrible_class_does_not_stop_a_better_pool(
    client: TestClient, settings, session_factory, make_user, class_model: Path
) -> None:
    _, admin = make_user("admin2", Role.admin)
    _, token = make_user("gatekeeper", Role.reviewer)
    ids = _labelled_frames(client, token, admin, 3, spatter=0)
    with session_factory() as session:
        for frame_id in ids:
            mask = np.zeros((H, W), bool)
            mask[8:56, 10:86] = True  # the teacher's pool: IoU 0.66
            path = store_mask(LocalStorage(settings.home), mask)
            session.add(Proposal(frame_id=frame_id, source="teacher", model_id="t", mask_path=path))
        from app.core.models import Frame, Split

        for frame_id in ids:
            session.get_one(Frame, frame_id).split = Split.validation
        session.commit()
    incumbent = _version(settings, session_factory, class_model, "no-pool", -30.0, 30.0)
    terrible = _version(settings, session_factory, class_model, "no-wire", 30.0, -30.0)
    everywhere = _version(settings, session_factory, class_model, "all-wire", 30.0, 30.0)

    bad = _measure(settings, session_factory, terrible, incumbent)
    good = _measure(settings, session_factory, everywhere, incumbent)
    assert bad["promote"] and good["promote"], (bad["reason"], good["reason"])
    assert bad["candidate"] == good["candidate"] and bad["reason"] == good["reason"]
    # the figures per class, on the 3 held-out frames that label them, computed by hand
    assert bad["classes"]["wire"] == {"kind": "mask", "frames": 3, "IoU": 0.0}
    assert good["classes"]["wire"]["IoU"] == pytest.approx(_wire().sum() / (W * H))
    tip = bad["classes"]["wire tip"]
    assert tip["frames"] == 3 and tip["missed"] == 3
    assert tip["distance_px"] == pytest.approx(np.hypot(W, H))  # not found: the diagonal
    models = {m["name"]: m for m in client.get("/api/v1/models", headers=auth(token)).json()}
    assert models["no-wire"]["config"]["student"]["classes"][1]["points"] == ["tip"]


def _validation_frames(client, settings, session_factory, token: str, admin: str) -> None:
    """Three labelled frames of the validation split, with a shrunk teacher pool on each."""
    from app.core.models import Frame, Split

    ids = _labelled_frames(client, token, admin, 3, spatter=0)
    with session_factory() as session:
        for frame_id in ids:
            mask = np.zeros((H, W), bool)
            mask[8:56, 10:86] = True  # the teacher's pool: IoU 0.66
            path = store_mask(LocalStorage(settings.home), mask)
            session.add(Proposal(frame_id=frame_id, source="teacher", model_id="t", mask_path=path))
            session.get_one(Frame, frame_id).split = Split.validation
        session.commit()


def test_the_gate_sets_the_incumbents_class_figures_beside_the_candidates(
    client: TestClient, settings, session_factory, make_user, class_model: Path
) -> None:
    _, admin = make_user("admin4", Role.admin)
    _, token = make_user("comparer", Role.reviewer)
    _validation_frames(client, settings, session_factory, token, admin)
    everywhere = _version(settings, session_factory, class_model, "wire-all", 30.0, 30.0)
    nowhere = _version(settings, session_factory, class_model, "wire-none", 30.0, -30.0)
    wire_only = (LearnedClass("wire", "mask"),)
    partial = _version(settings, session_factory, class_model, "wire-only", 30.0, 30.0, wire_only)
    plain = _version(settings, session_factory, class_model, "pool-only", 30.0, 30.0, ())
    all_wire = pytest.approx(_wire().sum() / (W * H))

    good = _measure(settings, session_factory, everywhere, nowhere)
    assert good["classes"]["wire"]["IoU"] == all_wire
    assert good["incumbent_classes"]["wire"] == {"kind": "mask", "frames": 3, "IoU": 0.0}
    bad = _measure(settings, session_factory, nowhere, everywhere)  # the columns swap
    assert bad["classes"]["wire"]["IoU"] == 0.0
    assert bad["incumbent_classes"]["wire"]["IoU"] == all_wire
    assert bad["incumbent_classes"]["wire tip"]["missed"] == 0  # its tip heatmap peaks
    assert good["incumbent_classes"]["wire tip"]["missed"] == 3
    # the pool's rule is the same with or without the incumbent's classes measured
    assert good["promote"] is bad["promote"] and good["incumbent_scores"] == bad["incumbent_scores"]
    # an incumbent that did not learn a class (with the same points) has no figure for it
    lacking = _measure(settings, session_factory, nowhere, partial)
    assert lacking["incumbent_classes"]["wire"]["IoU"] == all_wire
    assert lacking["incumbent_classes"]["wire tip"] is None
    none = _measure(settings, session_factory, everywhere, plain)
    assert none["incumbent_classes"] == {"wire": None, "wire tip": None}
    assert none["classes"] == good["classes"] and "incumbent_scores" in none


@pytest.mark.slow
def test_a_training_job_learns_the_classes_its_labels_hold_and_records_them(
    client: TestClient, settings, make_user
) -> None:
    _, admin = make_user("admin3", Role.admin)
    _, token = make_user("trainer", Role.reviewer)
    settings.student_class_min_labels = 2
    _labelled_frames(client, token, admin, 4, spatter=1)
    job = client.post(
        "/api/v1/student/train", json={"epochs": 1, "size": "light"}, headers=auth(token)
    ).json()
    done = wait_for_job(client, job["job_id"], token, timeout=300)
    assert done["status"] == "succeeded", done["error"]
    (model,) = client.get("/api/v1/models", headers=auth(token)).json()
    learned = [c["name"] for c in model["config"]["student"]["classes"]]
    assert learned == ["wire", "wire tip"]  # spatter: 1 label of the 2 needed
    assert set(model["metrics"]["classes"]) == {"wire", "wire tip"}
    assert set(model["gate"]["classes"]) == {"wire", "wire tip"}
