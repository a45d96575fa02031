"""A fresh home needs no command before the one a user meant: imports migrate and make the first
admin; a missing bucket is created by one command, which the error names."""

from __future__ import annotations

import uuid
from pathlib import Path

import cv2
import numpy as np

from tests.helpers import run_cli


def _masks_folder(root: Path) -> Path:
    """A two-frame dataset in the masks layout (what `weldpool export --format masks` writes)."""
    for sub in ("images", "masks"):
        (root / sub).mkdir(parents=True)
    for index in range(2):
        image = np.full((64, 96, 3), 40 + 60 * index, np.uint8)
        mask = np.zeros((64, 96), np.uint8)
        mask[20:44, 30:70] = 255
        cv2.imwrite(str(root / "images" / f"f{index}.png"), image)
        cv2.imwrite(str(root / "masks" / f"f{index}.png"), mask)
    return root


def test_import_labels_on_a_fresh_home_migrates_and_imports_as_the_first_admin(
    tmp_path: Path,
) -> None:
    home = tmp_path / "home"
    folder = _masks_folder(tmp_path / "labels")
    done = run_cli("import-labels", folder, "--format", "masks", env={"WELDPOOL_HOME": str(home)})
    assert done.returncode == 0, done.stderr
    assert "created user 'admin'" in done.stderr
    assert (home / "initial-admin-password").is_file()
    listed = run_cli("user", "list", env={"WELDPOOL_HOME": str(home)})
    assert "admin" in listed.stdout
    exported = tmp_path / "out.zip"
    again = run_cli("export", "--out", exported, env={"WELDPOOL_HOME": str(home)})
    assert again.returncode == 0, again.stderr
    assert exported.stat().st_size > 0


def test_train_without_a_dataset_names_the_command_that_makes_one(tmp_path: Path) -> None:
    done = run_cli("train", tmp_path / "nowhere", "--out", tmp_path / "m")
    assert done.returncode == 2
    assert "`weldpool export --format masks" in done.stderr


def test_a_missing_bucket_is_created_by_the_command_its_error_names(
    tmp_path: Path, s3_endpoint: str
) -> None:
    env = {
        "WELDPOOL_HOME": str(tmp_path / "home"),
        "WELDPOOL_STORAGE_URL": f"s3://fresh-{uuid.uuid4().hex[:12]}/lab",
        "WELDPOOL_S3_ENDPOINT_URL": s3_endpoint,
        "AWS_ACCESS_KEY_ID": "test",
        "AWS_SECRET_ACCESS_KEY": "test",
        "AWS_REGION": "us-east-1",
    }
    first = run_cli("demo", "--frames", "4", env=env)
    assert first.returncode == 2
    assert "`weldpool storage create-bucket`" in first.stderr
    created = run_cli("storage", "create-bucket", env=env)
    assert created.returncode == 0, created.stderr
    assert "created the bucket" in created.stderr
    assert "exists already" in run_cli("storage", "create-bucket", env=env).stderr
    filled = run_cli("demo", "--frames", "4", env=env)
    assert filled.returncode == 0, filled.stderr
