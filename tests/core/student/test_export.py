"""ONNX and TorchScript exports agree with PyTorch (mean latent) within 1e-4."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from weldpool_core.errors import InvalidInputError
from weldpool_core.student.checkpoint import load_student
from weldpool_core.student.export import (
    StudentExport,
    export_student,
    load_torchscript,
    run_onnx,
)
from weldpool_core.student.predict import StudentPredictor, frames_to_batch, to_frame
from weldpool_core.student.train import TrainResult
from weldpool_core.synth import SynthParams, synth_frame


@pytest.mark.parametrize("student", ["trained", "skipped"])
def test_onnx_and_torchscript_match_pytorch(student: str, request: pytest.FixtureRequest) -> None:
    trained: TrainResult = request.getfixturevalue(student)
    result = export_student(trained.model_dir)
    assert set(result.files) == {"onnx", "torchscript"}
    assert all(d <= 1e-4 for d in result.differences.values())
    model = load_student(trained.model_dir)
    frames = [synth_frame(seed, SynthParams(width=96, height=64)).image for seed in range(5)]
    images, geometries = frames_to_batch(frames, model.config)
    with torch.inference_mode():
        mask, heatmap = StudentExport(model.eval())(images)
    for batch in (images[:1], images):  # the batch size is dynamic
        onnx_mask, onnx_heatmap = run_onnx(result.files["onnx"], batch.numpy())
        assert np.abs(onnx_mask - mask[: len(batch)].numpy()).max() <= 1e-4
        assert np.abs(onnx_heatmap - heatmap[: len(batch)].numpy()).max() <= 1e-4
    with torch.inference_mode():
        script_mask, script_heatmap = load_torchscript(result.files["torchscript"])(images)
    assert torch.allclose(script_mask, mask, atol=1e-4)
    assert torch.allclose(script_heatmap, heatmap, atol=1e-4)
    described = json.loads((trained.model_dir / "export.json").read_text())
    assert described["input"]["shape"] == ["batch", 3, 64, 64]
    # A controller reproduces the predictor from the ONNX outputs and the geometry.
    predicted = StudentPredictor.load(trained.model_dir, "cpu").predict(frames)
    for index, geometry in enumerate(geometries):
        rebuilt = to_frame(onnx_mask[index], onnx_heatmap[index], geometry, model.config)
        assert np.mean(rebuilt.mask == predicted[index].mask) > 0.999
        assert np.allclose(rebuilt.heatmap, predicted[index].heatmap, atol=1e-3)


def test_unknown_formats_are_refused(trained: TrainResult) -> None:
    with pytest.raises(InvalidInputError, match="Unknown export format"):
        export_student(trained.model_dir, ["tflite"])


def test_two_threads_asking_for_a_missing_onnx_file_get_one_export(
    trained: TrainResult, tmp_path
) -> None:
    """Two live views start at once on a student never exported: one thread exports, the other
    waits and finds the file (PyTorch's exporter failed when two threads ran it at once)."""
    import shutil
    import threading

    from weldpool_core.student.export import ensure_onnx

    folder = tmp_path / "fresh"
    shutil.copytree(
        trained.model_dir, folder, ignore=shutil.ignore_patterns("*.onnx", "export.json")
    )
    barrier, answers, errors = threading.Barrier(2), [], []

    def ask() -> None:
        barrier.wait()
        try:
            answers.append(ensure_onnx(folder))
        except Exception as exc:  # any failure fails the test below
            errors.append(exc)

    threads = [threading.Thread(target=ask) for _ in range(2)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(300)
    assert errors == [] and sorted(answers) == [False, True]
    assert run_onnx(folder / "model.onnx", np.zeros((1, 3, 64, 64), np.float32))[0].shape[0] == 1
