"""Export from one instance, import into a fresh one: the same masks (pixel for pixel where
the format holds masks, IoU ≥ 0.97 through YOLO's polygons), keypoints and process parameters.
The importing instance runs on SQLite and on the real PostgreSQL."""

from __future__ import annotations

import io
import zipfile
from pathlib import Path

import pytest
from scipy.ndimage import binary_fill_holes

from app.core.models import Role
from tests.helpers import auth, run_cli
from tests.imports.common import (
    PROCESS,
    export_labels,
    iou,
    label_mask,
    same_points,
    start_import,
    stored_labels,
)

FORMATS = ["coco", "masks", "cvat", "yolo", "labelme"]


@pytest.fixture(scope="module")
def exported(tmp_path_factory: pytest.TempPathFactory):
    return export_labels(tmp_path_factory.mktemp("source"), FORMATS)


@pytest.mark.parametrize("fmt", FORMATS)
def test_an_export_imported_into_a_fresh_instance_gives_back_its_labels(
    fmt: str, exported, client, make_user
) -> None:
    _, token = make_user("importer", Role.reviewer)
    job = start_import(client, token, exported.archive[fmt], fmt)
    result = job["result"]
    assert result["refused"] == [] and result["skipped"] == []
    assert result["frames"] == 3 and result["labels"] == 3
    with_keypoints = fmt in ("coco", "masks", "cvat", "labelme")
    assert result["keypoints"] == (1 if with_keypoints else 0)

    found = {
        frame["original_name"]: (frame, label) for frame, label in stored_labels(client, token)
    }
    if fmt in ("coco", "masks"):  # formats that carry the frame's own name
        assert set(found) == set(exported.names)
    assert len(found) == 3
    by_image = {}
    for frame, label in found.values():
        image = client.get(f"/api/v1/frames/{frame['id']}/image", headers=auth(token)).content
        name = next(n for n, data in exported.images.items() if data == image)  # same bytes
        by_image[name] = (frame, label)
    for name, (frame, label) in by_image.items():
        assert label is not None and label["status"] == "corrected"
        assert label["updated_by"] == "importer"
        assert label["source"]["kind"] == "imported" and label["source"]["format"] == fmt
        mask = label_mask(label)
        if fmt == "yolo":  # polygons without holes: the outline of each region
            assert iou(mask, binary_fill_holes(exported.masks[name])) >= 0.97
        else:
            assert (mask == exported.masks[name]).all(), name  # holes and all
        if with_keypoints:
            assert same_points(label["keypoints"], exported.keypoints[name])
        history = client.get(
            f"/api/v1/frames/{frame['id']}/label/history", headers=auth(token)
        ).json()
        assert [h["source"]["format"] for h in history] == [fmt]
    if with_keypoints:
        manual_name = next(iter(exported.validation))
        frame = by_image[manual_name][0]
        manual = client.get(
            f"/api/v1/frames/{frame['id']}/validation-keypoints", headers=auth(token)
        ).json()
        assert same_points(manual["keypoints"], exported.validation[manual_name])
        detail = client.get(f"/api/v1/frames/{frame['id']}", headers=auth(token)).json()
        assert detail["split"] == "validation"
    if fmt in ("coco", "masks"):  # formats that carry the run and its process parameters
        runs = client.get("/api/v1/sequences", headers=auth(token)).json()
        run = next(r for r in runs if r["name"] == "run-a")
        assert {k: run[k] for k in PROCESS} == PROCESS

    # Again: every frame is there with its label; nothing new, each listed as skipped.
    again = start_import(client, token, exported.archive[fmt], fmt)["result"]
    assert again["frames"] == 0 and again["labels"] == 0 and again["skipped_count"] == 3
    assert again["keypoints"] == 0  # a frame's validation keypoints stay too
    assert all("already has a label (revision 1)" in s["reason"] for s in again["skipped"])
    # Asked to overwrite: a second revision each, the first kept in the history.
    over = start_import(client, token, exported.archive[fmt], fmt, overwrite=True)["result"]
    assert over["labels"] == 3 and over["skipped"] == []
    frame = next(iter(by_image.values()))[0]
    history = client.get(f"/api/v1/frames/{frame['id']}/label/history", headers=auth(token))
    assert sorted(h["revision"] for h in history.json()) == [1, 2]


def test_the_command_line_imports_a_folder(exported, tmp_path: Path) -> None:
    folder = tmp_path / "dataset"
    with zipfile.ZipFile(io.BytesIO(exported.archive["masks"])) as archive:
        archive.extractall(folder)
    env = {"WELDPOOL_HOME": str(tmp_path / "home")}
    assert run_cli("migrate", env=env).returncode == 0
    added = run_cli(
        "user",
        "add",
        "admin",
        "--role",
        "admin",
        "--password-stdin",
        env=env,
        stdin="correct horse\n",
    )
    assert added.returncode == 0, added.stderr
    done = run_cli("import-labels", folder, "--format", "masks", "--sequence", "cli-run", env=env)
    assert done.returncode == 0, done.stderr
    assert "3 labels and 1 keypoint sets imported, 3 new frames" in done.stderr
    again = run_cli("import-labels", folder, "--format", "masks", env=env)
    assert again.returncode == 0, again.stderr
    assert "0 labels" in again.stderr and "3 skipped" in again.stderr
    wrong = run_cli("import-labels", folder / "masks", "--format", "coco", env=env)
    assert wrong.returncode == 2 and "No COCO annotation file" in wrong.stderr


def test_the_command_line_names_the_formats_when_one_is_unknown(tmp_path: Path) -> None:
    env = {"WELDPOOL_HOME": str(tmp_path / "home")}
    assert run_cli("migrate", env=env).returncode == 0
    done = run_cli("import-labels", tmp_path, "--format", "pascal", env=env)
    assert done.returncode == 2
    assert "There is no label format 'pascal'; use one of coco, yolo, masks, labelme, cvat." in (
        done.stderr
    )


def test_a_large_imports_label_work_in_processes_gives_the_same_labels(
    exported, client, make_user, monkeypatch: pytest.MonkeyPatch
) -> None:
    """From ``PROCESS_MIN`` labels the work (rasterise, encode, Algorithm 1) runs in processes
    and comes back in order: the masks, keypoints and validation keypoints are the ones the
    threads give, frame by frame."""
    from app.core import processes
    from app.imports import pool, service

    monkeypatch.setattr(service, "PROCESS_MIN", 1)
    monkeypatch.setattr(pool, "PROCESS_CHUNK", 2)  # three labels: two tasks
    _, token = make_user("importer", Role.reviewer)
    result = start_import(client, token, exported.archive["coco"], "coco")["result"]
    assert result["labels"] == 3 and result["keypoints"] == 1 and result["refused"] == []
    assert processes.started()  # the processes did the work
    for frame, label in stored_labels(client, token):
        name = frame["original_name"]
        assert label is not None and (label_mask(label) == exported.masks[name]).all(), name
        assert same_points(label["keypoints"], exported.keypoints[name])
