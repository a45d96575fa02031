"""A trained cell in MODEL_DIR: its files, saved beside its student, loaded only for the
student it was trained on."""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path
from typing import Any

import torch

from weldpool_core.errors import InvalidInputError
from weldpool_core.student import checkpoint
from weldpool_core.student.sequential.config import SequentialConfig
from weldpool_core.student.sequential.model import LatentCell, SequentialStudent

SEQUENTIAL_WEIGHTS = "sequential.safetensors"
SEQUENTIAL_CONFIG = "sequential.json"
SEQUENTIAL_ONNX = "sequential.onnx"


def save_cell(
    root: Path, cell: LatentCell, config: SequentialConfig, windows: int, losses: list[float]
) -> None:
    """The cell's weights and its record (``sequential.json``) in the MODEL_DIR."""
    from safetensors.torch import save_file

    state = {name: t.detach().cpu().contiguous() for name, t in cell.state_dict().items()}
    checkpoint.write_atomic(root / SEQUENTIAL_WEIGHTS, lambda p: save_file(state, str(p)))
    record = asdict(config)
    checkpoint.write_json(
        root / SEQUENTIAL_CONFIG,
        {
            "channels": cell.channels,
            "student_sha256": _student_digest(root),
            "training": record,
            "windows": windows,
            "loss_curve": [round(x, 5) for x in losses[:: max(1, len(losses) // 50)]],
        },
    )
    (root / SEQUENTIAL_ONNX).unlink(missing_ok=True)  # an old export no longer matches


def _student_digest(root: Path) -> str:
    """SHA-256 of the per-frame student's weights the cell was trained on."""
    import hashlib

    return hashlib.sha256((root / checkpoint.WEIGHTS_FILE).read_bytes()).hexdigest()


def _matching_record(root: Path) -> Any:
    """The cell's record, or a one-sentence error when its student has been retrained since."""
    record = checkpoint.read_json(root / SEQUENTIAL_CONFIG)
    if record.get("student_sha256") != _student_digest(root):
        raise InvalidInputError(
            f"The sequential cell in {root} was trained for another version of its student; "
            "train the cell again."
        )
    return record


def has_sequential(model_dir: str | Path) -> bool:
    """Whether a MODEL_DIR holds a trained sequential cell."""
    return (Path(model_dir) / SEQUENTIAL_WEIGHTS).is_file()


def load_sequential(model_dir: str | Path, device: torch.device | None = None) -> SequentialStudent:
    """The sequential student of a MODEL_DIR (eval mode), or a one-sentence error."""
    from safetensors.torch import load_file

    root = Path(model_dir)
    if not has_sequential(root):
        raise InvalidInputError(
            f"{root} has no sequential cell; train one on videos of the camera first."
        )
    record = _matching_record(root)
    student = checkpoint.load_student(root, device)
    cell = LatentCell(int(record["channels"]))
    cell.load_state_dict(load_file(str(root / SEQUENTIAL_WEIGHTS)))
    return SequentialStudent(student, cell.to(device or torch.device("cpu"))).eval()
