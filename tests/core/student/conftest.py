"""Fixtures of the student tests: tiny frames and a student trained on them once."""

from __future__ import annotations

from dataclasses import replace

import pytest

from tests.core.student.common import TINY_STUDENT, synthetic_frames, tiny_config
from weldpool_core.student.data import TrainingFrame
from weldpool_core.student.train import TrainResult, train_student


@pytest.fixture(scope="session")
def tiny_frames() -> list[TrainingFrame]:
    return synthetic_frames(8)


@pytest.fixture(scope="session")
def trained(
    tmp_path_factory: pytest.TempPathFactory, tiny_frames: list[TrainingFrame]
) -> TrainResult:
    """A light student trained for two epochs on eight tiny frames (not accurate, but real)."""
    out = tmp_path_factory.mktemp("student") / "model"
    return train_student(tiny_frames, out, TINY_STUDENT, tiny_config())


@pytest.fixture(scope="session")
def skipped(
    tmp_path_factory: pytest.TempPathFactory, tiny_frames: list[TrainingFrame]
) -> TrainResult:
    """Like ``trained``, with the encoder's stride-16, 8 and 4 maps fed to the decoder."""
    out = tmp_path_factory.mktemp("skips-student") / "model"
    return train_student(tiny_frames, out, replace(TINY_STUDENT, skips=3), tiny_config())


@pytest.fixture(scope="session")
def sure_student(
    tmp_path_factory: pytest.TempPathFactory, tiny_frames: list[TrainingFrame]
) -> TrainResult:
    """A light student trained for 800 steps on the eight tiny frames: sure of frames like
    them (mIoU about 0.9 on other runs), so that what raises its uncertainty can be seen."""
    out = tmp_path_factory.mktemp("sure-student") / "model"
    config = tiny_config(epochs=None, steps=800, rounds=4)
    return train_student(tiny_frames, out, TINY_STUDENT, config)


@pytest.fixture(scope="session")
def sure_latent_student(
    tmp_path_factory: pytest.TempPathFactory, tiny_frames: list[TrainingFrame]
) -> TrainResult:
    """``sure_student`` without skips: everything it draws passes through its latent, the
    state a sequential cell carries (a skip student's finer maps come from each frame)."""
    out = tmp_path_factory.mktemp("sure-latent-student") / "model"
    config = tiny_config(epochs=None, steps=800, rounds=4)
    return train_student(tiny_frames, out, replace(TINY_STUDENT, skips=0), config)
