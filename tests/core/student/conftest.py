"""Fixtures of the student tests: tiny frames and a student trained on them once."""

from __future__ import annotations

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
