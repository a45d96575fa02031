"""The student from the command line: train on a DATASET folder (and its sequential cell on
videos), predict, export."""

from __future__ import annotations

import json
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import click

from app.cli.base import (
    IMAGE_SUFFIXES,
    fail,
    friendly_errors,
    image_files,
    load_settings,
    main,
    named_files,
)
from app.core.errors import WeldpoolError

MODEL_SIZES = ("resnet18", "resnet34", "light")


class _ProgressBar:
    """A stderr progress bar that appears at the first report (so that input errors found
    before any work stay one line), and the training callback that moves it."""

    def __init__(self) -> None:
        self.bar: Any = None
        self.shown = 0

    def __call__(self, fraction: float, message: str) -> None:
        if self.bar is None:
            self.bar = click.progressbar(length=1000, label=message, file=sys.stderr)
            self.bar.__enter__()
        target = min(1000, max(self.shown, round(fraction * 1000)))
        self.bar.label = message
        self.bar.update(target - self.shown)
        self.shown = target

    def close(self) -> None:
        if self.bar is not None:
            self.bar.__exit__(None, None, None)


def _given(ctx: click.Context, *names: str) -> bool:
    return any(
        ctx.get_parameter_source(name) is not click.core.ParameterSource.DEFAULT for name in names
    )


@main.command("train")
@click.argument("dataset", type=click.Path(path_type=Path))
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False, path_type=Path))
@click.option(
    "--steps",
    type=click.IntRange(min=1),
    help="Optimiser steps (default 800, at least 10 passes over large sets).",
)
@click.option(
    "--epochs",
    type=click.IntRange(min=1),
    help="Count the run in passes over the frames instead of steps.",
)
@click.option(
    "--model",
    "size",
    type=click.Choice(MODEL_SIZES),
    default="light",
    show_default=True,
    help="Model size: light (quarter-width ResNet18, the default: best from a few labels on a "
    "CPU), or the full ResNet18 / ResNet34 (ImageNet weights when present; for a GPU).",
)
@click.option("--input-size", type=click.IntRange(min=32), help="Square input side (×32).")
@click.option("--aspect", type=click.Choice(["letterbox", "resize"]), help="Frame → square input.")
@click.option(
    "--skips",
    type=click.IntRange(0, 3),
    help="Encoder maps (strides 16, 8, 4) fed to the decoder beside the latent (default 2).",
)
@click.option("--batch-size", default=8, show_default=True, type=click.IntRange(min=1))
@click.option("--learning-rate", default=3e-3, show_default=True, type=click.FloatRange(min=0))
@click.option("--seed", default=0, show_default=True, type=int)
@click.option("--resume", is_flag=True, help="Continue the run in --out after its last round.")
@click.option("--device", help="cpu, cuda, cuda:N, mps or auto (default: WELDPOOL_DEVICE).")
@click.option(
    "--encoder-weights",
    help="ImageNet ResNet weights: a save_pretrained folder or a hub id in the local cache.",
)
@click.option("--no-pretrained", is_flag=True, help="Start the encoder from random weights.")
@click.option(
    "--classes",
    "class_names",
    help="Other classes to learn beside the pool, comma-separated: classes/<class>/ masks or "
    "manifest.json points of DATASET (what the masks export writes).",
)
@click.pass_context
@friendly_errors
def train_cmd(
    ctx: click.Context,
    dataset: Path,
    out_dir: Path,
    steps: int | None,
    epochs: int | None,
    size: str,
    input_size: int | None,
    aspect: str | None,
    skips: int | None,
    batch_size: int,
    learning_rate: float,
    seed: int,
    resume: bool,
    device: str | None,
    encoder_weights: str | None,
    no_pretrained: bool,
    class_names: str | None,
) -> None:
    """Train a student on DATASET (images/, masks/, optional keypoints/) into --out.

    Keypoints come from keypoints/<stem>.json, else from Algorithm 1 on the mask. --classes
    wire,tip learns those classes too: classes/<class>/<stem>.png (a mask class),
    classes/<class>/<stem>_<n>.png (instances), the points of manifest.json's objects (a
    points class), as `weldpool export --format masks` writes them. Writes the best weights,
    config.json, metrics.json and curve.json; prints the best metrics as JSON.
    """
    from weldpool_core.student.folder import train_from_folder
    from weldpool_core.student.model import student_config
    from weldpool_core.student.train import TrainConfig

    settings = load_settings()
    model_options = ("size", "input_size", "aspect", "skips", "encoder_weights", "no_pretrained")
    student = None
    if not resume or _given(ctx, *model_options):
        changes: dict[str, Any] = {}
        if input_size is not None:
            changes["input_size"] = input_size
        if aspect is not None:
            changes["aspect"] = aspect
        if skips is not None:
            changes["skips"] = skips
        if encoder_weights is not None:
            changes["encoder_weights"] = encoder_weights
        if no_pretrained:
            changes["pretrained"] = False
        student = student_config(size, **changes)
    config = TrainConfig(
        epochs=epochs,
        batch_size=batch_size,
        learning_rate=learning_rate,
        seed=seed,
        device=device or settings.device,
    )
    if steps is not None:
        config = replace(config, steps=steps)
    bar = _ProgressBar()
    try:
        names = [n.strip() for n in (class_names or "").split(",") if n.strip()]
        result = train_from_folder(dataset, out_dir, student, config, bar, resume, names)
    finally:
        bar.close()
    summary = {
        "model_dir": str(result.model_dir),
        "best_epoch": result.best_epoch,
        "epochs": len(result.curve),
        "steps": result.curve[-1].step if result.curve else 0,
        "train_frames": result.train_frames,
        "validation_frames": result.validation_frames,
        "pretrained_encoder": result.pretrained_encoder,
        "metrics": result.metrics,
    }
    click.echo(json.dumps(summary, indent=2))
    click.echo(f"trained a student into {out_dir} (best epoch {result.best_epoch})", err=True)


@main.command("train-sequential")
@click.argument("model_dir", type=click.Path(file_okay=False, path_type=Path))
@click.argument("dataset", type=click.Path(path_type=Path))
@click.option(
    "--videos",
    required=True,
    type=click.Path(file_okay=False, path_type=Path),
    help="Folder of the videos the DATASET's frames come from (<video>.mp4 for <video>_f<index>).",
)
@click.option("--steps", type=click.IntRange(min=1), help="Optimiser steps (default 200).")
@click.option("--window", type=click.IntRange(min=2), help="Frames per window (default 8).")
@click.option("--seed", default=0, show_default=True, type=int)
@click.option("--device", help="cpu, cuda, cuda:N, mps or auto (default: WELDPOOL_DEVICE).")
@friendly_errors
def train_sequential_cmd(
    model_dir: Path,
    dataset: Path,
    videos: Path,
    steps: int | None,
    window: int | None,
    seed: int,
    device: str | None,
) -> None:
    """Train the sequential cell of the student in MODEL_DIR on labelled frames of videos.

    DATASET is a training folder (images/, masks/) whose stems name a video and a frame,
    <video>_f<index> (0-based); each labelled frame and the frames before it in
    --videos/<video>.mp4 make the training windows. The student itself is not changed; the
    cell is saved beside it and used by `weldpool stream --sequential`.
    """
    from weldpool_core.student.sequential import (
        SequentialConfig,
        dataset_clips,
        train_sequential,
    )

    settings = load_settings()
    if not model_dir.is_dir():
        fail(f"There is no student folder {str(model_dir)!r}.")
    config = SequentialConfig(seed=seed, device=device or settings.device)
    config = replace(config, steps=steps or config.steps, window=window or config.window)
    from weldpool_core.student.checkpoint import read_student_config

    clips = dataset_clips(dataset, videos, config, read_student_config(model_dir))
    bar = _ProgressBar()
    try:
        result = train_sequential(model_dir, clips, config, bar)
    finally:
        bar.close()
    summary = {
        "model_dir": str(result.model_dir),
        "windows": result.windows,
        "first_loss": round(result.first_loss, 4),
        "last_loss": round(result.last_loss, 4),
        "seconds": round(result.seconds, 1),
    }
    click.echo(json.dumps(summary, indent=2))
    click.echo(f"trained the sequential cell of {model_dir} on {result.windows} windows", err=True)


@main.command("predict")
@click.argument("model_dir", type=click.Path(path_type=Path))
@click.argument("images", nargs=-1, required=True)
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False, path_type=Path))
@click.option(
    "--samples",
    default=0,
    show_default=True,
    type=click.IntRange(min=0),
    help="Latent samples for the uncertainty score in each JSON (0: none).",
)
@click.option("--batch-size", default=16, show_default=True, type=click.IntRange(min=1))
@click.option("--device", help="cpu, cuda, cuda:N, mps or auto (default: WELDPOOL_DEVICE).")
@friendly_errors
def predict_cmd(
    model_dir: Path,
    images: tuple[str, ...],
    out_dir: Path,
    samples: int,
    batch_size: int,
    device: str | None,
) -> None:
    """Run a trained student on images (files or folders).

    Writes per image <stem>_mask.png (0 / 255), <stem>_heatmap.npy (H×W×2: heatmap, mask
    probability) and <stem>.json (keypoints in full-resolution pixels, and the uncertainty
    with --samples).
    """
    import numpy as np

    from weldpool_core.io import encode_mask_png, read_image, to_rgb8
    from weldpool_core.student.predict import StudentPredictor

    settings = load_settings()
    files = image_files(images)
    predictor = StudentPredictor.load(model_dir, device or settings.device, batch_size)
    out_dir.mkdir(parents=True, exist_ok=True)
    bar = _ProgressBar()  # appears after the first batch, so a bad first image stays one line
    try:
        for start in range(0, len(files), batch_size):
            chunk = files[start : start + batch_size]
            frames = []
            for path in chunk:
                try:
                    frames.append(to_rgb8(read_image(path, max_pixels=settings.max_image_pixels)))
                except WeldpoolError as exc:
                    fail(f"{path}: {exc.message}")
            for path, found in zip(chunk, predictor.predict(frames, samples), strict=True):
                (out_dir / f"{path.stem}_mask.png").write_bytes(encode_mask_png(found.mask))
                np.save(out_dir / f"{path.stem}_heatmap.npy", found.heatmap)
                record = {
                    "keypoints": found.keypoints.tolist(),
                    "uncertainty": found.uncertainty,
                    "samples": samples,
                    "width": int(found.mask.shape[1]),
                    "height": int(found.mask.shape[0]),
                    "image": str(path),
                    "model": str(model_dir),
                }
                (out_dir / f"{path.stem}.json").write_text(json.dumps(record, indent=2) + "\n")
            bar((start + len(chunk)) / len(files), "predict")
    finally:
        bar.close()
    click.echo(f"wrote student predictions for {len(files)} image(s) to {out_dir}", err=True)


@main.command("export-student")
@click.argument("model_dir", type=click.Path(path_type=Path))
@click.option(
    "--format",
    "formats",
    multiple=True,
    type=click.Choice(["onnx", "torchscript", "onnx-int8"]),
    help="Repeat for several; default onnx and torchscript. onnx-int8 needs --calibrate.",
)
@click.option(
    "--calibrate",
    "calibrate",
    multiple=True,
    metavar="PATH",
    help="For onnx-int8: frames of the camera (images, folders of them, or videos); repeat.",
)
@click.option(
    "--calibrate-frames",
    type=click.IntRange(min=4),
    default=64,
    show_default=True,
    help="For onnx-int8: how many frames, taken evenly from what --calibrate names.",
)
@friendly_errors
def export_cmd(
    model_dir: Path, formats: tuple[str, ...], calibrate: tuple[str, ...], calibrate_frames: int
) -> None:
    """Export a trained student as ONNX and/or TorchScript into MODEL_DIR, checked against
    PyTorch; prints the files and their largest difference as JSON.

    onnx-int8 quantizes model.onnx (int8 weights, uint8 activations; 1.5–3× faster on a
    CPU) with its ranges calibrated on real frames, and keeps it only when its masks agree with
    the float student's on frames it was not calibrated on (the report gives the agreement).
    """
    from weldpool_core.student.export import FORMATS, export_student

    wanted = formats or FORMATS
    if "onnx-int8" in wanted and not calibrate:
        fail("onnx-int8 needs frames of the camera to calibrate on: give --calibrate PATH.")
    if calibrate and "onnx-int8" not in wanted:
        fail("--calibrate is for --format onnx-int8.")
    images = _calibration_images(calibrate, calibrate_frames) if calibrate else []
    floats = [name for name in wanted if name != "onnx-int8"]
    result = export_student(model_dir, floats) if floats else None
    report: dict[str, Any] = {
        "files": {name: str(path) for name, path in (result.files if result else {}).items()},
        "max_abs_difference": result.differences if result else {},
    }
    if "onnx-int8" in wanted:
        from weldpool_core.student.quantize import quantize_student

        quantized = quantize_student(model_dir, images)
        report["files"]["onnx-int8"] = str(quantized.path)
        report["int8"] = quantized.as_dict()
    click.echo(json.dumps(report, indent=2))


def _calibration_images(paths: tuple[str, ...], count: int) -> list[Any]:
    """``count`` frames taken evenly from the images and videos PATHS name (folders expanded)."""
    from weldpool_core.io import read_image
    from weldpool_core.video import VIDEO_SUFFIXES, spread_evenly, spread_frames

    files = named_files(paths, IMAGE_SUFFIXES | VIDEO_SUFFIXES, "image or video", stem=str)
    stills = [p for p in files if p.suffix.lower() not in VIDEO_SUFFIXES]
    images = [read_image(p).pixels for p in spread_evenly(stills, count)]
    for video in (p for p in files if p.suffix.lower() in VIDEO_SUFFIXES):
        images += spread_frames(video, count)
    return spread_evenly(images, count)
