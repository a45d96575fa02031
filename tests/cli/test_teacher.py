"""`weldpool teacher` and `weldpool eval teacher` with local weight directories (random)."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest

from tests.helpers import run_cli
from tests.models import tiny_dino, tiny_sam2
from weldpool_core.io import encode_mask_png, read_mask
from weldpool_core.synth import SynthParams, synth_frame


@pytest.fixture(scope="module")
def weights(tmp_path_factory) -> dict[str, str]:
    root = tmp_path_factory.mktemp("weights")
    tiny_dino().model.save_pretrained(root / "dino")
    tiny_sam2().model.save_pretrained(root / "sam2")
    return {
        "WELDPOOL_DINO": str(root / "dino"),
        "WELDPOOL_SAM2": str(root / "sam2"),
        "WELDPOOL_DINO_INPUT_SIZE": "64",
    }


def run(tmp_path: Path, *args: str, **env: str) -> subprocess.CompletedProcess[str]:
    return run_cli(*args, env={"WELDPOOL_HOME": str(tmp_path / "home"), **env})


def _dataset(folder: Path, count: int = 2) -> Path:
    (folder / "images").mkdir(parents=True)
    (folder / "masks").mkdir()
    for seed in range(count):
        frame = synth_frame(seed=seed, params=SynthParams(width=160, height=100))
        cv2.imwrite(str(folder / "images" / f"f{seed}.png"), frame.image)
        (folder / "masks" / f"f{seed}.png").write_bytes(encode_mask_png(frame.mask))
    return folder


def test_teacher_writes_mask_heatmap_and_json(tmp_path: Path, weights) -> None:
    data = _dataset(tmp_path / "data")
    result = run(
        tmp_path,
        "teacher",
        str(data / "images"),
        "--out",
        str(tmp_path / "out"),
        "--prompts",
        "center",
        **weights,
    )
    assert result.returncode == 0, result.stderr
    for stem in ("f0", "f1"):
        mask = read_mask(tmp_path / "out" / f"{stem}_mask.png")
        heatmap = np.load(tmp_path / "out" / f"{stem}_heatmap.npy")
        record = json.loads((tmp_path / "out" / f"{stem}.json").read_text())
        assert mask.shape == (100, 160) and heatmap.shape == (100, 160, 2)
        assert np.array_equal(heatmap[:, :, 1] > 0.5, mask)
        assert record["prompt_config"] == "center" and len(record["prompts"]["points"]) == 1
        assert "keypoints" in record and record["width"] == 160
    cached = list((tmp_path / "home" / "cache" / "embeddings").glob("*/*.safetensors"))
    assert len(cached) == 2  # the click endpoint will find these


def test_eval_teacher_prints_the_ablation(tmp_path: Path, weights) -> None:
    data = _dataset(tmp_path / "data", count=2)
    table = run(tmp_path, "eval", "teacher", "--images", str(data), "--masks", str(data), **weights)
    assert table.returncode == 0, table.stderr
    lines = table.stdout.strip().splitlines()
    assert lines[0] == "prompt ablation on 2 frames (IoU in %)"
    assert [line.split()[0] for line in lines[2:]] == ["none", "center", "heuristic"]
    as_json = run(
        tmp_path,
        "eval",
        "teacher",
        "--images",
        str(data),
        "--masks",
        str(data),
        "--json",
        **weights,
    )
    report = json.loads(as_json.stdout)
    assert set(report) == {"none", "center", "heuristic"}
    assert all(0 <= row["mIoU"] <= 1 and row["count"] == 2 for row in report.values())


def test_missing_weights_are_one_line_naming_the_variable(tmp_path: Path) -> None:
    image = tmp_path / "a.png"
    cv2.imwrite(str(image), np.zeros((20, 20), np.uint8))
    result = run(
        tmp_path,
        "teacher",
        str(image),
        "--out",
        str(tmp_path / "o"),
        WELDPOOL_DINO=str(tmp_path / "nowhere"),
        HF_HOME=str(tmp_path / "hf"),
    )
    assert result.returncode == 2
    assert result.stderr.count("\n") == 1 and "WELDPOOL_DINO" in result.stderr
    assert "Traceback" not in result.stderr
