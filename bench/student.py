"""Benchmark the student sizes: FLOPs, the fp32 floor, inference and training speed.

Run: ``.venv/bin/python bench/student.py`` (about two minutes on 2 CPU threads; ``--threads``
to change, ``--accuracy`` to also train every size on the synthetic learning test, which takes
tens of minutes for the ResNet sizes on a CPU).

For each size: FLOPs of one frame (convolutions and matrix products, counted by
``torch.utils.flop_counter``, 2 per multiply-add); the floor, FLOPs divided by this machine's
fp32 matrix-multiply rate measured in the same run (a 2048² matmul); frames per second at batch
1 and 16 with PyTorch (BatchNorm folded, channels-last, inference mode, as ``StudentPredictor``
runs) and with ONNX Runtime (graph optimisation on, the same thread count), on the CPU and, when
one is present, on CUDA; training images per second (forward, backward and AdamW step at batch
8); each time the median of several runs. A second table shows what each inference speed-up
gives the default model at batch 1.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch
from floor import matmul_rate
from torch.utils.flop_counter import FlopCounterMode

from weldpool_core.student.data import TrainingTargets
from weldpool_core.student.export import StudentExport, export_onnx
from weldpool_core.student.losses import LossWeights, student_loss
from weldpool_core.student.model import (
    STUDENT_SIZES,
    ResNetVAE,
    build_student,
    channels_last,
    fuse_batchnorm,
)


def median_seconds(work: Callable[[], Any], repeats: int, warmup: int = 2) -> float:
    """Median wall time of ``work`` over ``repeats`` runs after ``warmup`` runs."""
    for _ in range(warmup):
        work()
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        work()
        times.append(time.perf_counter() - started)
    return statistics.median(times)


def frame_flops(model: ResNetVAE) -> int:
    """FLOPs of the deterministic student on one frame."""
    size = model.config.input_size
    with FlopCounterMode(display=False) as counter, torch.inference_mode():
        StudentExport(model)(torch.rand(1, 3, size, size))
    return int(counter.get_total_flops())


def inference_module(model: ResNetVAE, device: torch.device) -> StudentExport:
    """The student as ``StudentPredictor`` runs it: BN folded, channels-last, eval."""
    return StudentExport(channels_last(fuse_batchnorm(model.eval()).to(device))).eval()


def torch_fps(module: torch.nn.Module, size: int, batch: int, device: torch.device) -> float:
    """Frames per second of ``module`` at ``batch``."""
    images = torch.rand(batch, 3, size, size, device=device)
    images = images.contiguous(memory_format=torch.channels_last)

    def work() -> None:
        with torch.inference_mode():
            module(images)
        if device.type == "cuda":
            torch.cuda.synchronize()

    return batch / median_seconds(work, repeats=7 if batch == 1 else 3)


def onnx_session(path: Path, threads: int, level: str = "ORT_ENABLE_ALL") -> Any:
    """An ONNX Runtime CPU session with ``threads`` intra-op threads."""
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.graph_optimization_level = getattr(ort.GraphOptimizationLevel, level)
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    return ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])


def onnx_fps(session: Any, size: int, batch: int) -> float:
    """Frames per second of an ONNX Runtime session at ``batch``."""
    images = np.random.default_rng(0).random((batch, 3, size, size), dtype=np.float32)
    return batch / median_seconds(
        lambda: session.run(None, {"image": images}), repeats=7 if batch == 1 else 3
    )


def training_rate(model: ResNetVAE, device: torch.device, batch: int = 8) -> float:
    """Training images per second (forward, backward, AdamW step)."""
    model = channels_last(model.train().to(device))
    size = model.config.input_size
    optimizer = torch.optim.AdamW(model.parameters(), lr=1e-3)
    targets = TrainingTargets(
        torch.rand(batch, 3, size, size, device=device).contiguous(
            memory_format=torch.channels_last
        ),
        (torch.rand(batch, size, size, device=device) > 0.5).float(),
        torch.rand(batch, size, size, device=device) * 0.1,
    )

    def step() -> None:
        losses = student_loss(model, targets, LossWeights(), 1e-3, None)
        optimizer.zero_grad(set_to_none=True)
        losses.total.backward()
        optimizer.step()
        if device.type == "cuda":
            torch.cuda.synchronize()

    return batch / median_seconds(step, repeats=3, warmup=1)


def size_rows(threads: int, rate: float, devices: list[torch.device]) -> list[list[str]]:
    """One table row per model size and device."""
    rows = []
    for name, config in STUDENT_SIZES.items():
        model = build_student(config, load_pretrained=False).model.eval()
        flops = frame_flops(model)
        floor_ms = flops / rate * 1e3
        for device in devices:
            module = inference_module(build_student(config, load_pretrained=False).model, device)
            size = config.input_size
            fps1, fps16 = (torch_fps(module, size, b, device) for b in (1, 16))
            ort1 = ort16 = "-"
            if device.type == "cpu":
                with tempfile.TemporaryDirectory() as folder:
                    path = Path(folder) / "model.onnx"
                    export_onnx(model, path)
                    session = onnx_session(path, threads)
                    ort1 = f"{onnx_fps(session, size, 1):.1f}"
                    ort16 = f"{onnx_fps(session, size, 16):.1f}"
            train = training_rate(build_student(config, load_pretrained=False).model, device)
            rows.append(
                [
                    name,
                    device.type,
                    f"{size}²",
                    f"{flops / 1e9:.2f}",
                    f"{floor_ms:.1f}" if device.type == "cpu" else "-",
                    f"{fps1:.1f}",
                    f"{fps16:.1f}",
                    ort1,
                    ort16,
                    f"{train:.1f}",
                    f"{1e3 / fps1 / floor_ms:.2f}×" if device.type == "cpu" else "-",
                ]
            )
    return rows


def speedup_rows(threads: int) -> list[list[str]]:
    """What each inference speed-up gives the default model at batch 1 (CPU)."""
    config = STUDENT_SIZES["resnet18"]
    model = build_student(config, load_pretrained=False).model.eval()
    size = config.input_size
    images = torch.rand(1, 3, size, size)
    rows = []

    def plain() -> None:
        with torch.no_grad():
            model(images, sample=False)

    def inference() -> None:
        with torch.inference_mode():
            model(images, sample=False)

    rows.append(["eval + no_grad", f"{1e3 * median_seconds(plain, 7):.1f}"])
    rows.append(["+ inference_mode", f"{1e3 * median_seconds(inference, 7):.1f}"])
    last = channels_last(model)
    images = images.contiguous(memory_format=torch.channels_last)
    rows.append(["+ channels_last", f"{1e3 * median_seconds(inference, 7):.1f}"])
    model = fuse_batchnorm(last)
    rows.append(["+ BatchNorm folded (predictor)", f"{1e3 * median_seconds(inference, 7):.1f}"])
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "model.onnx"
        export_onnx(build_student(config, load_pretrained=False).model, path)
        for level in ("ORT_DISABLE_ALL", "ORT_ENABLE_BASIC", "ORT_ENABLE_ALL"):
            session = onnx_session(path, threads, level)
            rows.append([f"ONNX Runtime, {level}", f"{1e3 / onnx_fps(session, size, 1):.1f}"])
    return rows


def accuracy_rows() -> list[list[str]]:
    """Every size trained on the learning test's recipe; held-out mIoU and mED (slow)."""
    from weldpool_core.io import to_rgb8
    from weldpool_core.metrics import iou, keypoint_scores
    from weldpool_core.student.data import TrainingFrame
    from weldpool_core.student.predict import StudentPredictor
    from weldpool_core.student.train import TrainConfig, train_student
    from weldpool_core.synth import SynthParams, synth_frame

    params = SynthParams(width=256, height=160)
    frames = [
        TrainingFrame(to_rgb8(f.image), f.mask)
        for t in (0.0, 0.7, 1.4, 2.1)
        for f in (synth_frame(seed, params, t) for seed in range(75))
    ]
    held_out = [synth_frame(seed, params, 0.3) for seed in range(1000, 1040)]
    rows = []
    for name, config in STUDENT_SIZES.items():
        with tempfile.TemporaryDirectory() as folder:
            started = time.perf_counter()
            train_student(frames, Path(folder) / "m", config, TrainConfig(epochs=12, seed=0))
            seconds = time.perf_counter() - started
            found = StudentPredictor.load(Path(folder) / "m", "cpu").predict(
                [f.image for f in held_out]
            )
        pairs = list(zip(found, held_out, strict=True))
        miou = float(np.mean([iou(p.mask, f.mask) for p, f in pairs]))
        scores = keypoint_scores(
            {str(i): (p.keypoints, f.keypoints) for i, (p, f) in enumerate(pairs)}
        )
        med = "-" if scores.med is None else f"{scores.med:.2f}"
        rows.append([name, f"{miou:.3f}", med, str(scores.missed), f"{seconds:.0f}"])
    return rows


def print_table(header: list[str], rows: list[list[str]]) -> None:
    """A right-aligned plain-text table."""
    widths = [max(len(h), *(len(r[i]) for r in rows)) for i, h in enumerate(header)]
    print(" | ".join(h.rjust(w) for h, w in zip(header, widths, strict=True)))
    print("-+-".join("-" * w for w in widths))
    for row in rows:
        print(" | ".join(c.rjust(w) for c, w in zip(row, widths, strict=True)))
    print()


def main() -> None:
    """Print the tables."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--accuracy", action="store_true", help="also train every size (slow)")
    arguments = parser.parse_args()
    torch.set_num_threads(arguments.threads)
    rate = matmul_rate(repeats=7)
    devices = [torch.device("cpu")] + ([torch.device("cuda")] if torch.cuda.is_available() else [])
    print(
        f"student sizes, {arguments.threads} CPU threads; fp32 matmul rate {rate / 1e9:.0f} "
        "GFLOP/s (2048² matmul, median of 7); fps: median of 7 (batch 1) / 3 (batch 16) runs"
    )
    print_table(
        [
            "size",
            "device",
            "input",
            "GFLOP",
            "floor ms",
            "torch fps b1",
            "torch fps b16",
            "ORT fps b1",
            "ORT fps b16",
            "train img/s",
            "b1 / floor",
        ],
        size_rows(arguments.threads, rate, devices),
    )
    print("resnet18 at batch 1 on the CPU: what each speed-up gives (ms per frame, median of 7)")
    print_table(["setting", "ms"], speedup_rows(arguments.threads))
    if arguments.accuracy:
        print("held-out synthetic test (300 frames 256×160, 12 epochs, random encoder start)")
        print_table(["size", "mIoU", "mED px", "missed", "train s"], accuracy_rows())


if __name__ == "__main__":
    main()
