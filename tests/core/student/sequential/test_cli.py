"""`weldpool train-sequential` and `weldpool stream --sequential` from the command line."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np

from tests.helpers import run_cli, write_video
from weldpool_core.student.train import TrainResult


def test_train_sequential_and_stream_sequential_from_the_command_line(
    trained: TrainResult, tmp_path: Path
) -> None:
    root = Path(shutil.copytree(trained.model_dir, tmp_path / "model"))
    (tmp_path / "videos").mkdir()
    video = write_video(tmp_path / "videos" / "weld3.avi", 16)
    dataset = tmp_path / "dataset"
    (dataset / "images").mkdir(parents=True)
    (dataset / "masks").mkdir()
    capture = cv2.VideoCapture(str(video))
    for _ in range(16):
        ok, bgr = capture.read()
    capture.release()
    assert ok
    cv2.imwrite(str(dataset / "images" / "weld3_f0015.png"), bgr)
    pool = np.zeros(bgr.shape[:2], np.uint8)
    pool[20:44, 30:70] = 255
    cv2.imwrite(str(dataset / "masks" / "weld3_f0015.png"), pool)

    home = {"WELDPOOL_HOME": str(tmp_path / "home")}
    plain = run_cli("stream", str(video), "--model", str(root), "--sequential", env=home)
    assert plain.returncode != 0 and "has no sequential student" in plain.stderr
    trained_cell = run_cli(
        "train-sequential",
        str(root),
        str(dataset),
        "--videos",
        str(tmp_path / "videos"),
        "--steps",
        "3",
        "--device",
        "cpu",
        env=home,
    )
    assert trained_cell.returncode == 0, trained_cell.stderr
    assert json.loads(trained_cell.stdout)["windows"] == 2  # strides 1 and 2 both fit frame 15
    streamed = run_cli(
        "stream", str(video), "--model", str(root), "--sequential", "--max-frames", "4", env=home
    )
    assert streamed.returncode == 0, streamed.stderr
    records = [json.loads(line) for line in streamed.stdout.splitlines()]
    assert [r["frame"] for r in records] == [0, 1, 2, 3]
