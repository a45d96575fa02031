"""Training the cell: windows ending at labelled frames under a synthetic drift, and the
steadiness term on unlabelled windows."""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from numpy.typing import NDArray

from weldpool_core.device import resolve_device
from weldpool_core.errors import InvalidInputError
from weldpool_core.heatmap import HeatmapParams
from weldpool_core.student import checkpoint
from weldpool_core.student.data import (
    FrameGeometry,
    PreparedFrame,
    TrainingFrame,
    photometric,
    prepare_frame,
    random_affine,
    render_heatmap,
    warp_targets,
)
from weldpool_core.student.sequential.checkpoint import save_cell
from weldpool_core.student.sequential.config import SequentialConfig
from weldpool_core.student.sequential.data import LabelledClip
from weldpool_core.student.sequential.model import LatentCell, SequentialStudent


@dataclass(frozen=True)
class SequentialResult:
    """What ``train_sequential`` produced: the folder, the loss at the start and the end, the
    windows it learned from and the seconds it took."""

    model_dir: Path
    first_loss: float
    last_loss: float
    windows: int
    seconds: float


@dataclass
class Window:
    inputs: list[NDArray[np.uint8]]  # S×S×3 RGB, oldest first
    target: PreparedFrame  # the labelled frame (for an unlabelled window: a blank one)
    labelled: bool = True


def clip_windows(
    clips: Sequence[LabelledClip],
    config: SequentialConfig,
    student: Any,
    require_labelled: bool = True,
) -> list[Window]:
    """Every (labelled frame, stride) window at model resolution, then the unlabelled windows
    (``labelled`` False; their target is a blank frame's, for the geometry), the frames read
    once."""
    heatmap = HeatmapParams(k=student.k)
    cache: dict[tuple[int, int], NDArray[np.uint8]] = {}

    def placed(number: int, clip: LabelledClip, index: int, geometry: FrameGeometry) -> Any:
        key = (number, index)
        if key not in cache:
            frame = clip.frames(index)
            cache[key] = frame if clip.placed is not None else geometry.image_to_input(frame)
        return cache[key]

    windows = []
    for number, clip in enumerate(clips):
        if clip.placed is not None:
            fitted = FrameGeometry.fit(
                clip.placed.height, clip.placed.width, student.input_size, student.aspect
            )
            if fitted != clip.placed:
                raise InvalidInputError(
                    f"The frames of {clip.name} were kept for a {clip.placed.size}² input; "
                    f"this student's is {student.input_size}² ({student.aspect})."
                )
        for index, label in sorted(clip.labels.items()):
            target = prepare_frame(label, student.input_size, student.aspect, heatmap)
            for stride in config.strides:
                first = index - stride * (config.window - 1)
                if first < 0 or index >= clip.length:
                    continue
                inputs = [
                    placed(number, clip, i, target.geometry)
                    for i in range(first, index + 1, stride)
                ]
                windows.append(Window(inputs, target))
        if not clip.unlabelled:
            continue
        if clip.placed is None:
            shape = clip.frames(clip.unlabelled[0]).shape[:2]
        else:
            shape = (clip.placed.height, clip.placed.width)
        blank = TrainingFrame(
            np.zeros((*shape, 3), np.uint8), np.zeros(shape, np.bool_), name=clip.name
        )
        geometry_of = prepare_frame(blank, student.input_size, student.aspect, heatmap)
        for end in clip.unlabelled:
            inputs = [
                placed(number, clip, i, geometry_of.geometry)
                for i in range(end - config.window + 1, end + 1)
            ]
            windows.append(Window(inputs, geometry_of, labelled=False))
    if require_labelled and not any(w.labelled for w in windows):
        raise InvalidInputError(
            f"No labelled frame has {config.window - 1} frames before it at stride "
            f"{min(config.strides)}; label frames further into the videos."
        )
    return windows


def _example(
    window: Window, config: SequentialConfig, rng: np.random.Generator
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """One augmented window: T×3×S×S inputs in [0, 1], T×S×S mask and heatmap targets (of the
    labelled frame; meaningless for an unlabelled window), and its drift (x, y) in input px
    per frame."""
    target = window.target
    size = target.image.shape[0]
    base = random_affine(rng, size, config.augmentation) if config.augmentation.enabled else None
    velocity = rng.uniform(-config.drift, config.drift, 2) * size
    steps = len(window.inputs)
    images, masks, heats = [], [], []
    mask0 = target.mask.astype(np.float32) / 255.0
    for t, frame in enumerate(window.inputs):
        matrix = np.eye(3)[:2].copy() if base is None else base.copy()
        matrix[:, 2] += velocity * (t - (steps - 1))
        image, mask, points, covariances = warp_targets(
            frame.astype(np.float32), mask0, target.keypoints, target.covariances, matrix
        )
        if config.augmentation.enabled:
            image = photometric(image, rng, config.augmentation)
        heat = render_heatmap(points, covariances, mask, config.heatmap_sigma)
        images.append(np.clip(image, 0, 255).transpose(2, 0, 1) / np.float32(255))
        masks.append(mask)
        heats.append(heat)
    return (
        torch.from_numpy(np.stack(images).astype(np.float32)),
        torch.from_numpy(np.stack(masks)),
        torch.from_numpy(np.stack(heats)),
        torch.from_numpy(velocity.astype(np.float32)),
    )


def _loss(
    mask_logits: torch.Tensor, heat_logits: torch.Tensor, mask: torch.Tensor, heat: torch.Tensor
) -> torch.Tensor:
    from weldpool_core.student.losses import dice_loss, heatmap_loss

    bce = F.binary_cross_entropy_with_logits(mask_logits, mask)
    return bce + dice_loss(mask_logits, mask) + heatmap_loss(heat_logits, heat)


@dataclass(frozen=True)
class WindowCodes:
    """The frozen student's encoding of N windows of T frames: latent means (N×T×C×h×w) and
    the encoder maps its decoder takes with them (each N×T×…; none unless ``skips``)."""

    latents: torch.Tensor
    skips: tuple[torch.Tensor, ...]

    def step(self, t: int) -> tuple[torch.Tensor, tuple[torch.Tensor, ...]]:
        """Step ``t``'s latents (N×C×h×w) and skip maps."""
        return self.latents[:, t], tuple(s[:, t] for s in self.skips)

    def frames(self, first: int = 0) -> tuple[torch.Tensor, tuple[torch.Tensor, ...]]:
        """Steps ``first`` on, flattened to frames: latents ((N·T′)×C×h×w) and skip maps."""
        return self.latents[:, first:].flatten(0, 1), tuple(
            s[:, first:].flatten(0, 1) for s in self.skips
        )


def encode_windows(model: SequentialStudent, images: torch.Tensor) -> WindowCodes:
    """The frozen student's encoding of N windows of T frames (N×T×3×S×S)."""
    count, steps = images.shape[:2]
    with torch.no_grad():
        flat = images.flatten(0, 1).contiguous(memory_format=torch.channels_last)
        mean, _, skips = model.student.encode(flat)
    return WindowCodes(
        mean.reshape(count, steps, *mean.shape[1:]),
        tuple(s.reshape(count, steps, *s.shape[1:]) for s in skips),
    )


def unroll(
    model: SequentialStudent,
    images: torch.Tensor,
    first: int = 0,
    codes: WindowCodes | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Mask and heatmap logits (N×(T − first)×S×S) of N windows of T frames (N×T×3×S×S), in
    order, from step ``first`` on (training skips step 0: without a past the cell is the
    identity, so decoding it teaches nothing). ``codes``: the windows' ``encode_windows``
    when already at hand."""
    codes = encode_windows(model, images) if codes is None else codes
    state = None
    masks, heats = [], []
    for t in range(codes.latents.shape[1]):
        latent, skips = codes.step(t)
        state = model.cell(latent, state)
        if t < first:
            continue
        mask_logits, heat_logits = model.student.decode(state, skips)
        masks.append(mask_logits)
        heats.append(heat_logits)
    return torch.stack(masks, 1), torch.stack(heats, 1)


def _batch(
    windows: Sequence[Window],
    count: int,
    config: SequentialConfig,
    rng: np.random.Generator,
    device: torch.device,
) -> list[torch.Tensor]:
    """``count`` windows drawn and augmented: images, masks, heatmaps, drifts (stacked)."""
    picks = rng.choice(len(windows), count, replace=len(windows) < count)
    examples = [_example(windows[int(i)], config, rng) for i in picks]
    return [torch.stack(parts).to(device) for parts in zip(*examples, strict=True)]


def _supervised(model: SequentialStudent, batch: Sequence[torch.Tensor]) -> torch.Tensor:
    """The per-frame student's loss on the second half of labelled windows (the steps with a
    past: decoding is most of a step's cost, and the first steps teach the cell least)."""
    images, masks, heats, _ = batch
    first = images.shape[1] // 2
    mask_logits, heat_logits = unroll(model, images, first=first)
    return _loss(
        mask_logits.flatten(0, 1),
        heat_logits.flatten(0, 1),
        masks[:, first:].flatten(0, 1),
        heats[:, first:].flatten(0, 1),
    )


def shift(values: torch.Tensor, drift: torch.Tensor) -> torch.Tensor:
    """N×T×S×S maps moved by ``drift`` (N×2: x, y input pixels; bilinear, zero outside):
    ``shift(v, d)[y, x] = v[y − d_y, x − d_x]``."""
    count, steps, size = values.shape[0], values.shape[1], values.shape[-1]
    theta = torch.zeros(count, 2, 3, dtype=values.dtype, device=values.device)
    theta[:, 0, 0] = theta[:, 1, 1] = 1.0
    theta[:, :, 2] = -2.0 * drift / size
    theta = theta.repeat_interleave(steps, 0)
    flat = values.reshape(count * steps, 1, size, size)
    grid = F.affine_grid(theta, list(flat.shape), align_corners=False)
    moved = F.grid_sample(flat, grid, align_corners=False)
    return moved.reshape(values.shape)


def unsteadiness(probability: torch.Tensor, drift: torch.Tensor) -> torch.Tensor:
    """How much of N windows' T×S×S mask probabilities changes from one step to the next beyond
    each window's known drift (N×2, input px per step): Σ|p_t − shift(p_{t−1})| / Σ p_t, a
    share of the pool's area like the Dice term, averaged over steps and windows. What the pool
    did not do, the cell should not show."""
    change = (probability[:, 1:] - shift(probability[:, :-1], drift)).abs()
    area = probability[:, 1:].flatten(2).sum(2).clamp(min=1.0)
    return (change.flatten(2).sum(2) / area).mean()


def _steadiness(
    model: SequentialStudent, images: torch.Tensor, drift: torch.Tensor
) -> torch.Tensor:
    """``unsteadiness`` of the sequential student's masks over unlabelled windows."""
    mask_logits, _ = unroll(model, images)
    return unsteadiness(torch.sigmoid(mask_logits), drift)


def train_sequential(
    model_dir: str | Path,
    clips: Sequence[LabelledClip],
    config: SequentialConfig | None = None,
    progress: Callable[[float, str], None] | None = None,
) -> SequentialResult:
    """Train the latent cell of the student in ``model_dir`` on ``clips`` and save it there."""
    config = config or SequentialConfig()
    root = Path(model_dir)
    started = time.perf_counter()
    device = resolve_device(config.device)
    windows = clip_windows(clips, config, checkpoint.read_student_config(root))
    student = checkpoint.load_student(root, device)
    for parameter in student.parameters():
        parameter.requires_grad_(False)
    torch.manual_seed(config.seed)
    cell = LatentCell(student.config.latent_channels).to(device)
    model = SequentialStudent(student, cell).eval()  # BatchNorm stays as trained
    optimiser = torch.optim.AdamW(cell.parameters(), lr=config.learning_rate, weight_decay=1e-4)

    def factor(step: int) -> float:
        return 0.02 + 0.98 * 0.5 * (1 + math.cos(math.pi * step / config.steps))

    schedule = torch.optim.lr_scheduler.LambdaLR(optimiser, factor)
    labelled = [w for w in windows if w.labelled]
    unlabelled = [w for w in windows if not w.labelled] if config.consistency else []
    losses = []
    for step in range(config.steps):
        rng = np.random.default_rng([config.seed, step])
        loss = _supervised(model, _batch(labelled, config.batch_size, config, rng, device))
        if unlabelled and config.unlabelled_batch:
            batch = _batch(unlabelled, config.unlabelled_batch, config, rng, device)
            loss = loss + config.consistency * _steadiness(model, batch[0], batch[3])
        optimiser.zero_grad(set_to_none=True)
        loss.backward()  # type: ignore[no-untyped-call]
        optimiser.step()
        schedule.step()
        losses.append(float(loss.detach()))
        if progress is not None and (step + 1) % 10 == 0:
            progress((step + 1) / config.steps, f"step {step + 1} of {config.steps}")
    save_cell(root, cell, config, len(labelled), losses)
    first = float(np.mean(losses[: max(1, len(losses) // 10)]))
    last = float(np.mean(losses[-max(1, len(losses) // 10) :]))
    return SequentialResult(root, first, last, len(labelled), time.perf_counter() - started)
