"""Runners: a trained student on one prepared frame at a time, one small class per backend.

Every runner takes the 1×3×S×S input of ``stream.StreamStudent.prepare`` and answers the mask
probability and heatmap (S×S) and, where it can score one, the uncertainty. ``RUNNERS`` maps
each kind to its runner, and ``runner_kind`` picks the kind from what a caller asks for:

- ``onnx``: ONNX Runtime on the folder's ``model.onnx`` (the default beside the robot);
- ``int8``: ONNX Runtime on the quantized ``model.int8.onnx`` (``student.quantize``), only
  while it was made from the folder's weights as they are now;
- ``torch``: PyTorch (CUDA when present), the only one that scores the uncertainty, which
  draws the latent and reads the encoder;
- ``sequential``: the folder's sequential student (``student.sequential``) on ONNX Runtime or
  PyTorch, carrying its state from frame to frame; ``reset`` starts a new stream.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from weldpool_core.errors import InvalidInputError
from weldpool_core.student.checkpoint import INT8_ONNX_FILE, ONNX_FILE, current_record
from weldpool_core.student.data import FrameGeometry
from weldpool_core.student.export import onnx_session
from weldpool_core.student.model import StudentConfig
from weldpool_core.student.predict import uncertainty_of

BACKENDS = ("onnx", "torch")
Answer = tuple[NDArray[np.float32], NDArray[np.float32], float | None]


@dataclass(frozen=True)
class RunnerOptions:
    """What a runner is opened with (see ``stream.StreamStudent``)."""

    model_dir: Path
    config: StudentConfig
    backend: str = "onnx"
    device: str = "auto"
    threads: int | None = None
    spin: bool = False


class Runner(Protocol):
    """One prepared frame → mask probability, heatmap (S×S) and the uncertainty (or None);
    ``extra`` holds the last frame's learned-class probabilities (E×S×S; None without)."""

    extra: NDArray[np.float32] | None

    def run(self, batch: NDArray[np.float32], geometry: FrameGeometry, samples: int) -> Answer: ...

    def reset(self) -> None: ...


def _no_samples(samples: int, reason: str) -> None:
    if samples:
        raise InvalidInputError(reason)


def _torch_threads(threads: int | None) -> None:
    """``torch.set_num_threads`` (it holds for the whole process)."""
    if threads:
        import torch

        torch.set_num_threads(threads)


class OnnxRunner:
    """The per-frame student on ONNX Runtime (``model.onnx``)."""

    file = ONNX_FILE
    extra: NDArray[np.float32] | None = None

    def __init__(self, options: RunnerOptions) -> None:
        path = options.model_dir / self.file
        if not path.is_file():
            raise InvalidInputError(
                f"{options.model_dir} has no {path.name}; export the student to ONNX first, "
                "or run it with PyTorch."
            )
        self._session = onnx_session(path, options.threads, spin=options.spin)

    def run(self, batch: NDArray[np.float32], geometry: FrameGeometry, samples: int) -> Answer:
        _no_samples(samples, "The uncertainty needs the PyTorch backend.")
        mask, heatmap, *classes = self._session.run(None, {"image": batch})
        self.extra = classes[0][0] if classes else None
        return mask[0], heatmap[0], None

    def reset(self) -> None:
        pass


class Int8Runner(OnnxRunner):
    """The quantized student (``model.int8.onnx``), only while it matches the weights."""

    file = INT8_ONNX_FILE

    def __init__(self, options: RunnerOptions) -> None:
        path = options.model_dir / self.file
        if not path.is_file():
            raise InvalidInputError(
                f"{options.model_dir} has no {path.name}; make the int8 student first, "
                "calibrated on frames of the camera: “Make int8” on the models page of the "
                f"server, or weldpool export-student {options.model_dir} --format onnx-int8 "
                "--calibrate FRAMES."
            )
        if current_record(options.model_dir) is None:
            raise InvalidInputError(
                f"The {INT8_ONNX_FILE} of {options.model_dir} was made from other weights; make "
                "the int8 student again."
            )
        super().__init__(options)


class TorchRunner:
    """The per-frame student in PyTorch; scores the uncertainty with ``samples`` > 0."""

    extra: NDArray[np.float32] | None = None

    def __init__(self, options: RunnerOptions) -> None:
        from weldpool_core.student.predict import StudentPredictor

        _torch_threads(options.threads)
        self._predictor = StudentPredictor.load(options.model_dir, options.device, batch_size=1)

    def run(self, batch: NDArray[np.float32], geometry: FrameGeometry, samples: int) -> Answer:
        import torch

        masks, heatmaps, parts, extra = self._predictor.outputs_all(
            torch.from_numpy(batch), samples, [geometry]
        )
        self.extra = None if extra is None else extra[0]
        part = parts[0]
        return masks[0], heatmaps[0], None if part is None else uncertainty_of(part)

    def reset(self) -> None:
        pass


class SequentialRunner:
    """The folder's sequential student, on ONNX Runtime or PyTorch, with its state (it draws
    the pool alone: no learned classes)."""

    extra: NDArray[np.float32] | None = None

    def __init__(self, options: RunnerOptions) -> None:
        from weldpool_core.student import sequential

        if not sequential.has_sequential(options.model_dir):
            raise InvalidInputError(
                f"{options.model_dir} has no sequential student; train one on videos of the "
                "camera first."
            )
        self._config = options.config
        self._state: Any = None
        self._session: Any = None
        self._model: Any = None
        if options.backend == "onnx":
            path = sequential.export_sequential_onnx(options.model_dir)
            self._session = onnx_session(path, options.threads, spin=options.spin)
        else:
            from weldpool_core.device import resolve_device

            _torch_threads(options.threads)
            device = resolve_device(options.device)
            self._model = sequential.load_sequential(options.model_dir, device)

    def run(self, batch: NDArray[np.float32], geometry: FrameGeometry, samples: int) -> Answer:
        _no_samples(
            samples, "The uncertainty is the per-frame student's, not the sequential one's."
        )
        if self._session is not None:
            return self._onnx_step(batch)
        import torch

        device = next(self._model.parameters()).device
        with torch.inference_mode():
            mask_logits, heat_logits, self._state = self._model.step(
                torch.from_numpy(batch).to(device), self._state
            )
        mask = torch.sigmoid(mask_logits)[0].float().cpu().numpy()
        return mask, torch.sigmoid(heat_logits)[0].float().cpu().numpy(), None

    def _onnx_step(self, batch: NDArray[np.float32]) -> Answer:
        cells = self._config.input_size // 32
        fresh = self._state is None
        state = (
            np.zeros((1, self._config.latent_channels, cells, cells), np.float32)
            if fresh
            else self._state
        )
        mask, heatmap, self._state = self._session.run(
            None,
            {
                "image": batch,
                "state": state,
                "fresh": np.full((1, 1, 1, 1), float(fresh), np.float32),
            },
        )
        return mask[0], heatmap[0], None

    def reset(self) -> None:
        self._state = None


RUNNERS: dict[str, Callable[[RunnerOptions], Runner]] = {
    "onnx": OnnxRunner,
    "int8": Int8Runner,
    "torch": TorchRunner,
    "sequential": SequentialRunner,
}
"""Each kind's runner (``runner_kind`` picks one)."""


def runner_kind(backend: str, sequential: bool, int8: bool) -> str:
    """The kind of runner a caller's choice names; InvalidInputError for one that cannot run."""
    if backend not in BACKENDS:
        raise InvalidInputError(f"Unknown backend {backend!r}; use onnx or torch.")
    if int8 and (backend != "onnx" or sequential):
        raise InvalidInputError(
            "The int8 student runs on ONNX Runtime, frame by frame: not with PyTorch, nor as a "
            "sequential student."
        )
    if sequential:
        return "sequential"
    return "int8" if int8 else backend


def open_runner(options: RunnerOptions, kind: str) -> Runner:
    return RUNNERS[kind](options)
