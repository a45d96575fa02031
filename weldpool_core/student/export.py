"""Export a trained student for a controller process without Python's web stack.

Both formats hold ``StudentExport``: the deterministic student (the latent's mean, no sampling,
BatchNorm folded into the convolutions). Input ``image``: float32 N×3×S×S, RGB in [0, 1], the
frame letterboxed or resized to S×S as ``export.json`` says (``student.data.FrameGeometry``
gives the arithmetic both ways). Outputs ``mask`` and ``heatmap``: float32 N×S×S
probabilities in [0, 1]; keypoints are the heatmap's modes, mapped back to frame pixels.

- ONNX (``model.onnx``, torch's ``torch.export``-based exporter, dynamic batch size), checked
  with ONNX Runtime against PyTorch on random frames before it is kept.
- TorchScript (``model.torchscript.pt``, traced), for libtorch. PyTorch deprecates TorchScript
  in favour of ``torch.export``; its deprecation warnings are silenced here on purpose, as the
  format is asked for by controllers that embed libtorch. Prefer the ONNX file.
"""

from __future__ import annotations

import contextlib
import copy
import logging
import threading
import warnings
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import numpy as np
import torch
from torch import nn

from weldpool_core.errors import InvalidInputError
from weldpool_core.student import checkpoint
from weldpool_core.student.checkpoint import (
    EXPORT_FILE,
    INT8_ONNX_FILE,
    ONNX_FILE,
    current_record,
)
from weldpool_core.student.model import ResNetVAE, StudentConfig, fuse_batchnorm

TORCHSCRIPT_FILE = "model.torchscript.pt"
FORMATS = ("onnx", "torchscript")
TOLERANCE = 1e-4
"""Largest absolute difference allowed between an exported model and PyTorch."""
_EXPORTER_LOGGERS = ("torch.onnx", "torch.export", "onnxscript", "onnx_ir")


class StudentExport(nn.Module):
    """The deterministic student: RGB in [0, 1] → (mask probability, heatmap), N×S×S each."""

    def __init__(self, model: ResNetVAE) -> None:
        super().__init__()
        self.student = model

    def forward(self, image: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """Mean-latent mask probability and heatmap of a batch of frames, and for a student
        with learned classes their probabilities (N×E×S×S, ``student.classes`` order)."""
        mean, _, skips = self.student.encode(image)
        mask_logits, heatmap_logits, class_logits = self.student.decode_all(mean, skips)
        answer = (torch.sigmoid(mask_logits), torch.sigmoid(heatmap_logits))
        return answer if class_logits is None else (*answer, torch.sigmoid(class_logits))


def export_module(model: ResNetVAE) -> StudentExport:
    """A fused, eval-mode, CPU copy of ``model`` wrapped for export."""
    fused = fuse_batchnorm(copy.deepcopy(model).cpu().eval())
    return StudentExport(fused).eval()


def _examples(size: int, batch: int, seed: int = 0) -> torch.Tensor:
    generator = torch.Generator().manual_seed(seed)
    return torch.rand(batch, 3, size, size, generator=generator)


EXPORTING = threading.RLock()
"""Held while PyTorch exports or traces a model: its exporters keep global state (a mode stack,
the tracing context) and fail when two threads of one process export at once (two live views
of a student not yet exported, or a view beside the int8 job)."""


@contextlib.contextmanager
def quiet_exporter() -> Iterator[None]:
    """One export at a time in this process (``EXPORTING``), its progress notes (info logs,
    torch's pytree notices) kept off stderr."""
    with EXPORTING, _quiet():
        yield


@contextlib.contextmanager
def _quiet() -> Iterator[None]:
    loggers = [logging.getLogger(name) for name in _EXPORTER_LOGGERS]
    levels = [logger.level for logger in loggers]
    for logger in loggers:
        logger.setLevel(logging.ERROR)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", FutureWarning)
            yield
    finally:
        for logger, level in zip(loggers, levels, strict=True):
            logger.setLevel(level)


def export_onnx(model: ResNetVAE, path: Path) -> None:
    """Write ``model`` as ONNX with a dynamic batch dimension."""
    module = export_module(model)
    example = _examples(model.config.input_size, 2)
    batch = torch.export.Dim("batch", min=1, max=1024)
    with quiet_exporter():
        program = torch.onnx.export(
            module,
            (example,),
            dynamo=True,
            input_names=["image"],
            output_names=["mask", "heatmap"] + (["classes"] if model.config.classes else []),
            dynamic_shapes=({0: batch},),
            verbose=False,
        )
    if program is None:
        raise InvalidInputError("The ONNX exporter returned no program.")
    checkpoint.write_atomic(path, lambda p: program.save(str(p)))


def export_torchscript(model: ResNetVAE, path: Path) -> None:
    """Write ``model`` as traced TorchScript (see the module doc on its deprecation)."""
    module = export_module(model)
    example = _examples(model.config.input_size, 1)
    with EXPORTING, warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the deprecation, and transformers' shape checks
        traced = torch.jit.trace(module, (example,))  # type: ignore[no-untyped-call]
    checkpoint.write_atomic(path, lambda p: traced.save(str(p)))


def ensure_onnx(model_dir: str | Path) -> bool:
    """Export MODEL_DIR's ONNX file when it is missing (checked against PyTorch); True if it did
    (of two threads asking at once, one exports and the other finds the file)."""
    with EXPORTING:
        if (Path(model_dir) / ONNX_FILE).is_file():
            return False
        export_student(model_dir, ["onnx"])
        return True


def onnx_session(path: Path, threads: int | None = None, spin: bool = True) -> Any:
    """An ONNX Runtime session for a student file on the CPU (all graph optimisations on).

    ``threads``: intra-op threads (None: ONNX Runtime's default, one per core). ``spin``: let
    idle threads busy-wait for the next run (faster back-to-back batches; off where another
    thread, such as a video decoder, needs the cores between runs).
    """
    import onnxruntime as ort

    options = ort.SessionOptions()
    if not spin:
        options.add_session_config_entry("session.intra_op.allow_spinning", "0")
    options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    if threads:
        options.intra_op_num_threads = threads
        options.inter_op_num_threads = 1
    return ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])


def run_onnx(path: Path, images: np.ndarray[Any, Any], threads: int | None = None) -> list[Any]:
    """ONNX Runtime's (mask, heatmap) for an N×3×S×S float32 batch, on the CPU."""
    session = onnx_session(path, threads)
    return list(session.run(None, {"image": images.astype(np.float32)}))


def load_torchscript(path: Path) -> torch.jit.ScriptModule:
    """A TorchScript student (see the module doc on its deprecation)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        loaded = torch.jit.load(str(path), map_location="cpu")  # type: ignore[no-untyped-call]
    return cast(torch.jit.ScriptModule, loaded)


def _difference(model: ResNetVAE, outputs: Sequence[Any], images: torch.Tensor) -> float:
    with torch.inference_mode():
        reference = StudentExport(copy.deepcopy(model).cpu().eval())(images)
    return max(
        float(np.abs(np.asarray(ours) - theirs.numpy()).max())
        for ours, theirs in zip(outputs, reference, strict=True)
    )


def _class_outputs(config: StudentConfig) -> dict[str, str]:
    """The ``classes`` output's description, naming each channel (none without classes)."""
    if not config.classes:
        return {}
    names = [
        c.name if c.segments else f"{c.name}:{point}"
        for c in config.classes
        for point in (c.points or ("",))
    ]
    return {
        "classes": "float32 batch×E×S×S, learned classes' probabilities (masks ≥ 0.5; points "
        f"at each heatmap's peak), channels: {', '.join(names)}"
    }


@dataclass(frozen=True)
class ExportResult:
    """Written files and how far each format is from PyTorch (max absolute difference)."""

    files: dict[str, Path]
    differences: dict[str, float] = field(default_factory=dict)


def _current_int8(root: Path) -> dict[str, Any] | None:
    """The folder's int8 record when its file was made from the weights as they are now; a
    stale int8 file (the folder was trained further since) is removed."""
    record = current_record(root)
    if record is None:
        (root / INT8_ONNX_FILE).unlink(missing_ok=True)
    return record


def export_student(
    model_dir: str | Path, formats: Sequence[str] = FORMATS, check_batch: int = 3
) -> ExportResult:
    """Export MODEL_DIR's best student into the same folder and check each file against PyTorch.

    Raises InvalidInputError for an unknown format, and when an export differs from PyTorch
    by more than ``TOLERANCE`` on random frames (the file is then removed).
    """
    unknown = sorted(set(formats) - set(FORMATS))
    if unknown:
        raise InvalidInputError(f"Unknown export format {unknown[0]!r}; use onnx or torchscript.")
    root = Path(model_dir)
    model = checkpoint.load_student(root)
    images = _examples(model.config.input_size, check_batch, seed=1)
    files: dict[str, Path] = {}
    differences: dict[str, float] = {}
    for name in formats:
        if name == "onnx":
            path = root / ONNX_FILE
            export_onnx(model, path)
            outputs = run_onnx(path, images.numpy())
        else:
            path = root / TORCHSCRIPT_FILE
            export_torchscript(model, path)
            with torch.inference_mode():
                outputs = [t.numpy() for t in load_torchscript(path)(images)]
        differences[name] = _difference(model, outputs, images)
        if differences[name] > TOLERANCE:
            path.unlink()
            raise InvalidInputError(
                f"The {name} export differs from PyTorch by {differences[name]:.2g} "
                f"(more than {TOLERANCE:g}); it was not kept."
            )
        files[name] = path
    config = model.config
    int8 = _current_int8(root)
    checkpoint.write_json(
        root / EXPORT_FILE,
        {
            **({"int8": int8} if int8 else {}),
            "input": {
                "name": "image",
                "shape": ["batch", 3, config.input_size, config.input_size],
                "dtype": "float32",
                "channels": "RGB",
                "range": [0.0, 1.0],
                "aspect": config.aspect,
            },
            "outputs": {
                "mask": "float32 batch×S×S, pool probability (≥ 0.5 is the pool)",
                "heatmap": "float32 batch×S×S, keypoint heatmap; keypoints are its modes",
                **_class_outputs(config),
            },
            **({"classes": [c.as_dict() for c in config.classes]} if config.classes else {}),
            "keypoints": config.k,
            "files": {name: path.name for name, path in files.items()},
            "max_abs_difference_to_pytorch": differences,
        },
    )
    return ExportResult(files, differences)
