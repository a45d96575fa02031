"""The sequential student's settings (training windows, motion, steadiness)."""

from __future__ import annotations

from dataclasses import dataclass, field

from weldpool_core.errors import InvalidInputError
from weldpool_core.student.data import (
    Augmentation,
)


@dataclass(frozen=True)
class SequentialConfig:
    """How the sequential cell is trained (the per-frame student stays as it is).

    Attributes:
        window: consecutive frames per training example (the last one labelled).
        strides: frame strides drawn for a window (1: every frame; 2: every other), so the cell
            learns more than one frame rate.
        steps: optimiser steps.
        batch_size: windows per step.
        learning_rate: AdamW's peak learning rate (cosine to 2 % of it).
        drift: largest synthetic drift of a window, per frame along each axis, as a fraction
            of the input side (0.004: 1 input pixel per frame at 256², 5 frame pixels of a
            1280-wide camera; a pool that moves faster than that is rare in a torch-mounted
            camera, and a cell taught faster drifts keeps less of the past).
        consistency: weight of the steadiness term on unlabelled windows (0: off).
        unlabelled_windows: unlabelled windows per video (evenly spaced; stride 1).
        unlabelled_batch: unlabelled windows per step.
        augmentation: the shared per-window affine and the per-frame photometric noise.
        heatmap_sigma: the heatmap target's smallest spread (the per-frame student's).
        seed: seeds the cell's weights and every draw.
        device: cpu, cuda, cuda:N, mps or auto.
    """

    window: int = 8
    strides: tuple[int, ...] = (1, 2)
    steps: int = 200
    batch_size: int = 4
    learning_rate: float = 3e-3
    drift: float = 0.004
    consistency: float = 1.0
    unlabelled_windows: int = 32
    unlabelled_batch: int = 2
    augmentation: Augmentation = field(default_factory=Augmentation)
    heatmap_sigma: float = 3.0
    seed: int = 0
    device: str = "auto"

    def __post_init__(self) -> None:
        if self.consistency < 0 or self.unlabelled_windows < 0 or self.unlabelled_batch < 0:
            raise InvalidInputError(
                "Bad sequential training: consistency and the unlabelled counts must be ≥ 0."
            )
        if self.window < 2 or self.steps < 1 or self.batch_size < 1:
            raise InvalidInputError(
                "Bad sequential training: window must be at least 2, steps and batch_size 1."
            )
        if not self.strides or min(self.strides) < 1:
            raise InvalidInputError("Bad sequential training: strides must be positive.")
        if self.learning_rate <= 0 or not 0 <= self.drift < 0.1:
            raise InvalidInputError(
                "Bad sequential training: learning_rate must be > 0 and drift in [0, 0.1)."
            )
