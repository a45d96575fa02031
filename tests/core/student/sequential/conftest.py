"""A crisp tiny student that carries a cell keeping 60 % of the past."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from tests.core.student.sequential.common import gated_cell
from weldpool_core.student import checkpoint
from weldpool_core.student.export import export_student
from weldpool_core.student.sequential import (
    SequentialConfig,
    save_cell,
)
from weldpool_core.student.train import TrainResult


@pytest.fixture()
def stateful_dir(sure_latent_student: TrainResult, tmp_path: Path) -> Path:
    """The tiny student (without skips: all it draws comes through the state) trained until
    its masks are crisp, with a cell that keeps 60 % of the past (so the state shows in its
    masks)."""
    root = Path(shutil.copytree(sure_latent_student.model_dir, tmp_path / "model"))
    cell = gated_cell(checkpoint.load_student(root).config.latent_channels, update=0.4)
    save_cell(root, cell, SequentialConfig(device="cpu"), windows=1, losses=[1.0])
    export_student(root, ["onnx"])
    return root
