"""Training the student: frames in, a MODEL_DIR out (best checkpoint, metrics, curve).

``train_student`` is the one entry point: the CLI feeds it a DATASET folder (``folder``),
the app's worker feeds it reviewed labels from memory. It prepares each frame once (targets at
model resolution), then trains with AdamW under a warm-up + cosine learning-rate schedule and
validates at regular intervals ("evaluation rounds") on held-out frames, at full resolution,
with ``metrics.proposal_quality``; the round with the best score is kept.

Schedule: counted in optimiser steps by default (``TrainConfig.steps``, and at least
``min_epochs`` passes over a large set), because a few labelled frames need many more steps
than epochs: 6 frames at batch 8 make one step per epoch. Batches are drawn from a stream of
shuffled passes over the frames, so every step sees a full batch of differently augmented
frames; the run is cut into ``rounds`` evaluation rounds. With ``epochs`` set, the run counts
epochs instead (one round per epoch, the last batch of an epoch may be partial).

Loss = ``mask_bce``·BCE + ``mask_dice``·Dice on the mask logits + ``heatmap``·focal on the
heatmap logits + β·KL. The heatmap term is a quality focal loss (|y − p|²·BCE(p, y), summed and
divided by the target's mass): the Gaussians cover well under 1 % of the pixels, and an
unweighted loss would settle on an empty heatmap first. β ramps linearly from 0 to ``beta`` over
the first ``beta_warmup`` of the steps (KL annealing), so the decoder learns to use the latent
before the prior pulls on it.

Round choice (``_score``): with ``selection="mED"`` the score is ``mED_penalised`` (a keypoint
on a frame with IoU < 0.5 counts as the diagonal) plus ``IOU_TIE_BREAK_PX`` × (1 − mIoU), so
that while no validation frame clears the IoU floor (every round's ``mED_penalised`` the same)
the rounds are still ranked by mIoU and an untrained first round is never kept over a better
later one.

Reproducible: the same frames, configuration and seed give the same weights on the same
machine (initial weights, shuffling, augmentation and latent noise all derive from the seed,
the pass and the round). Resumable: each round ends by saving the full state; ``resume=True``
continues after the last saved round, and a run stopped and resumed ends with the weights of an
uninterrupted one. Cancellable: ``progress`` may raise; the exception propagates, and the
folder keeps the last finished round. After the last round, the kept weights' latent codes of
the training frames are saved for the predictor's novelty score (``uncertainty``).
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
from numpy.typing import NDArray

from weldpool_core.device import resolve_device
from weldpool_core.errors import InvalidInputError
from weldpool_core.heatmap import HeatmapParams
from weldpool_core.io import to_rgb8
from weldpool_core.student import checkpoint
from weldpool_core.student.data import (
    Augmentation,
    FrameSet,
    PreparedFrame,
    TrainingFrame,
    collate,
    prepare_frame,
)
from weldpool_core.student.losses import LossWeights, student_loss
from weldpool_core.student.model import (
    ResNetVAE,
    StudentConfig,
    build_student,
    channels_last,
)
from weldpool_core.student.predict import (
    FOREIGN_FRAMES,
    TrainingCodes,
    familiar_distance,
    foreign_versions,
    frame_codes,
)
from weldpool_core.student.validation import to_device, validate

ProgressCallback = Callable[[float, str], None]
"""``(fraction done in [0, 1], message) -> None``; raising from it cancels the training."""

TrainingSample = TrainingFrame | tuple[NDArray[Any], NDArray[Any], NDArray[Any] | None]
"""A frame to learn from: a ``TrainingFrame`` or an ``(image, mask, keypoints or None)`` tuple."""

Selection = Literal["mED", "mIoU"]


IOU_TIE_BREAK_PX = 10.0
"""Pixels of ``mED_penalised`` that one unit of 1 − mIoU is worth in the round choice (0.01 of
mIoU ≈ 0.1 px): enough to rank rounds whose keypoint score ties, too little to override a
real keypoint improvement."""


@dataclass(frozen=True)
class TrainConfig:
    """How the student is trained (the student's architecture is ``StudentConfig``).

    Attributes:
        epochs: None (default) counts the run in optimiser steps (``steps``); a number trains
            that many passes over the frames instead, validating after each (the paper: 100 on
            a V100).
        steps: optimiser steps of a run counted in steps (default 800: what 5–50 frames need
            on a CPU in a few minutes with the default student).
        min_epochs: a run counted in steps makes at least this many passes over the frames
            (large sets train longer than ``steps``).
        rounds: evaluation rounds of a run counted in steps (validation after each).
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
            frames are given (at least 1), once there are ``min_split_frames`` frames; with
            fewer, every frame trains and validation runs on the training frames themselves
            (unaugmented): training on one frame of two and validating on the other wastes
            half the labels.
        min_split_frames: fewest frames for which a validation split is held out (default 3).
        selection: which validation score picks the best round: ``mED`` (default) or ``mIoU``.
            For the choice, a keypoint without a predicted partner, or on a frame whose predicted
            mask has IoU < 0.5, counts as the frame's diagonal (a model that draws the wrong
            pool is not rescued by a lucky keypoint), and mIoU breaks ties (see the module doc).
        seed: seeds initial weights, data split, shuffling, augmentation and latent noise.
        device: ``cpu``, ``cuda``, ``cuda:N``, ``mps`` or ``auto`` (``device.resolve_device``).
    """

    epochs: int | None = None
    steps: int = 800
    min_epochs: int = 10
    rounds: int = 20
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
    min_split_frames: int = 3
    selection: Selection = "mED"
    seed: int = 0
    device: str = "auto"

    def __post_init__(self) -> None:
        problems = []
        if (self.epochs is not None and self.epochs < 1) or self.batch_size < 1:
            problems.append("epochs (when given) and batch_size must be at least 1")
        if self.steps < 1 or self.rounds < 1 or self.min_epochs < 0 or self.min_split_frames < 2:
            problems.append(
                "steps and rounds must be at least 1, min_epochs at least 0, "
                "min_split_frames at least 2"
            )
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

    def plan(self, frames: int) -> Plan:
        """The run's steps and evaluation rounds for ``frames`` training frames."""
        per_epoch = math.ceil(frames / self.batch_size)
        if self.epochs is not None:
            ends = tuple(per_epoch * (epoch + 1) for epoch in range(self.epochs))
            return Plan(per_epoch * self.epochs, ends, per_epoch)
        total = max(self.steps, self.min_epochs * per_epoch)
        rounds = min(self.rounds, total)
        return Plan(total, tuple(round(total * (r + 1) / rounds) for r in range(rounds)), None)

    def as_dict(self) -> dict[str, Any]:
        """A JSON-ready dict (stored in the MODEL_DIR's ``config.json``)."""
        return asdict(self)


@dataclass(frozen=True)
class Plan:
    """A run's schedule: optimiser steps, the step count at the end of each evaluation round,
    and steps per epoch when the run counts epochs (None: a stream of full batches)."""

    total_steps: int
    round_ends: tuple[int, ...]
    steps_per_epoch: int | None

    @property
    def rounds(self) -> int:
        """Evaluation rounds (epochs when the run counts epochs)."""
        return len(self.round_ends)


@dataclass(frozen=True)
class EpochRecord:
    """One point of the training curve: an evaluation round (an epoch when the run counts
    epochs); losses are means over the round's batches, ``step`` the optimiser steps done."""

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
    step: int = 0

    def as_dict(self) -> dict[str, Any]:
        """The record as JSON-ready values."""
        return asdict(self)


@dataclass(frozen=True)
class TrainResult:
    """What a training run produced.

    Attributes:
        model_dir: the MODEL_DIR (``checkpoint`` describes its files).
        best_epoch: the evaluation round (epoch) whose weights were kept (1-based).
        metrics: the best round's validation metrics (``mIoU``, ``mED``, ``mED_k``, ...).
        curve: one record per round, resumed rounds included.
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


def as_training_frame(sample: TrainingSample, index: int) -> TrainingFrame:
    """A sample as a ``TrainingFrame`` (a tuple's image made RGB uint8, named ``#index``)."""
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
        frame = as_training_frame(sample, index)
        size, aspect = student.input_size, student.aspect
        prepared.append(prepare_frame(frame, size, aspect, heatmap, student.classes))
        if (index + 1) % 50 == 0:
            report(f"prepared {index + 1} {what} frames")
    return prepared


def _split(
    frames: list[PreparedFrame], config: TrainConfig
) -> tuple[list[PreparedFrame], list[PreparedFrame]]:
    if len(frames) < config.min_split_frames:
        return frames, frames
    count = min(max(1, round(len(frames) * config.validation_fraction)), len(frames) - 1)
    order = np.random.default_rng([config.seed, 7]).permutation(len(frames))
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


MAX_CODES = 512
"""Most training frames whose descriptors are kept for the novelty score (evenly spaced)."""


def save_training_codes(
    root: Path, frames: Sequence[PreparedFrame], device: torch.device, batch_size: int
) -> None:
    """The kept weights' descriptors (``predict.frame_codes``) of up to ``MAX_CODES`` training
    frames, unaugmented, and the student's familiar distance, measured on the
    ``predict.foreign_versions`` of ``FOREIGN_FRAMES`` of them (``checkpoint.save_codes``; the
    predictor's novelty score)."""
    model = checkpoint.load_student(root, device)

    def descriptors(images: NDArray[np.uint8], foreign: bool = False) -> torch.Tensor:
        codes = []
        with torch.inference_mode():
            for start in range(0, len(images), batch_size):
                chunk = images[start : start + batch_size].transpose(0, 3, 1, 2)
                batch = torch.from_numpy(chunk).to(device).float().div_(255.0)
                if foreign:
                    batch = foreign_versions(batch)
                features = model.features(batch.contiguous(memory_format=torch.channels_last))
                codes.append(frame_codes(features).cpu())
        return torch.cat(codes)

    def evenly(count: int) -> NDArray[np.uint8]:
        chosen = np.unique(np.linspace(0, len(frames) - 1, min(len(frames), count)).round())
        return np.stack([frames[int(i)].image for i in chosen])

    codes = descriptors(evenly(MAX_CODES))
    foreign = descriptors(evenly(FOREIGN_FRAMES), foreign=True)
    familiar = familiar_distance(TrainingCodes.from_codes(codes), foreign)
    checkpoint.save_codes(root, codes, familiar)


def _score(metrics: dict[str, Any], selection: Selection) -> float:
    """The round-choice score of validation metrics (lower is better; see the module doc)."""
    if selection == "mIoU" or metrics["mED_penalised"] is None:
        return -float(metrics["mIoU"])
    return float(metrics["mED_penalised"]) + IOU_TIE_BREAK_PX * (1.0 - float(metrics["mIoU"]))


def _round_seed(seed: int, round_index: int) -> int:
    return int(np.random.default_rng([seed, round_index, 3]).integers(2**62))


def batch_draws(
    plan: Plan, frames: int, batch_size: int, seed: int, step: int
) -> list[tuple[int, int]]:
    """The ``(pass, frame index)`` pairs of optimiser step ``step`` (0-based).

    Counting epochs, step s is a slice of epoch s // steps_per_epoch's shuffled order (the
    last one may be short); counting steps, it is the next ``batch_size`` places of a stream
    of shuffled passes, so that every batch is full even with fewer frames than a batch. The
    pass seeds the frame's augmentation draw.
    """

    def order(index: int) -> NDArray[np.int64]:
        return np.random.default_rng([seed, index, 1]).permutation(frames)

    if plan.steps_per_epoch is not None:
        epoch, index = divmod(step, plan.steps_per_epoch)
        chosen = order(epoch)[index * batch_size : (index + 1) * batch_size]
        return [(epoch, int(i)) for i in chosen]
    draws = []
    for place in range(step * batch_size, (step + 1) * batch_size):
        pass_index, offset = divmod(place, frames)
        draws.append((pass_index, int(order(pass_index)[offset])))
    return draws


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
    if config.epochs is not None and int(state["epoch"]) >= config.epochs:
        raise InvalidInputError(
            f"{out_dir} has already trained {state['epoch']} epochs; ask for more than that."
        )
    return saved, state


@dataclass
class _Run:
    """One training run's state: the model, its optimiser and schedule, the curve so far and
    the best round (what ``checkpoint.save_state`` keeps to resume)."""

    model: ResNetVAE
    optimizer: torch.optim.Optimizer
    scheduler: torch.optim.lr_scheduler.LambdaLR
    pretrained: bool
    notes: list[str]
    curve: list[EpochRecord] = field(default_factory=list)
    best_score: float = math.inf
    best_round: int = 0
    best_metrics: dict[str, Any] = field(default_factory=dict)
    first_round: int = 0

    def state(self, rounds_done: int) -> dict[str, Any]:
        return {
            "epoch": rounds_done,
            "model": self.model.state_dict(),
            "optimizer": self.optimizer.state_dict(),
            "scheduler": self.scheduler.state_dict(),
            "curve": [r.as_dict() for r in self.curve],
            "best_score": self.best_score,
            "best_epoch": self.best_round,
            "best_metrics": self.best_metrics,
            "pretrained": self.pretrained,
        }


def _open_run(
    student: StudentConfig,
    config: TrainConfig,
    total_steps: int,
    state: dict[str, Any] | None,
    device: torch.device,
) -> _Run:
    """A fresh run (seeded), or the saved one to resume."""
    torch.manual_seed(config.seed)
    built = build_student(student)
    model = channels_last(built.model.to(device))
    optimizer = torch.optim.AdamW(
        model.parameters(), lr=config.learning_rate, weight_decay=config.weight_decay
    )
    scheduler = torch.optim.lr_scheduler.LambdaLR(optimizer, _schedule(config, total_steps))
    run = _Run(model, optimizer, scheduler, built.pretrained, built.notes)
    if state is not None:
        model.load_state_dict(state["model"])
        optimizer.load_state_dict(state["optimizer"])
        scheduler.load_state_dict(state["scheduler"])
        run.curve = [EpochRecord(**record) for record in state["curve"]]
        run.best_score, run.best_round = float(state["best_score"]), int(state["best_epoch"])
        run.best_metrics, run.pretrained = dict(state["best_metrics"]), bool(state["pretrained"])
        run.first_round = int(state["epoch"])
    return run


def _frame_sets(
    frames: Iterable[TrainingSample],
    validation: Iterable[TrainingSample] | None,
    student: StudentConfig,
    config: TrainConfig,
    report: ProgressCallback,
) -> tuple[list[PreparedFrame], list[PreparedFrame]]:
    """The prepared training and validation frames (validation split off when not given)."""
    prepared = _prepare(frames, student, lambda m: report(0.0, m), "training")
    if not prepared:
        raise InvalidInputError("There are no frames to train on.")
    if validation is None:
        return _split(prepared, config)
    held_out = _prepare(validation, student, lambda m: report(0.0, m), "validation")
    if not held_out:
        raise InvalidInputError("The validation set is empty.")
    return prepared, held_out


def _train_round(
    run: _Run,
    dataset: FrameSet,
    plan: Plan,
    config: TrainConfig,
    round_index: int,
    device: torch.device,
    report: ProgressCallback,
) -> tuple[NDArray[np.float64], float]:
    """One round (an epoch, or a share of the steps) of optimiser steps: the mean losses
    (total, mask, heatmap, KL) and the last β."""
    run.model.train()
    generator = torch.Generator(device=device).manual_seed(_round_seed(config.seed, round_index))
    first_step = plan.round_ends[round_index - 1] if round_index else 0
    last_step = plan.round_ends[round_index]
    unit = "epoch" if config.epochs is not None else "round"
    sums = np.zeros(4)
    beta = 0.0
    for step in range(first_step, last_step):
        draws = batch_draws(plan, len(dataset), config.batch_size, config.seed, step)
        batch = to_device(collate([dataset.draw(index, n) for n, index in draws]), device)
        beta = _beta(config, step, plan.total_steps)
        losses = student_loss(run.model, batch, config.losses, beta, generator)
        run.optimizer.zero_grad(set_to_none=True)
        losses.total.backward()  # type: ignore[no-untyped-call]
        run.optimizer.step()
        run.scheduler.step()
        parts = (losses.total, losses.mask, losses.heatmap, losses.kl)
        sums += [float(part.detach()) for part in parts]
        report(
            (step + 1) / plan.total_steps,
            f"{unit} {round_index + 1}/{plan.rounds} loss {sums[0] / (step - first_step + 1):.3g}",
        )
    return sums / max(1, last_step - first_step), beta


def _round_record(
    run: _Run,
    metrics: dict[str, Any],
    score: float,
    means: NDArray[np.float64],
    beta: float,
    round_index: int,
    last_step: int,
    seconds: float,
) -> EpochRecord:
    return EpochRecord(
        epoch=round_index + 1,
        loss=float(means[0]),
        mask_loss=float(means[1]),
        heatmap_loss=float(means[2]),
        kl=float(means[3]),
        beta=beta,
        learning_rate=float(run.scheduler.get_last_lr()[0]),
        miou=metrics["mIoU"],
        med=metrics["mED"],
        med_k=metrics["mED_k"],
        missed=metrics["missed"],
        score=score,
        seconds=seconds,
        step=last_step,
    )


def _save_round(
    root: Path,
    run: _Run,
    metrics: dict[str, Any],
    config: TrainConfig,
    plan: Plan,
    frames: tuple[list[PreparedFrame], list[PreparedFrame]],
    round_index: int,
) -> None:
    """The checkpoint saver after a round: the metrics, the curve and the state to resume."""
    train_frames, held_out = frames
    last_step = plan.round_ends[round_index]
    summary = {
        "best_epoch": run.best_round,
        "best": run.best_metrics,
        "last": metrics | {"epoch": round_index + 1, "step": last_step},
        "selection": config.selection,
        "steps": plan.total_steps,
        "rounds": plan.rounds,
        "train_frames": len(train_frames),
        "validation_frames": len(held_out),
        "validated_on_training_frames": held_out is train_frames,
        "pretrained_encoder": run.pretrained,
        "notes": run.notes,
    }
    checkpoint.write_json(root / checkpoint.METRICS_FILE, summary)
    checkpoint.write_json(root / checkpoint.CURVE_FILE, [r.as_dict() for r in run.curve])
    checkpoint.save_state(root, run.state(round_index + 1))


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
    train_frames, held_out = _frame_sets(frames, validation, student, config, report)
    plan = config.plan(len(train_frames))
    if state is not None and int(state["epoch"]) >= plan.rounds:
        raise InvalidInputError(
            f"{root} has already finished its {plan.rounds} rounds ({plan.total_steps} steps); "
            "ask for more steps than that."
        )
    run = _open_run(student, config, plan.total_steps, state, device)
    checkpoint.save_config(root, student, config.as_dict())
    unit = "epoch" if config.epochs is not None else "round"
    dataset = FrameSet(train_frames, config.heatmap_sigma, config.augmentation, config.seed)
    for round_index in range(run.first_round, plan.rounds):
        started = time.perf_counter()
        means, beta = _train_round(run, dataset, plan, config, round_index, device, report)
        metrics = validate(run.model, held_out, device, config.batch_size)
        score = _score(metrics, config.selection)
        last_step = plan.round_ends[round_index]
        seconds = time.perf_counter() - started
        run.curve.append(
            _round_record(run, metrics, score, means, beta, round_index, last_step, seconds)
        )
        if score < run.best_score:
            run.best_score, run.best_round, run.best_metrics = score, round_index + 1, metrics
            checkpoint.save_weights(root, run.model)
        _save_round(root, run, metrics, config, plan, (train_frames, held_out), round_index)
        med = "–" if metrics["mED"] is None else f"{metrics['mED']:.1f} px"
        report(
            last_step / plan.total_steps,
            f"{unit} {round_index + 1}/{plan.rounds} mIoU {metrics['mIoU']:.3f} mED {med}",
        )
    save_training_codes(root, train_frames, device, config.batch_size)
    return TrainResult(
        model_dir=root,
        best_epoch=run.best_round,
        metrics=run.best_metrics,
        curve=run.curve,
        train_frames=len(train_frames),
        validation_frames=len(held_out),
        pretrained_encoder=run.pretrained,
    )
