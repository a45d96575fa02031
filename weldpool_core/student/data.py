"""Training frames for the student: geometry, targets, augmentation and the DATASET folder.

Geometry (``FrameGeometry``): a frame of W×H pixels becomes the S×S model input by one scale
per axis and an offset. ``letterbox`` (default) scales both axes by the same factor so the frame
fits, centres it and pads the rest with black: shapes keep their proportions, at the cost of
unused padding (37.5 % of a 1280×800 frame). ``resize`` stretches each axis to S: every input
pixel is used, but circles become ellipses (the student learns the stretched shapes alike).
With pixel centres as the origin, ``x_in = (x + 0.5)·sx − 0.5 + ox`` and back
``x = (x_in − ox + 0.5) / sx − 0.5`` (same for y); outputs are cropped to the frame's part of the
input and resized to W×H, so masks, heatmaps and keypoints come back in full-resolution pixels.

Targets: the mask, and a heatmap drawn from the keypoints. Keypoints come from the dataset
(``keypoints/<stem>.json``) when given, else from Algorithm 1 on the full-resolution mask. The
heatmap is Algorithm 1's step 6 redrawn at model resolution: one peak-1 Gaussian per keypoint
with its covariance carried through the same affine maps as the image (Algorithm 1's group
covariance, or ``completion_sigma``² for given keypoints), plus ``heatmap_sigma``² so that no
peak is narrower than a couple of model pixels, times min(1, 2·S) of the (blurred) mask.

Augmentation (``Augmentation``) imitates what changes between weld runs and cameras: exposure
(gain and offset), arc glare (a bright Gaussian blob), sensor noise, defocus blur, and a small
affine (rotation, scale, shift) applied to image, mask and keypoints alike. No flips: the wire
comes from one side and the pool trails the other, so a mirrored frame is not a real frame.
Each frame's draw depends only on (seed, epoch, index), which makes training reproducible and
a resumed run identical to an uninterrupted one.
"""

from __future__ import annotations

import json
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import torch

from weldpool_core.errors import InvalidInputError
from weldpool_core.heatmap import HeatmapParams, gaussian_window, heatmap_from_mask
from weldpool_core.io import load_rgb8, read_mask
from weldpool_core.student.classes import (
    ClassTruth,
    LearnedClass,
    PreparedClasses,
    class_targets,
    prepare_classes,
)
from weldpool_core.student.model import Aspect

if TYPE_CHECKING:
    import cv2
    import numpy as np
    from numpy.typing import NDArray
else:
    from weldpool_core.lazy import cv2, np

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp")


BOX_FACTORS = (1, 3, 5)
"""Whole shrink factors for which ``shrink`` takes the box filter's faster way."""


def shrink(image: NDArray[Any], width: int, height: int) -> NDArray[Any]:
    """``image`` shrunk to ``width``×``height`` by area averaging: ``cv2.resize`` with
    ``INTER_AREA``, pixel for pixel. For a uint8 image shrunk by whole factors of 1, 3 or 5 on
    each axis (not 1 on both: a 1280×800 frame onto 256×160), the same pixels come from a box
    filter read at every factor-th pixel, 2× (5×5) to 4× (3×3) faster than OpenCV's area
    resize, which is vectorised for a factor of 2 only. (Both divide a block's sum by its size
    and round; with an odd box no quotient ends in exactly one half, while an even box's halves
    round differently, and larger factors are slower by the filter. The test checks every
    possible block sum against the installed OpenCV.)"""
    rows, columns = image.shape[:2]
    fx, fy = columns // width, rows // height
    if (
        image.dtype == np.uint8
        and fx * width == columns
        and fy * height == rows
        and fx in BOX_FACTORS
        and fy in BOX_FACTORS
        and fx * fy > 1
    ):
        box = cv2.boxFilter(image, -1, (fx, fy), anchor=(0, 0), borderType=cv2.BORDER_REPLICATE)
        return np.ascontiguousarray(box[::fy, ::fx])
    return cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA)


@dataclass(frozen=True)
class FrameGeometry:
    """How a W×H frame maps onto the S×S model input and back (see the module doc).

    Attributes:
        width: frame width in pixels.
        height: frame height in pixels.
        size: side S of the model input.
        scale_x: input pixels per frame pixel along x.
        scale_y: input pixels per frame pixel along y.
        offset_x: left edge of the frame's part of the input.
        offset_y: top edge of the frame's part of the input.
        inner_width: width of the frame's part of the input.
        inner_height: height of the frame's part of the input.
    """

    width: int
    height: int
    size: int
    scale_x: float
    scale_y: float
    offset_x: int
    offset_y: int
    inner_width: int
    inner_height: int

    @classmethod
    def fit(cls, height: int, width: int, size: int, aspect: Aspect = "letterbox") -> FrameGeometry:
        """The geometry of a ``height``×``width`` frame on a ``size``² input."""
        if height < 1 or width < 1:
            raise InvalidInputError(f"A frame must have pixels, not {width}×{height}.")
        if aspect == "resize":
            inner_w, inner_h = size, size
        else:
            factor = size / max(width, height)
            inner_w = min(size, max(1, round(width * factor)))
            inner_h = min(size, max(1, round(height * factor)))
        return cls(
            width=width,
            height=height,
            size=size,
            scale_x=inner_w / width,
            scale_y=inner_h / height,
            offset_x=(size - inner_w) // 2,
            offset_y=(size - inner_h) // 2,
            inner_width=inner_w,
            inner_height=inner_h,
        )

    @property
    def matrix(self) -> NDArray[np.float64]:
        """The 2×3 affine map from frame pixels to input pixels (pixel centres)."""
        return np.array(
            [
                [self.scale_x, 0.0, 0.5 * self.scale_x - 0.5 + self.offset_x],
                [0.0, self.scale_y, 0.5 * self.scale_y - 0.5 + self.offset_y],
            ]
        )

    def to_input(self, points: NDArray[Any]) -> NDArray[np.float64]:
        """Frame ``(x, y)`` points → model-input points."""
        xy = np.asarray(points, np.float64).reshape(-1, 2)
        return xy @ self.matrix[:, :2].T + self.matrix[:, 2]

    def to_frame(self, points: NDArray[Any]) -> NDArray[np.float64]:
        """Model-input ``(x, y)`` points → full-resolution frame points."""
        xy = np.asarray(points, np.float64).reshape(-1, 2)
        x = (xy[:, 0] - self.offset_x + 0.5) / self.scale_x - 0.5
        y = (xy[:, 1] - self.offset_y + 0.5) / self.scale_y - 0.5
        return np.stack([x, y], axis=1)

    def image_to_input(self, image: NDArray[Any]) -> NDArray[Any]:
        """A frame (H×W or H×W×C) scaled into the S×S input, zero-padded (letterbox)."""
        if self.inner_width < self.width or self.inner_height < self.height:
            inner = shrink(image, self.inner_width, self.inner_height)
        else:
            inner = cv2.resize(
                image, (self.inner_width, self.inner_height), interpolation=cv2.INTER_LINEAR
            )
        canvas = np.zeros((self.size, self.size, *image.shape[2:]), image.dtype)
        canvas[self.inner_rows, self.inner_columns] = inner
        return canvas

    def map_to_frame(self, values: NDArray[Any]) -> NDArray[Any]:
        """An S×S (or S×S×C) model output cropped to the frame's part and resized to H×W."""
        inner = np.ascontiguousarray(values[self.inner_rows, self.inner_columns])
        return cv2.resize(inner, (self.width, self.height), interpolation=cv2.INTER_LINEAR)

    @property
    def inner_rows(self) -> slice:
        """Rows of the input that show the frame."""
        return slice(self.offset_y, self.offset_y + self.inner_height)

    @property
    def inner_columns(self) -> slice:
        """Columns of the input that show the frame."""
        return slice(self.offset_x, self.offset_x + self.inner_width)


@dataclass(frozen=True)
class TrainingFrame:
    """One reviewed frame to learn from, at full resolution.

    Attributes:
        image: H×W×3 RGB uint8 (``io.to_rgb8`` makes it from any frame).
        mask: H×W bool, the molten pool.
        keypoints: k×2 ``(x, y)`` keypoints, or None to take them from Algorithm 1 on the mask.
        name: a label for messages (a file stem or a frame id).
        weight: how much the frame counts in the loss against 1 for a reviewed label (a
            teacher pseudo-label counts less; 0 < weight ≤ 1).
        classes: the frame's labels of other classes ({class name: truth}, full resolution),
            for a student that learns them (``student.classes``).
    """

    image: NDArray[np.uint8]
    mask: NDArray[np.bool_]
    keypoints: NDArray[np.float64] | None = None
    name: str = ""
    weight: float = 1.0
    classes: Mapping[str, ClassTruth] = field(default_factory=dict)

    def __post_init__(self) -> None:
        image, mask = np.asarray(self.image), np.asarray(self.mask)
        if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
            raise InvalidInputError(
                f"Frame {self.name or '?'}: the image must be H×W×3 RGB uint8, not "
                f"{image.dtype} of shape {image.shape}."
            )
        if not 0 < self.weight <= 1:
            raise InvalidInputError(
                f"Frame {self.name or '?'}: the weight must lie in (0, 1], not {self.weight}."
            )
        if mask.shape != image.shape[:2]:
            raise InvalidInputError(
                f"Frame {self.name or '?'}: the mask is {mask.shape[1]}×{mask.shape[0]} but the "
                f"image {image.shape[1]}×{image.shape[0]}; they must match."
            )


@dataclass(frozen=True)
class PreparedFrame:
    """A training frame brought to model resolution once (what each epoch augments).

    Attributes:
        image: S×S×3 RGB uint8 input.
        mask: S×S uint8 mask coverage (0..255, area-averaged from the full-resolution mask).
        keypoints: k×2 keypoints in input pixels (0×2 when the mask has none).
        covariances: k×2×2 their Gaussians' covariances in input pixels².
        geometry: the frame ↔ input mapping.
        frame_keypoints: k×2 keypoints in frame pixels (for validation).
        frame_mask: the full-resolution mask, bit-packed (for validation).
        name: the frame's label.
        classes: the learned classes' targets (None: a pool-only student).
    """

    image: NDArray[np.uint8]
    mask: NDArray[np.uint8]
    keypoints: NDArray[np.float64]
    covariances: NDArray[np.float64]
    geometry: FrameGeometry
    frame_keypoints: NDArray[np.float64]
    frame_mask: NDArray[np.uint8]
    name: str = ""
    weight: float = 1.0
    classes: PreparedClasses | None = None

    def truth_mask(self) -> NDArray[np.bool_]:
        """The full-resolution ground-truth mask."""
        count = self.geometry.width * self.geometry.height
        bits = np.unpackbits(self.frame_mask, count=count)
        return bits.reshape(self.geometry.height, self.geometry.width).astype(bool)


def prepare_frame(
    frame: TrainingFrame,
    size: int,
    aspect: Aspect,
    heatmap: HeatmapParams,
    learned: Sequence[LearnedClass] = (),
) -> PreparedFrame:
    """Targets for one frame (keypoints from Algorithm 1 when not given), at model resolution;
    with ``learned`` classes, theirs too."""
    height, width = frame.mask.shape
    geometry = FrameGeometry.fit(height, width, size, aspect)
    if frame.keypoints is not None and len(frame.keypoints):
        points = np.asarray(frame.keypoints, np.float64).reshape(-1, 2)
        covariances = np.repeat((heatmap.completion_sigma**2 * np.eye(2))[None], len(points), 0)
    else:
        try:
            result = heatmap_from_mask(frame.mask, heatmap)
            points, covariances = result.keypoints, result.covariances
        except InvalidInputError:  # an empty or tiny pool: no keypoints to learn
            points, covariances = np.zeros((0, 2)), np.zeros((0, 2, 2))
    linear = geometry.matrix[:, :2]
    return PreparedFrame(
        image=geometry.image_to_input(frame.image),
        mask=geometry.image_to_input(frame.mask.astype(np.uint8) * np.uint8(255)),
        keypoints=geometry.to_input(points),
        covariances=np.einsum("ij,njk,lk->nil", linear, covariances, linear),
        geometry=geometry,
        frame_keypoints=points,
        frame_mask=np.packbits(frame.mask.astype(np.uint8), axis=None),
        name=frame.name,
        weight=frame.weight,
        classes=prepare_classes(learned, frame.classes, geometry) if learned else None,
    )


def render_heatmap(
    keypoints: NDArray[np.float64],
    covariances: NDArray[np.float64],
    mask: NDArray[np.float32],
    sigma_floor: float,
    window_sigmas: float = 3.0,
) -> NDArray[np.float32]:
    """Peak-1 Gaussians at ``keypoints`` (covariance + floor²·I) times min(1, 2·blur(mask)).

    ``mask`` is the S×S coverage in [0, 1]; the result is clipped to [0, 1] where peaks overlap.
    """
    size_y, size_x = mask.shape
    heat = np.zeros(mask.shape, np.float32)
    for centre, covariance in zip(keypoints, covariances, strict=True):
        spread = covariance + sigma_floor**2 * np.eye(2)
        window = gaussian_window(centre, spread, (0, 0, size_x, size_y), window_sigmas)
        if window is not None:
            rows, columns, gaussian = window
            heat[rows, columns] += gaussian
    pool = cv2.blur(mask, (3, 3))
    return np.asarray(np.clip(heat * np.minimum(pool + pool, np.float32(1)), 0, 1), np.float32)


@dataclass(frozen=True)
class Augmentation:
    """Random changes applied to each training frame (see the module doc); ranges are ±.

    Attributes:
        enabled: False trains on the frames as they are.
        gamma: exposure curve: grey levels g become 255·(g/255)^γ, with log γ drawn from
            [−log(1 + gamma), log(1 + gamma)] (0: off).
        gain: exposure gain is drawn from [1 − gain, 1 + gain].
        offset: grey-level offset drawn from [−offset, offset].
        glare_probability: chance of an added arc glare blob.
        glare_peak: its largest brightness (grey levels).
        noise_sigma: sensor noise sigma drawn from [0, noise_sigma] grey levels.
        blur_probability: chance of a defocus blur.
        blur_sigma: its largest sigma in input pixels.
        rotation_deg: rotation drawn from [−rotation_deg, rotation_deg].
        scale: scale drawn from [1 − scale, 1 + scale].
        shift: shift drawn from [−shift, shift] of the input size, per axis.
    """

    enabled: bool = True
    gamma: float = 0.5
    gain: float = 0.3
    offset: float = 20.0
    glare_probability: float = 0.4
    glare_peak: float = 120.0
    noise_sigma: float = 6.0
    blur_probability: float = 0.3
    blur_sigma: float = 1.2
    rotation_deg: float = 12.0
    scale: float = 0.25
    shift: float = 0.1


def random_affine(rng: np.random.Generator, size: int, params: Augmentation) -> NDArray[np.float64]:
    """A random rotation, scale and shift of an S×S input (2×3, for ``cv2.warpAffine``)."""
    angle = rng.uniform(-params.rotation_deg, params.rotation_deg)
    scale = rng.uniform(1 - params.scale, 1 + params.scale)
    centre = ((size - 1) / 2, (size - 1) / 2)
    matrix = np.asarray(cv2.getRotationMatrix2D(centre, angle, scale), np.float64)
    matrix[:, 2] += rng.uniform(-params.shift, params.shift, 2) * size
    return matrix


def photometric(
    image: NDArray[np.float32], rng: np.random.Generator, params: Augmentation
) -> NDArray[np.float32]:
    """``image`` (S×S×3, grey levels as floats) under a random exposure, glare, blur and noise."""
    size = image.shape[0]
    if params.gamma > 0:
        spread = np.log1p(params.gamma)
        exponent = np.float32(np.exp(rng.uniform(-spread, spread)))
        image = np.float32(255) * (np.clip(image, 0, 255) / np.float32(255)) ** exponent
    image = image * np.float32(rng.uniform(1 - params.gain, 1 + params.gain))
    image += np.float32(rng.uniform(-params.offset, params.offset))
    if rng.random() < params.glare_probability:
        cx, cy = rng.uniform(0, size, 2)
        sigma = rng.uniform(0.05, 0.2) * size
        axis = np.arange(size, dtype=np.float32)
        across = np.exp(-((axis - cx) ** 2) / (2 * sigma**2)).astype(np.float32)
        down = np.exp(-((axis - cy) ** 2) / (2 * sigma**2)).astype(np.float32)
        peak = np.float32(rng.uniform(0.3, 1.0) * params.glare_peak)
        image += (peak * down[:, None] * across[None, :])[:, :, None]
    if rng.random() < params.blur_probability:
        blur = rng.uniform(0.3, params.blur_sigma)
        image = np.asarray(cv2.GaussianBlur(image, (0, 0), blur), np.float32)
    sigma = np.float32(rng.uniform(0, params.noise_sigma))
    image += sigma * rng.standard_normal(image.shape, dtype=np.float32)
    return np.asarray(image, np.float32)


@dataclass(frozen=True)
class TrainingTargets:
    """One augmented example: input image in [0, 1] (3×S×S), its mask and heatmap (S×S), its
    loss weight, and the learned classes' targets (E×S×S) with their presence flags (E) (a
    batch: N×… tensors and N weights)."""

    image: torch.Tensor
    mask: torch.Tensor
    heatmap: torch.Tensor
    weight: torch.Tensor | None = None
    classes: torch.Tensor | None = None
    present: torch.Tensor | None = None


def warp_targets(
    image: NDArray[np.float32],
    mask: NDArray[np.float32],
    keypoints: NDArray[np.float64],
    covariances: NDArray[np.float64],
    matrix: NDArray[np.float64],
) -> tuple[NDArray[np.float32], NDArray[np.float32], NDArray[np.float64], NDArray[np.float64]]:
    """An S×S input (float32), its mask coverage (0..1), keypoints (k×2) and their covariances
    (k×2×2), all moved by one 2×3 affine ``matrix`` (input pixels), so they stay together."""
    size = image.shape[0]
    moved_image = np.asarray(cv2.warpAffine(image, matrix, (size, size)), np.float32)
    moved_mask = np.asarray(cv2.warpAffine(mask, matrix, (size, size)), np.float32)
    linear = matrix[:, :2]
    moved_points = keypoints @ linear.T + matrix[:, 2]
    moved_covariances = np.einsum("ij,njk,lk->nil", linear, covariances, linear)
    return moved_image, moved_mask, moved_points, moved_covariances


def make_targets(
    frame: PreparedFrame,
    sigma_floor: float,
    augmentation: Augmentation | None = None,
    rng: np.random.Generator | None = None,
) -> TrainingTargets:
    """The model's input and targets for a prepared frame, augmented when ``rng`` is given."""
    image = frame.image.astype(np.float32)
    mask = frame.mask.astype(np.float32) / 255.0
    keypoints, covariances = frame.keypoints, frame.covariances
    matrix = None
    if augmentation is not None and augmentation.enabled and rng is not None:
        matrix = random_affine(rng, image.shape[0], augmentation)
        image, mask, keypoints, covariances = warp_targets(
            image, mask, keypoints, covariances, matrix
        )
        image = photometric(image, rng, augmentation)
    heatmap = render_heatmap(keypoints, covariances, mask, sigma_floor)
    pixels = np.clip(image, 0, 255) / np.float32(255)
    classes = present = None
    if frame.classes is not None:
        classes, present = class_targets(frame.classes, image.shape[0], sigma_floor, matrix)
    return TrainingTargets(
        image=torch.from_numpy(np.ascontiguousarray(pixels.transpose(2, 0, 1))),
        mask=torch.from_numpy(np.ascontiguousarray(mask)),
        heatmap=torch.from_numpy(heatmap),
        weight=torch.tensor(frame.weight, dtype=torch.float32),
        classes=classes,
        present=present,
    )


@dataclass
class FrameSet(torch.utils.data.Dataset[TrainingTargets]):
    """Prepared frames as a torch dataset; ``epoch`` selects the augmentation draw."""

    frames: Sequence[PreparedFrame]
    sigma_floor: float
    augmentation: Augmentation | None = None
    seed: int = 0
    epoch: int = 0

    def __len__(self) -> int:
        return len(self.frames)

    def __getitem__(self, index: int) -> TrainingTargets:
        return self.draw(index, self.epoch)

    def draw(self, index: int, epoch: int) -> TrainingTargets:
        """Frame ``index`` with the augmentation draw of pass ``epoch``."""
        rng = np.random.default_rng([self.seed, epoch, index])
        return make_targets(self.frames[index], self.sigma_floor, self.augmentation, rng)


def collate(batch: Sequence[TrainingTargets]) -> TrainingTargets:
    """Stack examples into one batch."""
    classes = [b.classes for b in batch if b.classes is not None]
    present = [b.present for b in batch if b.present is not None]
    return TrainingTargets(
        image=torch.stack([b.image for b in batch]),
        mask=torch.stack([b.mask for b in batch]),
        heatmap=torch.stack([b.heatmap for b in batch]),
        weight=torch.stack(
            [b.weight if b.weight is not None else torch.tensor(1.0) for b in batch]
        ),
        classes=torch.stack(classes) if len(classes) == len(batch) else None,
        present=torch.stack(present) if len(present) == len(batch) else None,
    )


def _keypoints_file(path: Path) -> NDArray[np.float64]:
    try:
        points = json.loads(path.read_text())["keypoints"]
        array = np.asarray(points, np.float64).reshape(-1, 2)
    except (OSError, ValueError, KeyError, TypeError):
        raise InvalidInputError(
            f'{path} is not a keypoints file; expected {{"keypoints": [[x, y], …]}}.'
        ) from None
    if not np.isfinite(array).all():
        raise InvalidInputError(f"{path} holds keypoints that are not finite numbers.")
    return array


def dataset_stems(folder: str | Path) -> list[str]:
    """The stems of a DATASET folder that have both an image and a mask (sorted).

    Raises InvalidInputError when the folder is not a DATASET (``images/`` and ``masks/``) or
    holds no image with a mask.
    """
    root = Path(folder)
    if not (root / "images").is_dir() or not (root / "masks").is_dir():
        raise InvalidInputError(
            f"{root} is not a DATASET folder; it needs images/<stem>.<png|jpg|tif> and "
            "masks/<stem>.png (`weldpool export --format masks --out labels.zip` writes one from "
            "an instance's reviewed labels: unzip it)."
        )
    images = [p.stem for p in (root / "images").iterdir() if p.suffix.lower() in IMAGE_SUFFIXES]
    twice = sorted({stem for stem in images if images.count(stem) > 1})
    if twice:
        raise InvalidInputError(
            f"{root / 'images'} holds several images named {twice[0]!r}; keep one per stem."
        )
    masks = {p.stem for p in (root / "masks").glob("*.png")}
    stems = sorted(set(images) & masks)
    if not stems:
        raise InvalidInputError(
            f"{root} holds no image with a mask of the same stem (images/<stem>.png and "
            "masks/<stem>.png)."
        )
    return stems


def read_dataset(folder: str | Path) -> Iterator[TrainingFrame]:
    """The frames of a DATASET folder (CONTRACT.md), read one at a time in stem order.

    Images without a mask are passed over; keypoints come from ``keypoints/<stem>.json`` when
    present. Raises InvalidInputError naming the file for an unreadable image, mask or
    keypoints file, or a mask whose size differs from its image.
    """
    root = Path(folder)
    stems = dataset_stems(root)
    images = {p.stem: p for p in (root / "images").iterdir() if p.suffix.lower() in IMAGE_SUFFIXES}
    for stem in stems:
        image_path = images[stem]
        try:
            image = load_rgb8(image_path)
            mask = read_mask(root / "masks" / f"{stem}.png")
        except InvalidInputError as exc:
            raise InvalidInputError(f"{stem}: {exc.message}") from None
        keypoints_path = root / "keypoints" / f"{stem}.json"
        keypoints = _keypoints_file(keypoints_path) if keypoints_path.is_file() else None
        yield TrainingFrame(image, mask, keypoints, stem)
