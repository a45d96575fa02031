"""The label configuration's other classes as extra outputs of the student, beside the pool.

A version learns the classes it is given (``StudentConfig.classes``; the app picks those with
enough reviewed labels). Each becomes channels of an extra decoder head after the pool's, which
reads the decoder's last features detached (``model.Decoder``): the classes' loss trains that
head alone, so the pool's weights, head, loss and figures are exactly what they are without
classes (with the same seed), and a class can never lower what the pool learns:

- a ``mask`` class, and an ``instances`` class as the union of its instances (a semantic mask),
  is one segmentation channel (BCE + Dice, as the pool's mask);
- a ``points`` class is one heatmap channel per named point (a peak-1 Gaussian of
  ``TrainConfig.heatmap_sigma`` input pixels at the point, the pool heatmap's quality focal
  loss); the point is read back as the channel's peak, as the pool's heatmap modes are.

A frame without a class's label does not teach that class (its channels carry no loss there),
and the class's figures (IoU; point distance in frame pixels) are measured only on the frames
that have it labelled. Channels follow the order of ``StudentConfig.classes``, and of
``LearnedClass.points`` within a points class: that order is stored with the version, so
predict, export and stream read each channel as the class it was trained as.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Literal

import torch

from weldpool_core.errors import InvalidInputError

if TYPE_CHECKING:
    import cv2
    import numpy as np
    from numpy.typing import NDArray
else:
    from weldpool_core.lazy import cv2, np

ClassKind = Literal["mask", "instances", "points"]
KINDS: tuple[str, ...] = ("mask", "instances", "points")
MAX_POINTS = 16
"""Most named points one points class may bring to the student."""


@dataclass(frozen=True)
class LearnedClass:
    """A class a student version learns: its name, its kind, and a points class's point names
    (one heatmap channel each, in this order)."""

    name: str
    kind: ClassKind
    points: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if not self.name or self.name == "pool":
            raise InvalidInputError("A learned class needs a name other than 'pool'.")
        if self.kind not in KINDS:
            raise InvalidInputError(
                f"The class {self.name!r} has kind {self.kind!r}; use mask, instances or points."
            )
        if (self.kind == "points") != bool(self.points) or len(self.points) > MAX_POINTS:
            raise InvalidInputError(
                f"The class {self.name!r}: a points class names 1 to {MAX_POINTS} points, "
                "other kinds none."
            )

    @property
    def channels(self) -> int:
        """Output channels of this class."""
        return len(self.points) if self.kind == "points" else 1

    @property
    def segments(self) -> bool:
        """Whether the class is a segmentation channel (mask or instances)."""
        return self.kind != "points"

    def as_dict(self) -> dict[str, Any]:
        """A JSON-ready dict (``from_dict`` reads it back)."""
        return {"name": self.name, "kind": self.kind, "points": list(self.points)}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> LearnedClass:
        """A class saved by ``as_dict``."""
        try:
            return cls(str(data["name"]), data["kind"], tuple(map(str, data.get("points", ()))))
        except (KeyError, TypeError):
            raise InvalidInputError(
                f"A learned class is {{name, kind, points}}, not {data!r}."
            ) from None


def channel_slices(classes: Sequence[LearnedClass]) -> dict[str, slice]:
    """Each class's channels among the extra outputs (in ``classes`` order)."""
    slices, start = {}, 0
    for learned in classes:
        slices[learned.name] = slice(start, start + learned.channels)
        start += learned.channels
    return slices


def channel_kinds(classes: Sequence[LearnedClass]) -> list[bool]:
    """For each extra channel: True for a segmentation channel, False for a point heatmap."""
    return [learned.segments for learned in classes for _ in range(learned.channels)]


def initial_bias(classes: Sequence[LearnedClass]) -> torch.Tensor:
    """The extra head's starting bias: 0 for masks, −4 for point heatmaps (mostly 0, as the
    pool's heatmap starts)."""
    return torch.tensor([0.0 if s else -4.0 for s in channel_kinds(classes)])


@dataclass(frozen=True)
class ClassTruth:
    """One frame's label of one class, at full resolution: a mask (mask and instances classes:
    the union of the frame's instances) or named ``(x, y)`` points."""

    mask: NDArray[np.bool_] | None = None
    points: Mapping[str, tuple[float, float]] = field(default_factory=dict)


@dataclass(frozen=True)
class PreparedClasses:
    """A frame's class targets at model resolution, per extra channel: a uint8 S×S coverage
    (segmentation) or an input-pixel point, None where the frame has no label for it; and the
    full-resolution truth for validation (packed mask or frame-pixel point)."""

    inputs: tuple[NDArray[np.uint8] | tuple[float, float] | None, ...]
    truths: tuple[NDArray[np.uint8] | tuple[float, float] | None, ...]


def prepare_classes(
    classes: Sequence[LearnedClass],
    truths: Mapping[str, ClassTruth],
    geometry: Any,
) -> PreparedClasses:
    """The targets of a frame's labels ``truths`` ({class name: truth}) for the channels of
    ``classes`` (``geometry``: the frame's ``data.FrameGeometry``)."""
    inputs: list[Any] = []
    frame: list[Any] = []
    for learned in classes:
        truth = truths.get(learned.name)
        if learned.segments:
            mask = None if truth is None else truth.mask
            if mask is None:
                inputs.append(None)
                frame.append(None)
                continue
            inputs.append(geometry.image_to_input(mask.astype(np.uint8) * np.uint8(255)))
            frame.append(np.packbits(mask.astype(np.uint8), axis=None))
            continue
        for name in learned.points:
            xy = None if truth is None else truth.points.get(name)
            if xy is None:
                inputs.append(None)
                frame.append(None)
                continue
            moved = geometry.to_input(np.asarray([xy], np.float64))[0]
            inputs.append((float(moved[0]), float(moved[1])))
            frame.append((float(xy[0]), float(xy[1])))
    return PreparedClasses(tuple(inputs), tuple(frame))


def point_heatmap(xy: tuple[float, float], size: int, sigma: float) -> NDArray[np.float32]:
    """A peak-1 Gaussian of ``sigma`` input pixels at ``xy`` on an S×S grid."""
    axis = np.arange(size, dtype=np.float32)
    across = np.exp(-((axis - xy[0]) ** 2) / (2 * sigma**2))
    down = np.exp(-((axis - xy[1]) ** 2) / (2 * sigma**2))
    return np.asarray(down[:, None] * across[None, :], np.float32)


def class_targets(
    prepared: PreparedClasses, size: int, sigma: float, matrix: NDArray[np.float64] | None
) -> tuple[torch.Tensor, torch.Tensor]:
    """C×S×S targets in [0, 1] and C presence flags of one frame, moved by the augmentation's
    2×3 affine ``matrix`` (None: as prepared), as the pool's mask and keypoints are."""
    planes, present = [], []
    for target in prepared.inputs:
        present.append(target is not None)
        if target is None:
            planes.append(np.zeros((size, size), np.float32))
        elif isinstance(target, tuple):
            xy = np.asarray(target, np.float64)
            if matrix is not None:
                xy = matrix[:, :2] @ xy + matrix[:, 2]
            planes.append(point_heatmap((float(xy[0]), float(xy[1])), size, sigma))
        else:
            plane = target.astype(np.float32) / np.float32(255)
            if matrix is not None:
                plane = np.asarray(cv2.warpAffine(plane, matrix, (size, size)), np.float32)
            planes.append(plane)
    return torch.from_numpy(np.stack(planes)), torch.tensor(present, dtype=torch.float32)


def unpack_truth(truth: NDArray[np.uint8], height: int, width: int) -> NDArray[np.bool_]:
    """A prepared frame-resolution mask truth (bit-packed) as a bool mask."""
    bits = np.unpackbits(truth, count=height * width)
    return bits.reshape(height, width).astype(bool)


MIN_PEAK = 0.1
"""Least heatmap peak at which a point class's point is read (below: the point is not seen)."""

ClassOutput = Any
"""One class's answer on one frame: an H×W bool mask, or {point name: [x, y] or None}."""


def read_point(
    heatmap: NDArray[np.float32], geometry: Any, min_peak: float = MIN_PEAK
) -> list[float] | None:
    """The frame-pixel ``[x, y]`` of an S×S heatmap's peak inside the frame's part of the input
    (refined by the 3×3 centroid around it), or None when the peak is under ``min_peak``."""
    inner = heatmap[geometry.inner_rows, geometry.inner_columns]
    if inner.size == 0 or float(inner.max()) < min_peak:
        return None
    row, column = np.unravel_index(int(np.argmax(inner)), inner.shape)
    top, left = max(0, row - 1), max(0, column - 1)
    window = inner[top : row + 2, left : column + 2].astype(np.float64)
    ys, xs = np.mgrid[top : top + window.shape[0], left : left + window.shape[1]]
    weight = window.sum()
    x = float((xs * window).sum() / weight) + geometry.offset_x
    y = float((ys * window).sum() / weight) + geometry.offset_y
    point = geometry.to_frame(np.asarray([[x, y]]))[0]
    return [float(point[0]), float(point[1])]


def classes_to_frame(
    probabilities: NDArray[np.float32], classes: Sequence[LearnedClass], geometry: Any
) -> dict[str, ClassOutput]:
    """One frame's C×S×S extra outputs (probabilities) as each class's answer in frame pixels."""
    slices = channel_slices(classes)
    found: dict[str, ClassOutput] = {}
    for learned in classes:
        channels = probabilities[slices[learned.name]]
        if learned.segments:
            found[learned.name] = np.asarray(geometry.map_to_frame(channels[0])) >= 0.5
        else:
            found[learned.name] = {
                name: read_point(channels[i], geometry) for i, name in enumerate(learned.points)
            }
    return found


def _iou(predicted: NDArray[np.bool_], truth: NDArray[np.bool_]) -> float:
    union = np.logical_or(predicted, truth).sum()
    return 1.0 if union == 0 else float(np.logical_and(predicted, truth).sum() / union)


def class_figures(
    classes: Sequence[LearnedClass],
    outputs: Sequence[Mapping[str, ClassOutput]],
    truths: Sequence[Mapping[str, ClassTruth]],
    sizes: Sequence[tuple[int, int]],
) -> dict[str, dict[str, Any]]:
    """Each class's figures over the frames that have it labelled: ``IoU`` (mean) for mask and
    instances classes, ``distance_px`` (mean over labelled points; a point not found counts as
    the frame's diagonal, and is counted in ``missed``) and per point for points classes.
    ``sizes``: each frame's (height, width)."""
    figures: dict[str, dict[str, Any]] = {}
    for learned in classes:
        frames, missed = 0, 0
        values: list[float] = []
        per_point: dict[str, list[float]] = {n: [] for n in learned.points}
        for output, truth_of, (height, width) in zip(outputs, truths, sizes, strict=True):
            truth = truth_of.get(learned.name)
            if truth is None:
                continue
            answer = output.get(learned.name)
            if learned.segments:
                if truth.mask is None:
                    continue
                frames += 1
                values.append(_iou(np.asarray(answer, bool), truth.mask))
                continue
            labelled = [n for n in learned.points if n in truth.points]
            frames += bool(labelled)
            for name in labelled:
                found, xy = (answer or {}).get(name), truth.points[name]
                if found is None:
                    missed += 1
                    distance = float(np.hypot(height, width))
                else:
                    distance = float(np.hypot(found[0] - xy[0], found[1] - xy[1]))
                values.append(distance)
                per_point[name].append(distance)
        mean = float(np.mean(values)) if values else None
        row: dict[str, Any] = {"kind": learned.kind, "frames": frames}
        if learned.segments:
            row["IoU"] = mean
        else:
            row["distance_px"] = mean
            row["points"] = {n: float(np.mean(v)) if v else None for n, v in per_point.items()}
            row["missed"] = missed
        figures[learned.name] = row
    return figures
