"""Training: the MODEL_DIR it writes, seeds, resume after a cancel, progress, in-memory input."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from safetensors.numpy import load_file

from tests.core.student.common import TINY_STUDENT, synthetic_frames, tiny_config
from weldpool_core.errors import InvalidInputError
from weldpool_core.student.data import TrainingFrame
from weldpool_core.student.train import (
    TrainConfig,
    TrainResult,
    _score,
    _split,
    batch_draws,
    train_student,
)


class Cancelled(Exception):
    """What a worker raises from the progress callback to stop a job."""


def _weights(model_dir: Path) -> dict[str, np.ndarray]:
    return load_file(str(model_dir / "model.safetensors"))


def _state_weights(model_dir: Path) -> dict[str, np.ndarray]:
    import torch

    state = torch.load(model_dir / "training_state.pt", weights_only=True)
    return {name: tensor.numpy() for name, tensor in state["model"].items()}


def test_the_model_dir_holds_config_weights_metrics_and_curve(trained: TrainResult) -> None:
    root = trained.model_dir
    names = {p.name for p in root.iterdir()}
    assert {"config.json", "model.safetensors", "metrics.json", "curve.json"} <= names
    assert "training_state.pt" in names
    config = json.loads((root / "config.json").read_text())
    assert config["format"] == "weldpool-student" and config["student"]["input_size"] == 64
    metrics = json.loads((root / "metrics.json").read_text())
    assert metrics["best_epoch"] == trained.best_epoch and 1 <= trained.best_epoch <= 2
    assert set(metrics["best"]) >= {"mIoU", "mED", "mED_k", "std"}
    assert 0 <= metrics["best"]["mIoU"] <= 1 and metrics["pretrained_encoder"] is False
    curve = json.loads((root / "curve.json").read_text())
    assert [r["epoch"] for r in curve] == [1, 2] == [r.epoch for r in trained.curve]
    assert all(r["loss"] > 0 and r["beta"] >= 0 for r in curve)
    assert trained.train_frames == 7 and trained.validation_frames == 1


def test_the_same_seed_gives_the_same_weights(
    tmp_path: Path, tiny_frames: list[TrainingFrame], trained: TrainResult
) -> None:
    again = train_student(tiny_frames, tmp_path / "again", TINY_STUDENT, tiny_config())
    first, second = _weights(trained.model_dir), _weights(again.model_dir)
    assert first.keys() == second.keys()
    assert all(np.array_equal(first[name], second[name]) for name in first)
    assert [r.loss for r in again.curve] == [r.loss for r in trained.curve]
    other = train_student(tiny_frames, tmp_path / "other", TINY_STUDENT, tiny_config(seed=1))
    assert not np.array_equal(
        _weights(other.model_dir)["to_latent.weight"], first["to_latent.weight"]
    )


def test_a_cancelled_run_resumes_from_its_saved_epoch_to_the_same_end(
    tmp_path: Path, tiny_frames: list[TrainingFrame]
) -> None:
    config = tiny_config(epochs=3)
    straight = train_student(tiny_frames, tmp_path / "straight", TINY_STUDENT, config)

    def cancel_after_epoch_2(fraction: float, message: str) -> None:
        if message.startswith("epoch 2/3 mIoU"):
            raise Cancelled

    with pytest.raises(Cancelled):
        train_student(tiny_frames, tmp_path / "run", TINY_STUDENT, config, cancel_after_epoch_2)
    saved = json.loads((tmp_path / "run" / "curve.json").read_text())
    assert [r["epoch"] for r in saved] == [1, 2]

    messages: list[str] = []
    resumed = train_student(
        tiny_frames, tmp_path / "run", None, config, lambda f, m: messages.append(m), resume=True
    )
    assert messages[0].startswith("epoch 3/3")  # no epoch is trained twice
    assert [r.epoch for r in resumed.curve] == [1, 2, 3]
    assert [r.loss for r in resumed.curve] == [r.loss for r in straight.curve]
    expected, found = _state_weights(tmp_path / "straight"), _state_weights(tmp_path / "run")
    assert all(np.array_equal(expected[name], found[name]) for name in expected)


def test_progress_rises_to_one_and_in_memory_tuples_train(tmp_path: Path) -> None:
    frames = synthetic_frames(4)
    samples = [  # a 16-bit gray frame, a 0/255 mask, given keypoints
        (f.image[:, :, 0].astype(np.uint16) * 257, f.mask.astype(np.uint8) * 255, None)
        for f in frames
    ]
    samples[0] = (frames[0].image, frames[0].mask, np.array([[30.0, 30.0], [60.0, 40.0]]))
    reports: list[tuple[float, str]] = []
    result = train_student(
        iter(samples),
        tmp_path / "model",
        TINY_STUDENT,
        tiny_config(epochs=1),
        lambda f, m: reports.append((f, m)),
        validation=iter(synthetic_frames(2, first_seed=10)),
    )
    fractions = [f for f, _ in reports]
    assert fractions == sorted(fractions) and fractions[-1] == 1.0 and min(fractions) >= 0
    assert result.train_frames == 4 and result.validation_frames == 2


def test_unusable_requests_are_one_sentence(tmp_path: Path, trained: TrainResult) -> None:
    with pytest.raises(InvalidInputError, match="no frames to train on"):
        train_student([], tmp_path / "empty", TINY_STUDENT, tiny_config())
    with pytest.raises(InvalidInputError, match="already holds a student model"):
        train_student(synthetic_frames(2), trained.model_dir, TINY_STUDENT, tiny_config())
    with pytest.raises(InvalidInputError, match="no training state to resume"):
        train_student(synthetic_frames(2), tmp_path / "new", None, tiny_config(), resume=True)
    with pytest.raises(InvalidInputError, match="already trained 2 epochs"):
        train_student(synthetic_frames(2), trained.model_dir, None, tiny_config(), resume=True)
    with pytest.raises(InvalidInputError, match="image must be H×W×3 RGB uint8"):
        TrainingFrame(np.zeros((4, 4), np.uint8), np.zeros((4, 4), bool))


def _metrics(miou: float, penalised: float | None = 943.4, med: float | None = None) -> dict:
    return {"mIoU": miou, "mED_penalised": penalised, "mED": med, "mED_k": [], "missed": 0}


def test_rounds_below_the_iou_floor_are_ranked_by_miou() -> None:
    # Every frame below IoU 0.5: mED_penalised is the diagonal whatever the round.
    assert _score(_metrics(0.40), "mED") < _score(_metrics(0.10), "mED")
    # A real keypoint improvement still outweighs a small mIoU change.
    assert _score(_metrics(0.80, 12.0), "mED") < _score(_metrics(0.82, 14.0), "mED")
    assert _score(_metrics(0.80, 12.0), "mIoU") > _score(_metrics(0.82, 14.0), "mIoU")


def test_an_untrained_first_round_is_not_kept_over_a_better_later_one(
    tmp_path: Path, tiny_frames: list[TrainingFrame], monkeypatch: pytest.MonkeyPatch
) -> None:
    rounds = iter([0.05, 0.20, 0.45, 0.30])  # all below the floor, the third the best

    def validate(*args: object) -> dict:
        return _metrics(next(rounds))

    monkeypatch.setattr("weldpool_core.student.train.validate", validate)
    result = train_student(tiny_frames[:4], tmp_path / "m", TINY_STUDENT, tiny_config(epochs=4))
    assert result.best_epoch == 3 and result.metrics["mIoU"] == 0.45


def test_a_few_frames_train_for_the_step_floor_in_full_batches() -> None:
    config = TrainConfig()
    plan = config.plan(6)
    assert config.epochs is None and plan.total_steps >= 300 and plan.steps_per_epoch is None
    assert plan.round_ends[-1] == plan.total_steps and plan.rounds == config.rounds
    assert list(plan.round_ends) == sorted(set(plan.round_ends))
    draws = [batch_draws(plan, 6, 8, 0, step) for step in range(3)]
    assert all(len(d) == 8 for d in draws)  # full batches with fewer frames than a batch
    stream = [d for step in draws for d in step]
    for pass_index in range(4):  # each pass shows every frame once
        assert sorted(i for p, i in stream if p == pass_index) == list(range(6))
    big = config.plan(4000)  # a large set trains min_epochs passes, more than the floor
    assert big.total_steps == config.min_epochs * 500 > config.steps
    by_epoch = replace(config, epochs=3).plan(6)
    assert by_epoch.total_steps == 3 and by_epoch.round_ends == (1, 2, 3)
    assert [i for _, i in batch_draws(by_epoch, 6, 8, 0, 0)] != list(range(6))  # shuffled
    assert len(batch_draws(by_epoch, 6, 8, 0, 0)) == 6  # an epoch's last batch is short


def test_a_run_counted_in_steps_resumes_to_the_same_end(
    tmp_path: Path, tiny_frames: list[TrainingFrame]
) -> None:
    config = tiny_config(epochs=None, steps=6, rounds=3, min_epochs=0)
    straight = train_student(tiny_frames, tmp_path / "straight", TINY_STUDENT, config)
    assert [r.step for r in straight.curve] == [2, 4, 6]

    def cancel_after_round_2(fraction: float, message: str) -> None:
        if message.startswith("round 2/3 mIoU"):
            raise Cancelled

    with pytest.raises(Cancelled):
        train_student(tiny_frames, tmp_path / "run", TINY_STUDENT, config, cancel_after_round_2)
    resumed = train_student(tiny_frames, tmp_path / "run", None, config, resume=True)
    assert [r.loss for r in resumed.curve] == [r.loss for r in straight.curve]
    expected, found = _state_weights(tmp_path / "straight"), _state_weights(tmp_path / "run")
    assert all(np.array_equal(expected[name], found[name]) for name in expected)
    assert (tmp_path / "run" / "frame_codes.safetensors").is_file()
    with pytest.raises(InvalidInputError, match="already finished its 3 rounds"):
        train_student(tiny_frames, tmp_path / "run", None, config, resume=True)


def test_fewer_frames_than_the_split_minimum_all_train() -> None:
    prepared = [f"frame{i}" for i in range(6)]
    train, held = _split(prepared[:2], TrainConfig())  # type: ignore[arg-type]
    assert train == held == prepared[:2]
    train, held = _split(prepared, TrainConfig())  # type: ignore[arg-type]
    assert len(train) == 5 and len(held) == 1 and set(train + held) == set(prepared)
    train, held = _split(prepared[:2], TrainConfig(min_split_frames=2))  # type: ignore[arg-type]
    assert len(train) == len(held) == 1
