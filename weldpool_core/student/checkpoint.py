"""The student's MODEL_DIR: what a training run leaves behind, and how it is read back.

Layout (every file written atomically: a temporary file, then a rename):

- ``config.json``: ``{"format": "weldpool-student", "version": 1, "student": StudentConfig,
  "training": TrainConfig}``, what the predictor needs to rebuild the network.
- ``model.safetensors``: the weights of the best epoch (by the validation score).
- ``metrics.json``: the best epoch's validation metrics, the last epoch's, and facts of the run
  (frames, whether the encoder started from ImageNet weights).
- ``curve.json``: one record per epoch (losses, β, learning rate, mIoU, mED, seconds).
- ``frame_codes.safetensors``: the kept weights' encoder descriptors of the training frames
  (``codes``, M×D; ``predict.frame_codes``) and the student's own familiar distance
  (``familiar``; ``predict.familiar_distance``), for the predictor's novelty score; absent in
  folders of older or unfinished runs (the uncertainty then has no novelty part; a folder with
  codes but no ``familiar`` uses ``predict.FAMILIAR_DISTANCE``).
- ``training_state.pt``: the last epoch's full state (weights, optimiser, schedule, best score)
  from which ``resume`` continues; not needed for inference. The service removes it once a
  version is recorded (``prune_state``): an interrupted run keeps it to resume.
- after ``export``: ``model.onnx``, ``model.torchscript.pt`` and ``export.json``; after
  ``quantize``, ``model.int8.onnx`` (its check recorded in ``export.json`` under ``int8``).

torch and safetensors are imported by the functions that need them, so the layout (and
``prune_state``) can be used by a process that never loads the network.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from weldpool_core.errors import InvalidInputError

if TYPE_CHECKING:
    import torch

    from weldpool_core.student.model import ResNetVAE, StudentConfig

FORMAT = "weldpool-student"
ONNX_FILE = "model.onnx"
"""The exported student for ONNX Runtime (``export``)."""
EXPORT_FILE = "export.json"
"""What the exports record: each file's difference from PyTorch, and the int8 student's record."""
INT8_ONNX_FILE = "model.int8.onnx"
"""The int8 student ``quantize`` makes beside the float ONNX file; its record is
``export.json["int8"]``."""
VERSION = 1
CONFIG_FILE = "config.json"
WEIGHTS_FILE = "model.safetensors"
METRICS_FILE = "metrics.json"
CURVE_FILE = "curve.json"
STATE_FILE = "training_state.pt"
CODES_FILE = "frame_codes.safetensors"


def write_atomic(path: Path, write: Callable[[Path], None]) -> None:
    """Write ``path`` through a temporary file in its folder, then rename it into place."""
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, temporary = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.")
    os.close(handle)
    try:
        write(Path(temporary))
        os.replace(temporary, path)
    finally:
        if os.path.exists(temporary):
            os.unlink(temporary)


def write_json(path: Path, data: Any) -> None:
    """Pretty JSON, atomically."""

    def write(temporary: Path) -> None:
        temporary.write_text(json.dumps(data, indent=2) + "\n")

    write_atomic(path, write)


def read_json(path: Path) -> Any:
    """JSON from a MODEL_DIR file, or an InvalidInputError naming it."""
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise InvalidInputError(
            f"{path.parent} is not a student model folder ({path.name} is missing); train a "
            "student into it first."
        ) from None
    except (OSError, ValueError) as exc:
        raise InvalidInputError(f"{path} cannot be read ({exc}).") from None


def save_weights(model_dir: Path, model: ResNetVAE) -> None:
    """The network's weights as ``model.safetensors``."""
    state = {
        name: tensor.detach().cpu().contiguous() for name, tensor in model.state_dict().items()
    }
    from safetensors.torch import save_file

    write_atomic(model_dir / WEIGHTS_FILE, lambda p: save_file(state, str(p)))


def save_config(model_dir: Path, student: StudentConfig, training: dict[str, Any]) -> None:
    """``config.json``: the architecture and the training settings."""
    write_json(
        model_dir / CONFIG_FILE,
        {"format": FORMAT, "version": VERSION, "student": student.as_dict(), "training": training},
    )


def read_student_config(model_dir: str | Path) -> StudentConfig:
    """The architecture stored in a MODEL_DIR."""
    data = read_json(Path(model_dir) / CONFIG_FILE)
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise InvalidInputError(f"{model_dir} does not hold a weldpool student model.")
    if data.get("version") != VERSION:
        raise InvalidInputError(
            f"{model_dir} holds a student model of format version {data.get('version')}; this "
            f"weldpool reads version {VERSION}."
        )
    from weldpool_core.student.model import StudentConfig

    return StudentConfig.from_dict(data["student"])


def load_student(model_dir: str | Path, device: torch.device | None = None) -> ResNetVAE:
    """The best network of a MODEL_DIR, in eval mode on ``device`` (CPU by default)."""
    import torch
    from safetensors.torch import load_file

    from weldpool_core.student.model import build_student

    root = Path(model_dir)
    config = read_student_config(root)
    model = build_student(config, load_pretrained=False).model
    weights = root / WEIGHTS_FILE
    if not weights.is_file():
        raise InvalidInputError(
            f"{root} has no {WEIGHTS_FILE}; the training did not finish an epoch."
        )
    try:
        state = load_file(str(weights))
        model.load_state_dict(state)
    except (OSError, RuntimeError) as exc:
        raise InvalidInputError(f"{weights} does not fit its config.json ({exc}).") from None
    return model.to(device or torch.device("cpu")).eval()


def save_codes(model_dir: Path, codes: torch.Tensor, familiar: float | None = None) -> None:
    """The training frames' descriptors (M×D) as ``frame_codes.safetensors``, with the
    student's familiar distance (``predict.familiar_distance``) when given."""
    import torch

    state = {"codes": codes.detach().float().cpu().contiguous()}
    if familiar is not None:
        state["familiar"] = torch.tensor([float(familiar)])
    from safetensors.torch import save_file

    write_atomic(model_dir / CODES_FILE, lambda p: save_file(state, str(p)))


def load_codes(model_dir: str | Path) -> tuple[torch.Tensor, float | None] | None:
    """The training frames' descriptors and the familiar distance saved with them (None for a
    folder saved before it was), or None when the folder has no descriptors (or unreadable)."""
    path = Path(model_dir) / CODES_FILE
    if not path.is_file():
        return None
    from safetensors.torch import load_file

    try:
        state = load_file(str(path))
        codes = state["codes"]
    except (OSError, RuntimeError, KeyError):
        return None
    if codes.ndim != 2 or not len(codes):
        return None
    familiar = state.get("familiar")
    if familiar is None or familiar.numel() != 1 or not float(familiar) > 0:
        return codes, None
    return codes, float(familiar)


def save_state(model_dir: Path, state: dict[str, Any]) -> None:
    """The resumable training state (``training_state.pt``)."""
    import torch

    write_atomic(model_dir / STATE_FILE, lambda p: torch.save(state, p))


def prune_state(model_dir: Path) -> int:
    """Remove the resumable training state of a finished run (inference never needs it; it is
    most of a version's size); returns the bytes freed. Weights, metrics and curve stay."""
    path = Path(model_dir) / STATE_FILE
    if not path.is_file():
        return 0
    size = path.stat().st_size
    path.unlink()
    return size


def load_state(model_dir: Path) -> dict[str, Any] | None:
    """The resumable training state, or None when the folder has none."""
    path = model_dir / STATE_FILE
    if not path.is_file():
        return None
    import torch

    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except (OSError, RuntimeError) as exc:
        raise InvalidInputError(f"{path} cannot be read ({exc}); train from the start.") from None
    if not isinstance(state, dict):
        raise InvalidInputError(f"{path} is not a training state; train from the start.")
    return state


def weights_digest(model_dir: str | Path) -> str:
    """SHA-256 of a folder's float weights (``model.safetensors``), which an int8 file names."""
    digest = hashlib.sha256()
    with open(Path(model_dir) / WEIGHTS_FILE, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def current_record(model_dir: str | Path) -> dict[str, Any] | None:
    """The folder's int8 record (``export.json["int8"]``) when its ``model.int8.onnx`` exists
    and was made from the float weights as they are now; None otherwise (none made, or the
    folder was trained further since and the int8 file is stale)."""
    root = Path(model_dir)
    if not (root / INT8_ONNX_FILE).is_file() or not (root / EXPORT_FILE).is_file():
        return None
    data = read_json(root / EXPORT_FILE)
    record = data.get("int8") if isinstance(data, dict) else None
    if not isinstance(record, dict) or record.get("weights_sha256") != weights_digest(root):
        return None
    return record
