"""Training the student: frames in, a MODEL_DIR out (best checkpoint, metrics, curve).

``train_student`` is the one entry point: the CLI feeds it a DATASET folder (``read_dataset``),
the app's worker feeds it reviewed labels from memory. It prepares each frame once (targets at
model resolution), then trains with AdamW under a warm-up + cosine learning-rate schedule and
validates after every epoch on held-out frames, at full resolution, with mIoU and mED.

Loss = ``mask_bce``·BCE + ``mask_dice``·Dice on the mask logits + ``heatmap``·focal on the
heatmap logits + β·KL. The heatmap term is a quality focal loss (|y − p|²·BCE(p, y), summed and
divided by the target's mass): the Gaussians cover well under 1 % of the pixels, and an
unweighted loss would settle on an empty heatmap first. β ramps linearly from 0 to ``beta`` over
the first ``beta_warmup`` of the steps (KL annealing), so the decoder learns to use the latent
before the prior pulls on it.

Reproducible: the same frames, configuration and seed give the same weights on the same
machine (initial weights, shuffling, augmentation and latent noise all derive from the seed and
the epoch). Resumable: each epoch ends by saving the full state; ``resume=True`` continues after
the last saved epoch, and a run stopped and resumed ends with the weights of an uninterrupted
one. Cancellable: ``progress`` may raise; the exception propagates, and the folder keeps the
last finished epoch.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch
import torch.nn.functional as F
from numpy.typing import NDArray

from weldpool_core.device import resolve_device
from weldpool_core.errors import InvalidInputError
from weldpool_core.heatmap import HeatmapParams
from weldpool_core.io import to_rgb8
from weldpool_core.metrics import proposal_quality
from weldpool_core.student import checkpoint
from weldpool_core.student.data import (
    Augmentation,
    FrameSet,
    PreparedFrame,
    TrainingFrame,
    TrainingTargets,
    collate,
    prepare_frame,
    read_dataset,
)
from weldpool_core.student.model import (
    ResNetVAE,
    StudentConfig,
    build_student,
    channels_last,
    kl_divergence,
)
from weldpool_core.student.predict import to_frame

ProgressCallback = Callable[[float, str], None]
"""``(fraction done in [0, 1], message) -> None``; raising from it cancels the training."""

TrainingSample = TrainingFrame | tuple[NDArray[Any], NDArray[Any], NDArray[Any] | None]
"""A frame to learn from: a ``TrainingFrame`` or an ``(image, mask, keypoints or None)`` tuple."""

Selection = Literal["mED", "mIoU"]


@dataclass(frozen=True)
class LossWeights:
    """Weights of the loss terms (β, the KL weight, is in ``TrainConfig``)."""

    mask_bce: float = 1.0
    mask_dice: float = 1.0
    heatmap: float = 1.0


@dataclass(frozen=True)
class TrainConfig:
    """How the student is trained (the student's architecture is ``StudentConfig``).

    Attributes:
        epochs: passes over the training frames (the paper: 100 on a V100).
        batch_size: frames per optimiser step.
        learning_rate: AdamW's peak learning rate.
        weight_decay: AdamW's decoupled weight decay.
        warmup: fraction of the steps over which the learning rate rises linearly from 0;
            afterwards it follows a cosine down to ``final_lr`` × the peak.
        final_lr: the learning rate at the end, as a fraction of the peak.
        beta: the KL weight β after its warm-up.
        beta_warmup: fraction of the steps over which β rises linearly from 0 to ``beta``.
        losses: weights of the mask and heatmap terms.
        heatmap_sigma: smallest Gaussian spread of the heatmap target, in input pixels.
        augmentation: the random changes applied to training frames.
        validation_fraction: share of the frames held out for validation when no validation
            frames are given (at least 1; with a single frame it validates on that frame).
        selection: which validation score picks the best epoch: ``mED`` (default) or ``mIoU``.
            For the choice, a keypoint without a predicted partner, or on a frame whose predicted
            mask has IoU < 0.5, counts as the frame's diagonal (a model that draws the wrong
            pool is not rescued by a lucky keypoint).
        seed: seeds initial weights, data split, shuffling, augmentation and latent noise.
        device: ``cpu``, ``cuda``, ``cuda:N``, ``mps`` or ``auto`` (``device.resolve_device``).
    """

    epochs: int = 30
    batch_size: int = 8
    learning_rate: float = 3e-3
    weight_decay: float = 1e-4
    warmup: float = 0.05
    final_lr: float = 0.02
    beta: float = 1e-3
    beta_warmup: float = 0.3
    losses: LossWeights = field(default_factory=LossWeights)
    heatmap_sigma: float = 3.0
    augmentation: Augmentation = field(default_factory=Augmentation)
    validation_fraction: float = 0.1
    selection: Selection = "mED"
    seed: int = 0
    device: str = "auto"

    def __post_init__(self) -> None:
        problems = []
        if self.epochs < 1 or self.batch_size < 1:
            problems.append("epochs and batch_size must be at least 1")
        if self.learning_rate <= 0 or self.weight_decay < 0 or self.beta < 0:
            problems.append("learning_rate must be > 0, weight_decay and beta ≥ 0")
        if not 0 <= self.warmup < 1 or not 0 <= self.beta_warmup <= 1 or not 0 < self.final_lr <= 1:
            problems.append("warmup must lie in [0, 1), beta_warmup in [0, 1], final_lr in (0, 1]")
        if not 0 < self.validation_fraction < 1 or self.heatmap_sigma <= 0:
            problems.append("validation_fraction must lie in (0, 1) and heatmap_sigma be > 0")
        if self.selection not in ("mED", "mIoU"):
            problems.append(f"selection must be mED or mIoU, not {self.selection!r}")
        if problems:
            raise InvalidInputError(f"Bad training configuration: {'; '.join(problems)}.")

    def as_dict(self) -> dict[str, Any]:
        """A JSON-ready dict (stored in the MODEL_DIR's ``config.json``)."""
        return asdict(self)


@dataclass(frozen=True)
class EpochRecord:
    """One point of the training curve (losses are means over the epoch's batches)."""

    epoch: int
    loss: float
    mask_loss: float
    heatmap_loss: float
    kl: float
    beta: float
    learning_rate: float
    miou: float
    med: float | None
    med_k: list[float | None]
    missed: int
    score: float
    seconds: float

    def as_dict(self) -> dict[str, Any]:
        """The record as JSON-ready values."""
        return asdict(self)


@dataclass(frozen=True)
class TrainResult:
    """What a training run produced.

    Attributes:
        model_dir: the MODEL_DIR (``checkpoint`` describes its files).
        best_epoch: the epoch whose weights were kept (1-based).
        metrics: the best epoch's validation metrics (``mIoU``, ``mED``, ``mED_k``, ...).
        curve: one record per epoch, resumed epochs included.
        train_frames: frames trained on.
        validation_frames: frames validated on.
        pretrained_encoder: whether the encoder started from ImageNet weights.
    """

    model_dir: Path
    best_epoch: int
    metrics: dict[str, Any]
    curve: list[EpochRecord]
    train_frames: int
    validation_frames: int
    pretrained_encoder: bool


def _as_frame(sample: TrainingSample, index: int) -> TrainingFrame:
    if isinstance(sample, TrainingFrame):
        return sample
    image, mask, keypoints = sample
    points = None if keypoints is None else np.asarray(keypoints, np.float64)
    return TrainingFrame(to_rgb8(image), np.asarray(mask) != 0, points, f"#{index}")


def _prepare(
    samples: Iterable[TrainingSample],
    student: StudentConfig,
    report: Callable[[str], None],
    what: str,
) -> list[PreparedFrame]:
    heatmap = HeatmapParams(k=student.k)
    prepared = []
    for index, sample in enumerate(samples):
        frame = _as_frame(sample, index)
        prepared.append(prepare_frame(frame, student.input_size, student.aspect, heatmap))
        if (index + 1) % 50 == 0:
            report(f"prepared {index + 1} {what} frames")
    return prepared


def _split(
    frames: list[PreparedFrame], fraction: float, seed: int
) -> tuple[list[PreparedFrame], list[PreparedFrame]]:
    if len(frames) == 1:
        return frames, frames
    count = min(max(1, round(len(frames) * fraction)), len(frames) - 1)
    order = np.random.default_rng([seed, 7]).permutation(len(frames))
    held = set(order[:count].tolist())
    train = [f for i, f in enumerate(frames) if i not in held]
    return train, [frames[i] for i in sorted(held)]


def _schedule(config: TrainConfig, total_steps: int) -> Callable[[int], float]:
    warmup = max(1, round(config.warmup * total_steps))

    def factor(step: int) -> float:
        if step < warmup:
            return (step + 1) / warmup
        progress = min(1.0, (step - warmup) / max(1, total_steps - warmup))
        return config.final_lr + (1 - config.final_lr) * 0.5 * (1 + math.cos(math.pi * progress))

    return factor


def _beta(config: TrainConfig, step: int, total_steps: int) -> float:
    ramp = config.beta_warmup * total_steps
    return config.beta if ramp <= 0 else config.beta * min(1.0, step / ramp)


def dice_loss(logits: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """1 − soft Dice per frame, averaged over the batch (N×H×W logits and targets in [0, 1])."""
    probability = torch.sigmoid(logits).flatten(1)
    truth = target.flatten(1)
    overlap = (probability * truth).sum(1)
    return torch.mean(1 - (2 * overlap + 1) / (probability.sum(1) + truth.sum(1) + 1))


def heatmap_loss(logits: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Quality focal loss |y − p|²·BCE(p, y), summed and divided by the target's mass."""
    probability = torch.sigmoid(logits)
    bce = F.binary_cross_entropy_with_logits(logits, target, reduction="none")
    return (bce * (probability - target).abs().pow(2)).sum() / target.sum().clamp(min=1.0)


@dataclass
class _Losses:
    total: torch.Tensor
    mask: torch.Tensor
    heatmap: torch.Tensor
    kl: torch.Tensor


def student_loss(
    model: ResNetVAE,
    batch: TrainingTargets,
    weights: LossWeights,
    beta: float,
    generator: torch.Generator | None,
) -> _Losses:
    """The training loss of one batch (see the module doc), with its parts."""
    output = model(batch.image, sample=True, generator=generator)
    mask = weights.mask_bce * F.binary_cross_entropy_with_logits(
        output.mask_logits, batch.mask
    ) + weights.mask_dice * dice_loss(output.mask_logits, batch.mask)
    heat = weights.heatmap * heatmap_loss(output.heatmap_logits, batch.heatmap)
    kl = kl_divergence(output.mean, output.logvar)
    return _Losses(mask + heat + beta * kl, mask, heat, kl)


def validate(
    model: ResNetVAE, frames: Sequence[PreparedFrame], device: torch.device, batch_size: int
) -> dict[str, Any]:
    """``metrics.proposal_quality`` of the model's mean-latent outputs on ``frames``, at full
    resolution (``per_image`` left out)."""
    model.eval()
    scored: dict[str, tuple[NDArray[Any], Any, NDArray[Any], Any]] = {}
    with torch.inference_mode():
        for start in range(0, len(frames), batch_size):
            chunk = frames[start : start + batch_size]
            images = np.stack([f.image for f in chunk]).transpose(0, 3, 1, 2)
            batch = torch.from_numpy(images).to(device).float().div_(255.0)
            batch = batch.contiguous(memory_format=torch.channels_last)
            output = model(batch, sample=False)
            masks = torch.sigmoid(output.mask_logits).cpu().numpy()
            heatmaps = torch.sigmoid(output.heatmap_logits).cpu().numpy()
            for offset, frame in enumerate(chunk):
                found = to_frame(masks[offset], heatmaps[offset], frame.geometry, model.config.k)
                scored[f"{start + offset}:{frame.name}"] = (
                    found.mask,
                    found.keypoints,
                    frame.truth_mask(),
                    frame.frame_keypoints,
                )
    metrics = proposal_quality(scored)
    metrics.pop("per_image")
    return metrics


def _score(metrics: dict[str, Any], selection: Selection) -> float:
    """Lower is better."""
    if selection == "mIoU" or metrics["mED_penalised"] is None:
        return -float(metrics["mIoU"])
    return float(metrics["mED_penalised"])


def _epoch_seed(seed: int, epoch: int) -> int:
    return int(np.random.default_rng([seed, epoch, 3]).integers(2**62))


def _start(
    out_dir: Path, student: StudentConfig | None, config: TrainConfig, resume: bool
) -> tuple[StudentConfig, dict[str, Any] | None]:
    """The architecture to train and the state to resume from (None: a fresh start)."""
    if not resume:
        if (out_dir / checkpoint.CONFIG_FILE).exists():
            raise InvalidInputError(
                f"{out_dir} already holds a student model; resume it or train into another folder."
            )
        return student or StudentConfig(), None
    state = checkpoint.load_state(out_dir)
    if state is None:
        raise InvalidInputError(f"{out_dir} holds no training state to resume; train it afresh.")
    saved = checkpoint.read_student_config(out_dir)
    if student is not None and student != saved:
        raise InvalidInputError(
            f"{out_dir} was trained with another student configuration; resume it without "
            "changing the model options."
        )
    if int(state["epoch"]) >= config.epochs:
        raise InvalidInputError(
            f"{out_dir} has already trained {state['epoch']} epochs; ask for more than that."
        )
    return saved, state


def train_student(
    frames: Iterable[TrainingSample],
    out_dir: str | Path,
    student: StudentConfig | None = None,
    config: TrainConfig | None = None,
    progress: ProgressCallback | None = None,
    validation: Iterable[TrainingSample] | None = None,
    resume: bool = False,
) -> TrainResult:
    """Train a student on ``frames`` and write its MODEL_DIR to ``out_dir``.

    Args:
        frames: training frames, read once: ``TrainingFrame``s or ``(image, mask, keypoints)``
            tuples (image: any ``io`` frame, RGB uint8 preferred; mask: H×W, nonzero = pool;
            keypoints: k×2 or None for Algorithm 1's).
        out_dir: the MODEL_DIR to write (must not hold a model unless ``resume``).
        student: the architecture (default ``StudentConfig()``); with ``resume``, the saved one.
        config: the training settings (default ``TrainConfig()``).
        progress: called as ``progress(fraction, message)`` during preparation and after every
            batch; raise from it to cancel.
        validation: held-out frames; default: ``config.validation_fraction`` of ``frames``.
        resume: continue the run in ``out_dir`` after its last saved epoch.

    Returns:
        The best epoch, its metrics and the curve. Raises InvalidInputError for unusable input.
    """
    config = config or TrainConfig()
    root = Path(out_dir)
    student, state = _start(root, student, config, resume)
    report = progress or (lambda fraction, message: None)
    device = resolve_device(config.device)
    prepared = _prepare(frames, student, lambda m: report(0.0, m), "training")
    if not prepared:
        raise InvalidInputError("There are no frames to train on.")
    if validation is not None:
        train_frames = prepared
        held_out = _prepare(validation, student, lambda m: report(0.0, m), "validation")
        if not held_out:
            raise InvalidInputError("The validation set is empty.")
    else:
        train_frames, held_out = _split(prepared, config.validation_fraction, config.seed)

    torch.manual_seed(config.seed)
    built = build_student(student)
    model = channels_last(built.model.to(device))
    pretrained = built.pretrained
    optimizer = torch.optim.AdamW(
        model.parameters(), lr=config.learning_rate, weight_decay=config.weight_decay
    )
    steps_per_epoch = math.ceil(len(train_frames) / config.batch_size)
    total_steps = steps_per_epoch * config.epochs
    scheduler = torch.optim.lr_scheduler.LambdaLR(optimizer, _schedule(config, total_steps))
    curve: list[EpochRecord] = []
    best_score, best_epoch, best_metrics = math.inf, 0, {}
    first_epoch = 0
    if state is not None:
        model.load_state_dict(state["model"])
        optimizer.load_state_dict(state["optimizer"])
        scheduler.load_state_dict(state["scheduler"])
        curve = [EpochRecord(**record) for record in state["curve"]]
        best_score, best_epoch = float(state["best_score"]), int(state["best_epoch"])
        best_metrics, pretrained = dict(state["best_metrics"]), bool(state["pretrained"])
        first_epoch = int(state["epoch"])
    checkpoint.save_config(root, student, config.as_dict())

    dataset = FrameSet(train_frames, config.heatmap_sigma, config.augmentation, config.seed)
    for epoch in range(first_epoch, config.epochs):
        started = time.perf_counter()
        model.train()
        dataset.epoch = epoch
        generator = torch.Generator(device=device).manual_seed(_epoch_seed(config.seed, epoch))
        order = np.random.default_rng([config.seed, epoch, 1]).permutation(len(dataset))
        sums = np.zeros(4)
        beta = 0.0
        for index in range(steps_per_epoch):
            chosen = order[index * config.batch_size : (index + 1) * config.batch_size]
            batch = collate([dataset[int(i)] for i in chosen])
            batch = TrainingTargets(
                batch.image.to(device).contiguous(memory_format=torch.channels_last),
                batch.mask.to(device),
                batch.heatmap.to(device),
            )
            step = epoch * steps_per_epoch + index
            beta = _beta(config, step, total_steps)
            losses = student_loss(model, batch, config.losses, beta, generator)
            optimizer.zero_grad(set_to_none=True)
            losses.total.backward()  # type: ignore[no-untyped-call]
            optimizer.step()
            scheduler.step()
            parts = (losses.total, losses.mask, losses.heatmap, losses.kl)
            sums += [float(part.detach()) for part in parts]
            report(
                (epoch + (index + 1) / steps_per_epoch) / config.epochs,
                f"epoch {epoch + 1}/{config.epochs} loss {sums[0] / (index + 1):.4f}",
            )
        metrics = validate(model, held_out, device, config.batch_size)
        score = _score(metrics, config.selection)
        means = sums / steps_per_epoch
        record = EpochRecord(
            epoch=epoch + 1,
            loss=float(means[0]),
            mask_loss=float(means[1]),
            heatmap_loss=float(means[2]),
            kl=float(means[3]),
            beta=beta,
            learning_rate=float(scheduler.get_last_lr()[0]),
            miou=metrics["mIoU"],
            med=metrics["mED"],
            med_k=metrics["mED_k"],
            missed=metrics["missed"],
            score=score,
            seconds=time.perf_counter() - started,
        )
        curve.append(record)
        if score < best_score:
            best_score, best_epoch, best_metrics = score, epoch + 1, metrics
            checkpoint.save_weights(root, model)
        summary = {
            "best_epoch": best_epoch,
            "best": best_metrics,
            "last": metrics | {"epoch": epoch + 1},
            "selection": config.selection,
            "train_frames": len(train_frames),
            "validation_frames": len(held_out),
            "pretrained_encoder": pretrained,
            "notes": built.notes,
        }
        checkpoint.write_json(root / checkpoint.METRICS_FILE, summary)
        checkpoint.write_json(root / checkpoint.CURVE_FILE, [r.as_dict() for r in curve])
        checkpoint.save_state(
            root,
            {
                "epoch": epoch + 1,
                "model": model.state_dict(),
                "optimizer": optimizer.state_dict(),
                "scheduler": scheduler.state_dict(),
                "curve": [r.as_dict() for r in curve],
                "best_score": best_score,
                "best_epoch": best_epoch,
                "best_metrics": best_metrics,
                "pretrained": pretrained,
            },
        )
        med = "-" if metrics["mED"] is None else f"{metrics['mED']:.2f} px"
        report(
            (epoch + 1) / config.epochs,
            f"epoch {epoch + 1}/{config.epochs} mIoU {metrics['mIoU']:.3f} mED {med}",
        )
    return TrainResult(
        model_dir=root,
        best_epoch=best_epoch,
        metrics=best_metrics,
        curve=curve,
        train_frames=len(train_frames),
        validation_frames=len(held_out),
        pretrained_encoder=pretrained,
    )


def train_from_folder(
    dataset: str | Path,
    out_dir: str | Path,
    student: StudentConfig | None = None,
    config: TrainConfig | None = None,
    progress: ProgressCallback | None = None,
    resume: bool = False,
) -> TrainResult:
    """``train_student`` on a DATASET folder (CONTRACT.md), frames read one at a time."""
    return train_student(read_dataset(dataset), out_dir, student, config, progress, resume=resume)
