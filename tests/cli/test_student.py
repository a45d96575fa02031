"""`weldpool train` (with `--classes`), `predict` and `export-student` through the real command
line."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest

from tests.helpers import run_cli
from weldpool_core.io import encode_mask_png, read_mask
from weldpool_core.synth import SynthParams, synth_frame


def run(tmp_path: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return run_cli(*args, env={"WELDPOOL_HOME": str(tmp_path / "home")})


def _dataset(folder: Path, count: int = 6) -> Path:
    """Synthetic frames with the pool and its keypoints, and in the masks export's layout a
    wire (a mask class) and its tip (a points class of manifest.json)."""
    for part in ("images", "masks", "keypoints", "classes/wire"):
        (folder / part).mkdir(parents=True)
    frames = []
    for seed in range(count):
        frame = synth_frame(seed, SynthParams(width=96, height=64))
        cv2.imwrite(str(folder / "images" / f"f{seed}.png"), frame.image)
        (folder / "masks" / f"f{seed}.png").write_bytes(encode_mask_png(frame.mask))
        record = {"keypoints": frame.keypoints.tolist()}
        (folder / "keypoints" / f"f{seed}.json").write_text(json.dumps(record))
        wire = np.zeros((64, 96), bool)
        wire[0:12, 40 + seed : 50 + seed] = True
        (folder / "classes" / "wire" / f"f{seed}.png").write_bytes(encode_mask_png(wire))
        tip = {"class": "tip", "points": {"end": [45.0 + seed, 12.0]}}
        frames.append({"stem": f"f{seed}", "objects": [tip]})
    (folder / "manifest.json").write_text(json.dumps({"frames": frames}))
    return folder


@pytest.fixture(scope="module")
def model(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    root = tmp_path_factory.mktemp("cli-student")
    data = _dataset(root / "data")
    result = run(
        root, "train", str(data), "--out", str(root / "model"), "--epochs", "1",
        "--model", "light", "--input-size", "64", "--skips", "2", "--batch-size", "4",
        "--device", "cpu", "--classes", "tip, wire",
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    summary = json.loads(result.stdout)
    assert (
        summary["best_epoch"] == 1 and summary["train_frames"] + summary["validation_frames"] == 6
    )
    assert "epoch 1/1" in result.stderr  # the progress bar
    # the model this module's tests predict with and export feeds two encoder maps forward
    student = json.loads((root / "model" / "config.json").read_text())["student"]
    assert student["skips"] == 2
    # --classes: the classes of the masks export's layout, in the order asked, in the config
    assert student["classes"] == [
        {"name": "tip", "kind": "points", "points": ["end"]},
        {"name": "wire", "kind": "mask", "points": []},
    ]
    assert set(summary["metrics"]["classes"]) == {"tip", "wire"}
    return root / "model", data


def test_train_writes_a_model_dir(model: tuple[Path, Path]) -> None:
    model_dir, _ = model
    assert {"config.json", "model.safetensors", "metrics.json", "curve.json"} <= {
        p.name for p in model_dir.iterdir()
    }


def test_predict_writes_mask_heatmap_and_keypoints(
    tmp_path: Path, model: tuple[Path, Path]
) -> None:
    model_dir, data = model
    out = tmp_path / "out"
    result = run(
        tmp_path,
        "predict",
        str(model_dir),
        str(data / "images"),
        "--out",
        str(out),
        "--samples",
        "3",
    )
    assert result.returncode == 0, result.stderr
    for stem in (f"f{i}" for i in range(6)):
        mask = read_mask(out / f"{stem}_mask.png")
        heatmap = np.load(out / f"{stem}_heatmap.npy")
        record = json.loads((out / f"{stem}.json").read_text())
        assert mask.shape == (64, 96) and heatmap.shape == (64, 96, 2)
        assert np.array_equal(heatmap[:, :, 1] >= 0.5, mask)
        assert len(record["keypoints"]) <= 4 and 0 <= record["uncertainty"] <= 1
    scored = run(tmp_path, "eval", "keypoints", "--pred", str(out), "--gt", str(data))
    assert scored.returncode == 0, scored.stderr
    assert json.loads(scored.stdout)["count"] == 6


def test_export_student_writes_checked_onnx(tmp_path: Path, model: tuple[Path, Path]) -> None:
    model_dir, _ = model
    result = run(tmp_path, "export-student", str(model_dir), "--format", "onnx")
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout)
    assert Path(report["files"]["onnx"]).is_file() and report["max_abs_difference"]["onnx"] <= 1e-4
    assert result.stderr == ""


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (("train", "{tmp}/nowhere", "--out", "{tmp}/m"), "is not a DATASET folder"),
        (("predict", "{tmp}", "{tmp}/bad.png", "--out", "{tmp}/o"), "not a student model folder"),
        (("predict", "{model}", "{tmp}/bad.png", "--out", "{tmp}/o"), "bad.png: "),
        (("train", "{data}", "--out", "{tmp}/m", "--classes", "arc"), "holds no class 'arc'"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(
    tmp_path: Path, model: tuple[Path, Path], args: tuple[str, ...], message: str
) -> None:
    (tmp_path / "bad.png").write_bytes(b"\x89PNG\r\n\x1a\n broken")
    filled = [a.format(tmp=tmp_path, model=model[0], data=model[1]) for a in args]
    result = run(tmp_path, *filled)
    assert result.returncode == 2
    assert result.stderr.count("\n") == 1 and message in result.stderr
    assert "Traceback" not in result.stderr
