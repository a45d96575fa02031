"""The whole sequential student as one ONNX file, checked against PyTorch."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from weldpool_core.errors import InvalidInputError
from weldpool_core.student import checkpoint
from weldpool_core.student.sequential.checkpoint import (
    SEQUENTIAL_ONNX,
    _matching_record,
    load_sequential,
)
from weldpool_core.student.sequential.model import SequentialExport, SequentialStudent


def export_sequential_onnx(model_dir: str | Path) -> Path:
    """``sequential.onnx`` of a MODEL_DIR (written once; returns its path).

    The file is checked against PyTorch over two steps (a fresh frame, then a frame with the
    state carried) before it takes its name: more than ``export.TOLERANCE`` apart, it is not kept
    and this raises InvalidInputError.
    """
    from weldpool_core.student.export import TOLERANCE, quiet_exporter

    root = Path(model_dir)
    path = root / SEQUENTIAL_ONNX
    if path.is_file():
        _matching_record(root)  # an export made before the student was retrained is refused too
        return path
    import copy

    from weldpool_core.student.model import fuse_batchnorm

    reference = load_sequential(root)
    model = copy.deepcopy(reference)
    model.student = fuse_batchnorm(model.student)
    size = model.config.input_size
    cells = size // 32
    image = torch.rand(1, 3, size, size, generator=torch.Generator().manual_seed(0))
    state = torch.zeros(1, model.cell.channels, cells, cells)
    fresh = torch.ones(1, 1, 1, 1)
    with quiet_exporter():
        program = torch.onnx.export(
            SequentialExport(model).eval(),
            (image, state, fresh),
            dynamo=True,
            input_names=["image", "state", "fresh"],
            output_names=["mask", "heatmap", "new_state"],
            verbose=False,
        )
    if program is None:
        raise InvalidInputError("The ONNX exporter returned no program.")

    def write_checked(temporary: Path) -> None:  # checked before it takes the file's name
        program.save(str(temporary))
        difference = _onnx_difference(reference, temporary)
        if difference > TOLERANCE:
            raise InvalidInputError(
                f"The sequential ONNX export differs from PyTorch by {difference:.2g} (more "
                f"than {TOLERANCE:g}); it was not kept."
            )

    checkpoint.write_atomic(path, write_checked)
    return path


def _onnx_difference(reference: SequentialStudent, path: Path) -> float:
    """Largest absolute difference between ``path`` and PyTorch over a fresh step and a step
    with the state carried (two different random frames)."""
    from weldpool_core.student.export import onnx_session

    size, channels = reference.config.input_size, reference.cell.channels
    frames = torch.rand(2, 1, 3, size, size, generator=torch.Generator().manual_seed(1))
    session = onnx_session(path, threads=1)
    torch_module = SequentialExport(reference).eval()
    state = torch.zeros(1, channels, size // 32, size // 32)
    worst = 0.0
    for step, fresh in enumerate((1.0, 0.0)):
        flag = torch.full((1, 1, 1, 1), fresh)
        with torch.inference_mode():
            expected = torch_module(frames[step], state, flag)
        feeds = {"image": frames[step].numpy(), "state": state.numpy(), "fresh": flag.numpy()}
        outputs = session.run(None, feeds)
        worst = max(
            worst,
            *(float(np.abs(o - e.numpy()).max()) for o, e in zip(outputs, expected, strict=True)),
        )
        state = expected[2]
    return worst
