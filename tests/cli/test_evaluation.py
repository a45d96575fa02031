"""`weldpool heatmap` and `weldpool eval segmentation|keypoints`, through the real command."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest

from tests.helpers import run_cli
from weldpool_core.heatmap import HeatmapParams, heatmap_from_mask
from weldpool_core.io import encode_mask_png, read_mask
from weldpool_core.synth import SynthParams, synth_frame

SMALL = SynthParams(width=160, height=100)


def run(tmp_path: Path, *args: str | Path) -> subprocess.CompletedProcess[str]:
    return run_cli(*args, env={"WELDPOOL_HOME": str(tmp_path / "home")})


def _one_line_error(result: subprocess.CompletedProcess[str], text: str) -> None:
    assert result.returncode == 2
    assert result.stderr.count("\n") == 1 and result.stderr.startswith("weldpool: ")
    assert text in result.stderr and "Traceback" not in result.stderr


@pytest.fixture
def dataset(tmp_path: Path) -> Path:
    """A DATASET folder with three synthetic masks."""
    masks = tmp_path / "dataset" / "masks"
    masks.mkdir(parents=True)
    for seed in range(3):
        (masks / f"frame{seed}.png").write_bytes(encode_mask_png(synth_frame(seed, SMALL).mask))
    return tmp_path / "dataset"


def test_heatmap_writes_npy_and_json_per_mask(tmp_path: Path, dataset: Path) -> None:
    result = run(tmp_path, "heatmap", dataset / "masks", "--out", tmp_path / "out")
    assert result.returncode == 0, result.stderr
    for seed in range(3):
        mask = read_mask(dataset / "masks" / f"frame{seed}.png")
        expected = heatmap_from_mask(mask)
        heatmap = np.load(tmp_path / "out" / f"frame{seed}_heatmap.npy")
        assert heatmap.shape == (100, 160, 2) and heatmap.dtype == np.float32
        assert np.array_equal(heatmap, expected.heatmap)
        record = json.loads((tmp_path / "out" / f"frame{seed}.json").read_text())
        assert np.allclose(record["keypoints"], expected.keypoints)
        assert record["rules"] == list(expected.rules)


def test_heatmap_takes_files_k_and_strips_mask_suffix(tmp_path: Path, dataset: Path) -> None:
    teacher_mask = tmp_path / "run7_mask.png"
    teacher_mask.write_bytes((dataset / "masks" / "frame1.png").read_bytes())
    result = run(tmp_path, "heatmap", teacher_mask, "--out", tmp_path / "out", "--k", "6")
    assert result.returncode == 0, result.stderr
    record = json.loads((tmp_path / "out" / "run7.json").read_text())
    expected = heatmap_from_mask(read_mask(teacher_mask), HeatmapParams(k=6))
    assert np.allclose(record["keypoints"], expected.keypoints) and len(record["keypoints"]) == 6
    assert (tmp_path / "out" / "run7_heatmap.npy").is_file()


def test_heatmap_bad_input_is_one_line(tmp_path: Path) -> None:
    _one_line_error(
        run(tmp_path, "heatmap", tmp_path / "nope", "--out", tmp_path / "o"), "does not exist"
    )
    text = tmp_path / "notes.png"
    text.write_text("not an image")
    _one_line_error(run(tmp_path, "heatmap", text, "--out", tmp_path / "o"), "notes.png")
    empty = tmp_path / "empty.png"
    empty.write_bytes(encode_mask_png(np.zeros((40, 40), bool)))
    _one_line_error(run(tmp_path, "heatmap", empty, "--out", tmp_path / "o"), "empty")
    folder = tmp_path / "nothing"
    folder.mkdir()
    _one_line_error(run(tmp_path, "heatmap", folder, "--out", tmp_path / "o"), "no PNG mask")
    _one_line_error(run(tmp_path, "heatmap", empty, "--out", tmp_path / "o", "--k", "0"), "k must")


def test_eval_segmentation(tmp_path: Path, dataset: Path) -> None:
    predictions = tmp_path / "pred"
    predictions.mkdir()
    truth = read_mask(dataset / "masks" / "frame0.png")
    (predictions / "frame0_mask.png").write_bytes(encode_mask_png(truth))  # IoU 1
    half = truth.copy()
    half[:, :80] = False
    (predictions / "frame1.png").write_bytes(
        encode_mask_png(half & read_mask(dataset / "masks" / "frame1.png"))
    )
    result = run(tmp_path, "eval", "segmentation", "--pred", predictions, "--gt", dataset)
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout)
    frame1 = read_mask(dataset / "masks" / "frame1.png")
    expected1 = (half & frame1).sum() / frame1.sum()
    assert report["per_image"] == pytest.approx({"frame0": 1.0, "frame1": expected1, "frame2": 0.0})
    assert report["mIoU"] == pytest.approx((1 + expected1) / 3)
    assert report["quartiles"]["median"] == pytest.approx(expected1)
    assert report["missing"] == ["frame2"]


def test_eval_keypoints(tmp_path: Path, dataset: Path) -> None:
    assert run(tmp_path, "heatmap", dataset / "masks", "--out", tmp_path / "gt").returncode == 0
    predictions = tmp_path / "pred"
    predictions.mkdir()
    for seed in range(3):
        record = json.loads((tmp_path / "gt" / f"frame{seed}.json").read_text())
        moved = (np.array(record["keypoints"]) + np.array([3.0, 4.0]))[::-1]  # 5 px off, reversed
        (predictions / f"frame{seed}.json").write_text(json.dumps({"keypoints": moved.tolist()}))
    result = run(tmp_path, "eval", "keypoints", "--pred", predictions, "--gt", tmp_path / "gt")
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout)
    assert report["mED"] == pytest.approx(5.0) and report["std"] == pytest.approx(0.0)
    assert report["mED_k"] == pytest.approx([5.0] * 4)
    assert report["per_image"]["frame1"] == pytest.approx([5.0] * 4)
    in_order = run(
        tmp_path,
        "eval",
        "keypoints",
        "--pred",
        predictions,
        "--gt",
        tmp_path / "gt",
        "--matching",
        "order",
    )
    assert json.loads(in_order.stdout)["mED"] > 5.0


def test_eval_bad_input_is_one_line(tmp_path: Path, dataset: Path) -> None:
    empty = tmp_path / "empty"
    empty.mkdir()
    _one_line_error(
        run(tmp_path, "eval", "segmentation", "--pred", empty, "--gt", dataset),
        "holds no prediction",
    )
    _one_line_error(
        run(tmp_path, "eval", "segmentation", "--pred", dataset, "--gt", empty),
        "no ground-truth mask",
    )
    truth = tmp_path / "kp"
    truth.mkdir()
    (truth / "a.json").write_text('{"keypoints": [[1, 2]]}')
    _one_line_error(
        run(tmp_path, "eval", "keypoints", "--pred", tmp_path / "x", "--gt", truth), "not a folder"
    )
    (empty / "a.json").write_text("{oops")
    _one_line_error(
        run(tmp_path, "eval", "keypoints", "--pred", empty, "--gt", truth), "not a keypoints file"
    )
    small = tmp_path / "small"
    small.mkdir()
    (small / "frame0.png").write_bytes(encode_mask_png(np.ones((10, 10), bool)))
    _one_line_error(
        run(tmp_path, "eval", "segmentation", "--pred", small, "--gt", dataset), "differ in size"
    )
