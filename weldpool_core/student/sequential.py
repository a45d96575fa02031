"""The sequential student: a recurrent cell on a trained student's latent (the paper's future
work: "a sequential student that keeps temporal information").

A per-frame student sees each frame alone, so glare flicker, floating oxide and sensor noise move
its mask and keypoints from frame to frame even where the pool stands still. The sequential
student keeps the per-frame student as it is (encoder and decoder frozen) and adds one small
gated cell between them, on the stride-32 latent mean ``x_t`` (C×h×w):

    d = x_t − s_{t−1}                         (the innovation: what this frame says that is new)
    z, r = σ(conv₃ₓ₃[x_t, s_{t−1}, d])        (per latent cell and channel)
    c = x_t + conv₃ₓ₃(r ⊙ d)                  (the frame's latent, corrected by what changed)
    s_t = s_{t−1} + z ⊙ (c − s_{t−1})         (the state, decoded as the frame's latent)

With no state (the first frame of a stream, or after a reset) ``s = x_t``, so ``d = 0`` and
``s_t = x_t``: the first frame is the per-frame student's answer exactly. The cell starts close
to the identity (z ≈ 0.98, the correction conv zero), so an untrained cell changes little; training
teaches it how much of the past to keep, cell by cell, from the size and kind of the innovation:
a small flicker is averaged away, a real move of the pool is followed at once. It is causal (no
future frame) and costs two 3×3 convolutions at stride 32: well under 1 % of the student.

Training (``train_sequential``) needs no labels on consecutive frames, only videos in which some
frames are labelled: each example is a window of ``window`` consecutive video frames ending at a
labelled frame (frame stride drawn from ``strides``, so the cell does not learn one frame rate).
The pool barely moves within a window of a fraction of a second (the camera moves with the
torch), so every step of the window is supervised with the labelled frame's targets — moved by
the window's synthetic motion: each window gets one shared random affine (as the per-frame
student's augmentation) plus a constant drift of up to ``drift`` of the input side per frame, and
the targets of step t are shifted by the drift at t. A cell that only averaged would trail that
drift and pay for it in the loss; one that ignored the past would pay for each frame's own
photometric noise (drawn independently per step, as real glare and noise are). The loss is the
per-frame student's (BCE + Dice on the mask, focal on the heatmap), on the decoded state of the
second half of each window (the steps with a past). A steadiness term adds unlabelled windows of
the same videos (``unlabelled_windows`` per video, evenly spaced, with the same drift and
noise): ``unsteadiness``, the share of the mask that changes from one step to the next beyond
the known drift. Measured on the real videos (``bench/sequential.py``), this term is what makes
the cell steady the held-out clip: supervision alone took 7–10 % off the keypoint jitter.

A MODEL_DIR with a trained cell holds ``sequential.safetensors`` and ``sequential.json`` (its
settings and training record); ``sequential.onnx`` is the whole sequential student for ONNX
Runtime (inputs ``image`` and ``state`` and ``fresh``; outputs mask, heatmap and the new state).
"""

from __future__ import annotations

import math
import re
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, cast

import numpy as np
import torch
import torch.nn.functional as F
from numpy.typing import NDArray
from torch import nn

from weldpool_core.device import resolve_device
from weldpool_core.errors import InvalidInputError
from weldpool_core.heatmap import HeatmapParams
from weldpool_core.metrics import iou
from weldpool_core.student import checkpoint
from weldpool_core.student.data import (
    Augmentation,
    FrameGeometry,
    PreparedFrame,
    TrainingFrame,
    photometric,
    prepare_frame,
    random_affine,
    render_heatmap,
    warp_targets,
)
from weldpool_core.student.model import ResNetVAE, StudentConfig

SEQUENTIAL_WEIGHTS = "sequential.safetensors"
SEQUENTIAL_CONFIG = "sequential.json"
SEQUENTIAL_ONNX = "sequential.onnx"

UPDATE_BIAS = 4.0
"""The update gate's starting bias: σ(4) ≈ 0.98, so an untrained cell passes the frame through."""


class LatentCell(nn.Module):
    """The gated recurrent cell on the latent mean (see the module doc)."""

    def __init__(self, channels: int) -> None:
        super().__init__()
        self.channels = channels
        self.gates = nn.Conv2d(3 * channels, 2 * channels, 3, padding=1)
        self.correction = nn.Conv2d(channels, channels, 3, padding=1, bias=False)
        with torch.no_grad():
            self.gates.weight.mul_(0.1)
            bias = torch.zeros(2 * channels)
            bias[:channels] = UPDATE_BIAS
            cast(torch.Tensor, self.gates.bias).copy_(bias)
            self.correction.weight.zero_()

    def forward(self, latent: torch.Tensor, state: torch.Tensor | None) -> torch.Tensor:
        """The new state (= the latent to decode) from this frame's latent and the last state."""
        if state is None:
            return latent
        change = latent - state
        update, reset = torch.sigmoid(self.gates(torch.cat([latent, state, change], 1))).chunk(2, 1)
        candidate = latent + self.correction(reset * change)
        new_state: torch.Tensor = state + update * (candidate - state)
        return new_state


class SequentialStudent(nn.Module):
    """A trained student with a ``LatentCell`` between its encoder and decoder."""

    def __init__(self, student: ResNetVAE, cell: LatentCell) -> None:
        super().__init__()
        self.student = student
        self.cell = cell

    @property
    def config(self) -> Any:
        """The per-frame student's ``StudentConfig``."""
        return self.student.config

    def step(
        self, images: torch.Tensor, state: torch.Tensor | None
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Mask logits, heatmap logits (N×S×S) and the new state for one frame per stream."""
        latent, _ = self.student.encode(images)
        new_state = self.cell(latent, state)
        mask_logits, heatmap_logits = self.student.decode(new_state)
        return mask_logits, heatmap_logits, new_state


class SequentialExport(nn.Module):
    """The sequential student as ONNX Runtime runs it: probabilities, and a state input that
    ``fresh`` = 1 replaces by the frame's own latent (the first frame of a stream)."""

    def __init__(self, model: SequentialStudent) -> None:
        super().__init__()
        self.model = model

    def forward(
        self, image: torch.Tensor, state: torch.Tensor, fresh: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        latent, _ = self.model.student.encode(image)
        start = fresh * latent + (1 - fresh) * state
        new_state = self.model.cell(latent, start)
        mask_logits, heatmap_logits = self.model.student.decode(new_state)
        return torch.sigmoid(mask_logits), torch.sigmoid(heatmap_logits), new_state


@dataclass(frozen=True)
class SequentialConfig:
    """How the sequential cell is trained (the per-frame student stays as it is).

    Attributes:
        window: consecutive frames per training example (the last one labelled).
        strides: frame strides drawn for a window (1: every frame; 2: every other), so the cell
            learns more than one frame rate.
        steps: optimiser steps.
        batch_size: windows per step.
        learning_rate: AdamW's peak learning rate (cosine to 2 % of it).
        drift: largest synthetic drift of a window, per frame along each axis, as a fraction
            of the input side (0.004: 1 input pixel per frame at 256², 5 frame pixels of a
            1280-wide camera; a pool that moves faster than that is rare in a torch-mounted
            camera, and a cell taught faster drifts keeps less of the past).
        consistency: weight of the steadiness term on unlabelled windows (0: off).
        unlabelled_windows: unlabelled windows per video (evenly spaced; stride 1).
        unlabelled_batch: unlabelled windows per step.
        augmentation: the shared per-window affine and the per-frame photometric noise.
        heatmap_sigma: the heatmap target's smallest spread (the per-frame student's).
        seed: seeds the cell's weights and every draw.
        device: cpu, cuda, cuda:N, mps or auto.
    """

    window: int = 8
    strides: tuple[int, ...] = (1, 2)
    steps: int = 200
    batch_size: int = 4
    learning_rate: float = 3e-3
    drift: float = 0.004
    consistency: float = 1.0
    unlabelled_windows: int = 32
    unlabelled_batch: int = 2
    augmentation: Augmentation = field(default_factory=Augmentation)
    heatmap_sigma: float = 3.0
    seed: int = 0
    device: str = "auto"

    def __post_init__(self) -> None:
        if self.consistency < 0 or self.unlabelled_windows < 0 or self.unlabelled_batch < 0:
            raise InvalidInputError(
                "Bad sequential training: consistency and the unlabelled counts must be ≥ 0."
            )
        if self.window < 2 or self.steps < 1 or self.batch_size < 1:
            raise InvalidInputError(
                "Bad sequential training: window must be at least 2, steps and batch_size 1."
            )
        if not self.strides or min(self.strides) < 1:
            raise InvalidInputError("Bad sequential training: strides must be positive.")
        if self.learning_rate <= 0 or not 0 <= self.drift < 0.1:
            raise InvalidInputError(
                "Bad sequential training: learning_rate must be > 0 and drift in [0, 0.1)."
            )


@dataclass(frozen=True)
class LabelledClip:
    """A video's frames (in order, any frame rate) and the labelled ones among them.

    Attributes:
        frames: a callable giving frame ``index`` as H×W×3 RGB uint8 (a decoded video, or a
            list's ``__getitem__``), and ``length`` frames in all.
        labels: frame index → its label (a ``TrainingFrame`` of that frame).
        name: for messages.
        unlabelled: the last frames of unlabelled windows (the steadiness term's; their
            ``window`` frames, stride 1, must be readable).
        placed: when set, ``frames`` gives each frame already placed on the student's S×S
            input by this geometry (the frames' own size is ``placed.height × width``), so a
            clip holds its windows at model resolution, not the camera's.
    """

    frames: Callable[[int], NDArray[np.uint8]]
    length: int
    labels: dict[int, TrainingFrame]
    name: str = ""
    unlabelled: tuple[int, ...] = ()
    placed: FrameGeometry | None = None


def unlabelled_ends(length: int, config: SequentialConfig) -> tuple[int, ...]:
    """The last frames of up to ``unlabelled_windows`` evenly spaced unlabelled windows."""
    first = config.window - 1
    if length <= first or not config.unlabelled_windows or not config.consistency:
        return ()
    ends = np.linspace(first, length - 1, min(config.unlabelled_windows, length - first))
    return tuple(sorted({int(e) for e in np.rint(ends)}))


def needed_frames(
    labels: Sequence[int], config: SequentialConfig, unlabelled: Sequence[int] = ()
) -> set[int]:
    """The frame indices the training windows of ``labels`` (and of the unlabelled window
    ends) read."""
    wanted = {
        index - stride * back
        for index in labels
        for stride in config.strides
        for back in range(config.window)
        if index - stride * (config.window - 1) >= 0
    }
    wanted |= {end - back for end in unlabelled for back in range(config.window)}
    return wanted


def video_clip(
    path: str | Path,
    labels: dict[int, TrainingFrame],
    config: SequentialConfig,
    unlabelled: Sequence[int] | None = None,
    student: StudentConfig | None = None,
) -> LabelledClip:
    """A ``LabelledClip`` of a video file that decodes only the frames its windows read.
    ``unlabelled``: the unlabelled windows' last frames (default ``unlabelled_ends`` of the
    video's length). With ``student``, each frame is kept placed on that student's input as it
    is decoded (a 1280×800 frame: 64 KB instead of 1 MB gray, 3 MB colour); without, as stored
    (gray for a grayscale camera). The windows are the same either way."""
    from weldpool_core.io import to_rgb8
    from weldpool_core.video import iter_video_frames, probe_video

    if unlabelled is None:
        ends = unlabelled_ends(probe_video(path).frame_count, config)
    else:
        ends = tuple(sorted({int(e) for e in unlabelled if e >= config.window - 1}))
    wanted = needed_frames(list(labels), config, ends)
    kept: dict[int, NDArray[np.uint8]] = {}
    placed: FrameGeometry | None = None
    length = 0
    for frame in iter_video_frames(path):
        length = frame.index + 1
        if frame.index in wanted:
            pixels = frame.pixels
            if student is not None:
                if placed is None:
                    placed = _placement(pixels.shape[:2], labels, student, Path(path).name)
                pixels = placed.image_to_input(pixels)
            kept[frame.index] = pixels
        if wanted and frame.index >= max(wanted):
            break
    missing = sorted(i for i in labels if i >= length)
    if missing:
        raise InvalidInputError(
            f"{Path(path).name} has {length} frames; labelled frame {missing[0]} is not in it."
        )
    readable = tuple(e for e in ends if e < length)  # the header's count may overstate

    def read(index: int) -> NDArray[np.uint8]:
        return to_rgb8(kept[index])

    return LabelledClip(
        read,
        max(length, max(labels, default=0) + 1),
        labels,
        Path(path).stem,
        unlabelled=readable,
        placed=placed,
    )


def _placement(
    shape: tuple[int, ...], labels: dict[int, TrainingFrame], student: StudentConfig, name: str
) -> FrameGeometry:
    """The geometry that places a video's frames on the student's input; its labelled frames
    must land on the same part of the input (the video's size, or a scaled copy of it)."""
    height, width = int(shape[0]), int(shape[1])
    placed = FrameGeometry.fit(height, width, student.input_size, student.aspect)
    for index, label in labels.items():
        rows, columns = int(label.image.shape[0]), int(label.image.shape[1])
        own = FrameGeometry.fit(rows, columns, student.input_size, student.aspect)
        if (own.inner_rows, own.inner_columns) != (placed.inner_rows, placed.inner_columns):
            raise InvalidInputError(
                f"Labelled frame {index} of {name} is {label.image.shape[1]}×"
                f"{label.image.shape[0]}, another shape than the video's {width}×{height} frames."
            )
    return placed


FRAME_STEM = re.compile(r"^(?P<video>.+)_f(?P<index>\d+)$")
"""A labelled frame's stem names its video and its 0-based frame index: ``<video>_f0050``."""
VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".mkv")


def dataset_clips(
    dataset: str | Path,
    videos: str | Path,
    config: SequentialConfig,
    student: StudentConfig | None = None,
) -> list[LabelledClip]:
    """The labelled videos of a DATASET whose stems are ``<video>_f<index>`` (their videos in
    ``videos``), one clip per video; a one-sentence error for a stem or video that does not fit."""
    from weldpool_core.student.data import read_dataset

    by_video: dict[str, dict[int, TrainingFrame]] = {}
    for frame in read_dataset(dataset):
        match = FRAME_STEM.match(frame.name)
        if match is None:
            raise InvalidInputError(
                f"{frame.name} does not name its video frame; name labelled frames "
                "<video>_f<index> (for example weld3_f0050)."
            )
        by_video.setdefault(match["video"], {})[int(match["index"])] = frame
    clips = []
    for name, labels in sorted(by_video.items()):
        found = [Path(videos) / f"{name}{suffix}" for suffix in VIDEO_SUFFIXES]
        path = next((p for p in found if p.is_file()), None)
        if path is None:
            raise InvalidInputError(f"No video {name}.mp4 (or .avi, .mov, .mkv) in {videos}.")
        clips.append(video_clip(path, labels, config, student=student))
    return clips


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
class _Window:
    inputs: list[NDArray[np.uint8]]  # S×S×3 RGB, oldest first
    target: PreparedFrame  # the labelled frame (for an unlabelled window: a blank one)
    labelled: bool = True


def _windows(
    clips: Sequence[LabelledClip],
    config: SequentialConfig,
    student: Any,
    require_labelled: bool = True,
) -> list[_Window]:
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
                windows.append(_Window(inputs, target))
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
            windows.append(_Window(inputs, geometry_of, labelled=False))
    if require_labelled and not any(w.labelled for w in windows):
        raise InvalidInputError(
            f"No labelled frame has {config.window - 1} frames before it at stride "
            f"{min(config.strides)}; label frames further into the videos."
        )
    return windows


def _example(
    window: _Window, config: SequentialConfig, rng: np.random.Generator
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
    from weldpool_core.student.train import dice_loss, heatmap_loss

    bce = F.binary_cross_entropy_with_logits(mask_logits, mask)
    return bce + dice_loss(mask_logits, mask) + heatmap_loss(heat_logits, heat)


def encode_windows(model: SequentialStudent, images: torch.Tensor) -> torch.Tensor:
    """The frozen student's latent means (N×T×C×h×w) of N windows of T frames (N×T×3×S×S)."""
    count, steps = images.shape[:2]
    with torch.no_grad():
        flat = images.flatten(0, 1).contiguous(memory_format=torch.channels_last)
        mean = model.student.encode(flat)[0]
    return mean.reshape(count, steps, *mean.shape[1:])


def unroll(
    model: SequentialStudent,
    images: torch.Tensor,
    first: int = 0,
    latents: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Mask and heatmap logits (N×(T − first)×S×S) of N windows of T frames (N×T×3×S×S), in
    order, from step ``first`` on (training skips step 0: without a past the cell is the
    identity, so decoding it teaches nothing). ``latents``: the windows' ``encode_windows``
    when already at hand."""
    latents = encode_windows(model, images) if latents is None else latents
    state = None
    masks, heats = [], []
    for t in range(latents.shape[1]):
        state = model.cell(latents[:, t], state)
        if t < first:
            continue
        mask_logits, heat_logits = model.student.decode(state)
        masks.append(mask_logits)
        heats.append(heat_logits)
    return torch.stack(masks, 1), torch.stack(heats, 1)


def _batch(
    windows: Sequence[_Window],
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
    windows = _windows(clips, config, checkpoint.read_student_config(root))
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


def _as_batch(window: _Window, device: torch.device) -> torch.Tensor:
    """A window's frames as 1×T×3×S×S in [0, 1], unaugmented."""
    stacked = np.stack(window.inputs).transpose(0, 3, 1, 2).astype(np.float32) / np.float32(255)
    return torch.from_numpy(stacked)[None].to(device)


def _per_frame_masks(model: SequentialStudent, latents: torch.Tensor) -> torch.Tensor:
    """The per-frame student's mask probabilities (N×T×S×S) of ``encode_windows`` latents: each
    frame decoded alone."""
    mask_logits, _ = model.student.decode(latents.flatten(0, 1))
    return torch.sigmoid(mask_logits).reshape(*latents.shape[:2], *mask_logits.shape[1:])


def measure_sequential(
    model_dir: str | Path,
    clips: Sequence[LabelledClip],
    config: SequentialConfig | None = None,
) -> dict[str, Any]:
    """The sequential student against its own per-frame student on the same frames.

    Accuracy: on each labelled frame of ``clips`` with ``window`` − 1 frames before it, the
    mask IoU (at model resolution, against the label brought there as for training) of the
    per-frame student on that frame alone and of the sequential student after the window's
    frames (stride 1, state fresh at the window's start). Steadiness: on the clips' unlabelled
    windows, ``unsteadiness`` (no drift: the share of the pool's mask that changes from one
    frame to the next) of each. Labelled frames should be ones the cell did not train on.

    Returns ``frames`` and ``windows`` counted, ``per_frame_iou`` / ``sequential_iou`` (None
    without a labelled window) and ``per_frame_change`` / ``sequential_change`` (None without
    an unlabelled window).
    """
    config = replace(config or SequentialConfig(), strides=(1,))
    root = Path(model_dir)
    device = resolve_device(config.device)
    model = load_sequential(root, device)
    windows = _windows(clips, config, model.config, require_labelled=False)
    ious: dict[str, list[float]] = {"per_frame": [], "sequential": []}
    changes: dict[str, list[float]] = {"per_frame": [], "sequential": []}
    still = torch.zeros(1, 2, device=device)
    with torch.no_grad():
        for window in windows:
            images = _as_batch(window, device)
            latents = encode_windows(model, images)  # once for both students
            last = images.shape[1] - 1 if window.labelled else 0  # a label: its frame only
            alone = _per_frame_masks(model, latents[:, last:])
            steady = torch.sigmoid(unroll(model, images, first=last, latents=latents)[0])
            if window.labelled:
                truth = window.target.mask >= 128
                for name, probability in (("per_frame", alone), ("sequential", steady)):
                    predicted = (probability[0, -1] >= 0.5).cpu().numpy()
                    ious[name].append(iou(predicted, truth))
            else:
                changes["per_frame"].append(float(unsteadiness(alone, still)))
                changes["sequential"].append(float(unsteadiness(steady, still)))

    def mean(values: list[float]) -> float | None:
        return round(float(np.mean(values)), 4) if values else None

    return {
        "frames": len(ious["per_frame"]),
        "windows": len(changes["per_frame"]),
        "per_frame_iou": mean(ious["per_frame"]),
        "sequential_iou": mean(ious["sequential"]),
        "per_frame_change": mean(changes["per_frame"]),
        "sequential_change": mean(changes["sequential"]),
    }


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
            f"train it again with `weldpool train-sequential {root} …`."
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
            f"{root} has no sequential cell; train one with `weldpool train-sequential {root} …`."
        )
    record = _matching_record(root)
    student = checkpoint.load_student(root, device)
    cell = LatentCell(int(record["channels"]))
    cell.load_state_dict(load_file(str(root / SEQUENTIAL_WEIGHTS)))
    return SequentialStudent(student, cell.to(device or torch.device("cpu"))).eval()


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
