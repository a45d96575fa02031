"""Helpers of the student tests: small synthetic frames and a small training configuration."""

from __future__ import annotations

from typing import Any

from weldpool_core.io import to_rgb8
from weldpool_core.student.data import TrainingFrame
from weldpool_core.student.model import student_config
from weldpool_core.student.train import TrainConfig
from weldpool_core.synth import SynthParams, synth_frame

TINY_FRAME = SynthParams(width=96, height=64)
TINY_STUDENT = student_config("light", input_size=64)
"""The light layout on a 64² input: an epoch over a few frames takes well under a second."""


def synthetic_frames(
    count: int, params: SynthParams = TINY_FRAME, first_seed: int = 0, time_s: float = 0.0
) -> list[TrainingFrame]:
    """``count`` synthetic frames (one weld run per seed) as training frames."""
    frames = []
    for seed in range(first_seed, first_seed + count):
        frame = synth_frame(seed, params, time_s)
        frames.append(TrainingFrame(to_rgb8(frame.image), frame.mask, None, f"s{seed}"))
    return frames


def tiny_config(**changes: Any) -> TrainConfig:
    """A CPU training configuration small enough for unit tests."""
    values: dict[str, Any] = {"epochs": 2, "batch_size": 4, "device": "cpu"}
    values.update(changes)
    return TrainConfig(**values)
