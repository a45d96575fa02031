"""Fixtures of the student tests: students trained once on the tiny frames (``tiny_frames``,
and the crisp ``sure_student``, are in ``tests/conftest.py``: the app's tests use them too)."""

from __future__ import annotations

from dataclasses import replace

import pytest

from tests.core.student.common import TINY_STUDENT, tiny_config
from weldpool_core.student.data import TrainingFrame
from weldpool_core.student.train import TrainResult, train_student


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
