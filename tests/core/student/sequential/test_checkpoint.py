"""A cell belongs to the student it was trained on."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from weldpool_core.cell.stream import StreamStudent
from weldpool_core.errors import InvalidInputError
from weldpool_core.student import checkpoint
from weldpool_core.student.sequential import (
    load_sequential,
)


def test_a_cell_is_refused_once_its_student_is_retrained(stateful_dir: Path) -> None:
    StreamStudent(stateful_dir, "onnx", sequential=True)  # exports sequential.onnx
    student = checkpoint.load_student(stateful_dir)
    with torch.no_grad():
        student.to_latent.bias.add_(0.1)  # another training run into the same folder
    checkpoint.save_weights(stateful_dir, student)
    with pytest.raises(InvalidInputError, match="trained for another version of its student"):
        load_sequential(stateful_dir)
    with pytest.raises(InvalidInputError, match="trained for another version of its student"):
        StreamStudent(stateful_dir, "onnx", sequential=True)
