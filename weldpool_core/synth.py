"""Synthetic weld-pool frames with ground truth, so tests and the demo need no private data.

A frame imitates the WAAM camera (``shared/data/waam``): a dark background above, a tungsten
electrode from the top, a filler wire from the right whose tip makes a notch in the pool, the
molten pool as a large dark region with an irregular outline and a bright rim, the rippled solid
bead trailing to the left, a bright arc glare over the pool's front, and sensor noise.

The ground truth is exact: the mask is the rasterised pool outline (less the wire), and the
keypoints and heatmap are what Algorithm 1 (``heatmap_from_mask``) gives on that mask. Within a
sequence the outline deforms smoothly: its shape parameters are slow sinusoids of time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Literal

from weldpool_core.errors import InvalidInputError
from weldpool_core.heatmap import HeatmapParams, heatmap_from_mask
from weldpool_core.keypoints import Points

if TYPE_CHECKING:
    import cv2
    import numpy as np
    from numpy.typing import NDArray
else:
    from weldpool_core.lazy import cv2, np

_OUTLINE_POINTS = 720
_SUBPIXEL_BITS = 4


@dataclass(frozen=True)
class SynthParams:
    """What the generator draws.

    Attributes:
        width: frame width in pixels (the WAAM camera: 1280).
        height: frame height in pixels (the WAAM camera: 800).
        bit_depth: 8 (uint8) or 16 (uint16, as a high-dynamic-range camera writes).
        noise_sigma: sensor noise, in 8-bit grey levels.
        fps: frame rate of ``synth_sequence``.
        heatmap: the Algorithm 1 parameters of the ground truth.
    """

    width: int = 1280
    height: int = 800
    bit_depth: Literal[8, 16] = 8
    noise_sigma: float = 3.0
    fps: float = 15.0
    heatmap: HeatmapParams = field(default_factory=HeatmapParams)

    def __post_init__(self) -> None:
        if self.width < 64 or self.height < 64:
            raise InvalidInputError("Synthetic frames must be at least 64×64 pixels.")
        if self.bit_depth not in (8, 16):
            raise InvalidInputError(f"bit_depth must be 8 or 16, not {self.bit_depth}.")
        if self.noise_sigma < 0 or self.fps <= 0:
            raise InvalidInputError("noise_sigma must be ≥ 0 and fps > 0.")


@dataclass(frozen=True)
class SynthFrame:
    """A synthetic frame and its ground truth.

    Attributes:
        image: H×W gray frame, uint8 or uint16.
        mask: H×W bool, the molten pool.
        keypoints: k×2 ``(x, y)``: Algorithm 1 on ``mask``.
        heatmap: H×W×2 float32 (heatmap, mask): Algorithm 1 on ``mask``.
        time_s: the frame's time in its sequence.
    """

    image: NDArray[np.uint8] | NDArray[np.uint16]
    mask: NDArray[np.bool_]
    keypoints: Points
    heatmap: NDArray[np.float32]
    time_s: float


@dataclass(frozen=True)
class _Wave:
    """A slow sinusoid ``mean + amplitude·sin(2π·frequency·t + phase)``."""

    mean: float
    amplitude: float
    frequency: float
    phase: float

    def at(self, time_s: float) -> float:
        return self.mean + self.amplitude * math.sin(
            2 * math.pi * self.frequency * time_s + self.phase
        )


def _wave(rng: np.random.Generator, mean: float, amplitude: float) -> _Wave:
    return _Wave(mean, amplitude, float(rng.uniform(0.15, 0.6)), float(rng.uniform(0, 2 * math.pi)))


@dataclass(frozen=True)
class _Pool:
    """A seeded weld pool: outline, wire, electrode and lighting as functions of time."""

    centre_x: _Wave
    centre_y: _Wave
    half_length: _Wave
    half_width: _Wave
    tail: _Wave
    notch_angle: _Wave
    notch_depth: _Wave
    notch_width: float
    harmonics: tuple[tuple[int, _Wave, float, float], ...]
    ripple_period: float
    islands: tuple[tuple[float, float, float, float], ...]

    @classmethod
    def draw(cls, rng: np.random.Generator) -> _Pool:
        harmonics = tuple(
            (
                order,
                _wave(rng, float(rng.uniform(0.01, 0.03)), 0.01),
                float(rng.uniform(0, 6.3)),
                float(rng.uniform(-0.8, 0.8)),
            )
            for order in range(3, 7)
        )
        islands = tuple(
            (
                float(rng.uniform(-0.6, 0.3)),
                float(rng.uniform(-0.6, 0.5)),
                float(rng.uniform(0.012, 0.03)),
                float(rng.uniform(0, 6.3)),
            )
            for _ in range(int(rng.integers(2, 5)))
        )
        return cls(
            centre_x=_wave(rng, float(rng.uniform(0.52, 0.58)), 0.01),
            centre_y=_wave(rng, float(rng.uniform(0.56, 0.62)), 0.008),
            half_length=_wave(rng, float(rng.uniform(0.25, 0.29)), 0.012),
            half_width=_wave(rng, float(rng.uniform(0.21, 0.26)), 0.01),
            tail=_wave(rng, float(rng.uniform(0.08, 0.2)), 0.03),
            notch_angle=_wave(rng, float(rng.uniform(-0.35, -0.1)), 0.04),
            notch_depth=_wave(rng, float(rng.uniform(0.08, 0.14)), 0.02),
            notch_width=float(rng.uniform(0.08, 0.13)),
            harmonics=harmonics,
            ripple_period=float(rng.uniform(16, 24)),
            islands=islands,
        )

    def outline(self, time_s: float, width: int, height: int) -> NDArray[np.float64]:
        """The pool outline at ``time_s``: a closed polygon (N×2, x y) in pixels."""
        phi = np.linspace(0, 2 * math.pi, _OUTLINE_POINTS, endpoint=False)
        radius = 1 + self.tail.at(time_s) * np.clip(-np.cos(phi), 0, None) ** 2
        for order, amplitude, phase, drift in self.harmonics:
            radius *= 1 + amplitude.at(time_s) * np.cos(order * phi + phase + drift * time_s)
        offset = np.angle(np.exp(1j * (phi - self.notch_angle.at(time_s))))
        radius *= 1 - self.notch_depth.at(time_s) * np.exp(-((offset / self.notch_width) ** 2))
        x = self.centre_x.at(time_s) * width + self.half_length.at(
            time_s
        ) * width * radius * np.cos(phi)
        y = self.centre_y.at(time_s) * height + self.half_width.at(
            time_s
        ) * height * radius * np.sin(phi)
        return np.stack([x, y], axis=1)

    def notch_tip(self, time_s: float, width: int, height: int) -> tuple[float, float]:
        """Where the wire touches the pool: the deepest point of the notch."""
        phi = self.notch_angle.at(time_s)
        inner = 1 - self.notch_depth.at(time_s)
        return (
            self.centre_x.at(time_s) * width
            + self.half_length.at(time_s) * width * inner * math.cos(phi),
            self.centre_y.at(time_s) * height
            + self.half_width.at(time_s) * height * inner * math.sin(phi),
        )


def _fill(polygon: NDArray[np.float64], shape: tuple[int, int]) -> NDArray[np.bool_]:
    canvas = np.zeros(shape, np.uint8)
    points = np.round(polygon * (1 << _SUBPIXEL_BITS)).astype(np.int32)
    cv2.fillPoly(canvas, [points], 1, lineType=cv2.LINE_8, shift=_SUBPIXEL_BITS)
    return canvas.astype(bool)


def _wire(tip: tuple[float, float], width: int, height: int) -> NDArray[np.float64]:
    """The filler wire: a band from beyond the right edge, up and to the right, to the tip."""
    entry = np.array([width * 1.05, height * 0.28])
    end = np.array(tip)
    along = (entry - end) / np.linalg.norm(entry - end)
    across = np.array([-along[1], along[0]]) * 0.018 * width
    return np.array([end + across, entry + across, entry - across, end - across])


def _scene(
    pool: _Pool,
    mask: NDArray[np.bool_],
    wire: NDArray[np.float64],
    time_s: float,
    rng: np.random.Generator,
) -> NDArray[np.float32]:
    """Grey levels (0..255, float) of everything but the noise."""
    height, width = mask.shape
    scale = math.sqrt(width * height / (1280 * 800))
    ys, xs = np.mgrid[0:height, 0:width].astype(np.float32)
    cx, cy = pool.centre_x.at(time_s) * width, pool.centre_y.at(time_s) * height
    # Background and the plate: dark above the horizon and in the bottom shadow, grey between.
    horizon = height * (0.33 + 0.02 * np.sin(xs / width * 3.0))
    surface = 1 / (1 + np.exp(-(ys - horizon) / (6 * scale)))
    surface *= 1 / (1 + np.exp((ys - height * 0.86) / (25 * scale)))
    grain = cv2.GaussianBlur(rng.normal(0, 1, (height, width)).astype(np.float32), (0, 0), 1.2)
    image = 10 + surface * (52 + 12 * grain)
    # The solid bead trailing left: bright ripples concentric with the pool's trailing edge.
    rx = (xs - cx) / (pool.half_length.at(time_s) * width)
    ry = (ys - cy) / (pool.half_width.at(time_s) * height)
    reach = np.sqrt(rx * rx + ry * ry) * pool.half_length.at(time_s) * width
    phase = 2 * math.pi * (reach / (pool.ripple_period * scale) + 0.6 * time_s)
    bead = surface * np.clip((cx - xs) / (0.15 * width), 0, 1)
    bead *= np.clip((1.15 - np.abs(ry)) / 0.2, 0, 1)
    sparkle = np.clip(rng.normal(0, 1, (height, width)).astype(np.float32), 0, None)
    image += bead * (15 + 70 * (0.5 + 0.5 * np.cos(phase)) ** 6 + 30 * sparkle)
    # The pool: dark, a faint reflection, bright oxide islands, and a bright rim outside it.
    inside = mask.astype(np.float32)
    reflection = 20 * np.clip(1 - np.hypot(rx + 0.3, ry), 0, 1)
    image = image * (1 - inside) + inside * (26 + reflection + 4 * grain)
    for dx, dy, size, angle in pool.islands:
        centre = (int(cx + dx * 0.25 * width + 8 * scale * time_s), int(cy + dy * 0.2 * height))
        axes = (max(int(size * width), 1), max(int(size * width * 0.4), 1))
        island = np.zeros((height, width), np.uint8)
        cv2.ellipse(island, centre, axes, math.degrees(angle), 0, 360, 1, -1)
        image += (island.astype(bool) & mask) * (45 + 60 * sparkle)
    outside = cv2.distanceTransform((~mask).view(np.uint8), cv2.DIST_L2, 3)
    trailing = np.clip(0.6 - 0.4 * rx, 0.2, 1)
    image += (1 - inside) * 95 * trailing * np.exp(-((outside / (3.5 * scale)) ** 2))
    # The electrode from the top, the arc glare below its tip, the wire from the right.
    tip_x, tip_y = cx + 0.1 * width, 0.27 * height
    electrode = np.array([[tip_x - 0.055 * width, 0], [tip_x + 0.06 * width, 0], [tip_x, tip_y]])
    cone = np.zeros((height, width), np.uint8)
    cv2.fillPoly(cone, [np.round(electrode).astype(np.int32)], 1)
    shine = np.clip(1 - np.abs(xs - (tip_x - 0.02 * width)) / (0.05 * width), 0, 1)
    image = np.where(cone.astype(bool), 90 + 150 * shine, image)
    glare = np.exp(
        -((xs - tip_x + 0.02 * width) ** 2 + (ys - 0.47 * height) ** 2) / (2 * (0.09 * width) ** 2)
    )
    image += 200 * glare + 80 * np.exp(
        -((xs - tip_x) ** 2 + (ys - tip_y) ** 2) / (2 * (0.03 * width) ** 2)
    )
    rod = np.zeros((height, width), np.uint8)
    cv2.fillPoly(rod, [np.round(wire).astype(np.int32)], 1)
    cv2.circle(rod, tuple(int(v) for v in wire[[0, 3]].mean(axis=0)), int(0.022 * width), 1, -1)
    rod_shade = cv2.GaussianBlur(rod.astype(np.float32), (0, 0), 0.01 * width)
    image = np.where(rod.astype(bool), 60 + 140 * rod_shade**3, image)
    return np.asarray(image, np.float32)


def _finish(
    image: NDArray[np.float32], params: SynthParams, rng: np.random.Generator
) -> NDArray[np.uint8] | NDArray[np.uint16]:
    """Sensor noise and a slight optical blur, then the camera's bit depth."""
    noise = rng.normal(0, params.noise_sigma, image.shape).astype(np.float32)
    noisy = np.asarray(cv2.GaussianBlur(image + noise, (3, 3), 0), np.float32)
    if params.bit_depth == 16:
        return np.clip(noisy * 257, 0, 65535).astype(np.uint16)
    return np.clip(np.round(noisy), 0, 255).astype(np.uint8)


def _frame(pool: _Pool, seed: int, time_s: float, params: SynthParams) -> SynthFrame:
    width, height = params.width, params.height
    rng = np.random.default_rng([seed, round(time_s * 1e6)])
    wire = _wire(pool.notch_tip(time_s, width, height), width, height)
    mask = _fill(pool.outline(time_s, width, height), (height, width)) & ~_fill(
        wire, (height, width)
    )
    truth = heatmap_from_mask(mask, params.heatmap)
    image = _finish(_scene(pool, mask, wire, time_s, rng), params, rng)
    return SynthFrame(image, mask, truth.keypoints, truth.heatmap, time_s)


def synth_frame(
    seed: int = 0, params: SynthParams | None = None, time_s: float = 0.0
) -> SynthFrame:
    """One frame of the synthetic weld run ``seed`` at ``time_s`` (same inputs, same frame)."""
    return _frame(_Pool.draw(np.random.default_rng(seed)), seed, time_s, params or SynthParams())


def _frozen(wave: _Wave, factor: float = 1.0) -> _Wave:
    """``wave`` held at its value at t = 0 (times ``factor``)."""
    return _Wave(wave.at(0.0) * factor, 0.0, wave.frequency, wave.phase)


def steady_pool_frame(
    seed: int = 0, params: SynthParams | None = None, time_s: float = 0.0, scale: float = 1.0
) -> SynthFrame:
    """A frame of a steady weld pool whose size a process sets: the pool of run ``seed`` with its
    shape held at t = 0 and its length and width multiplied by ``scale`` (about its centre); the
    lighting, ripples and sensor noise still change with ``time_s``. ``weldpool_core.cell.plant``
    renders its width with it, so a change in the frames is the process's, not the generator's.
    """
    if not 0.2 <= scale <= 1.6:
        raise InvalidInputError(
            f"A pool scale must be within 0.2–1.6 (it leaves the frame), not {scale}."
        )
    pool = _Pool.draw(np.random.default_rng(seed))
    steady = _Pool(
        centre_x=_frozen(pool.centre_x),
        centre_y=_frozen(pool.centre_y),
        half_length=_frozen(pool.half_length, scale),
        half_width=_frozen(pool.half_width, scale),
        tail=_frozen(pool.tail),
        notch_angle=_frozen(pool.notch_angle),
        notch_depth=_frozen(pool.notch_depth),
        notch_width=pool.notch_width,
        harmonics=tuple(
            (order, _frozen(amplitude), phase, 0.0)
            for order, amplitude, phase, drift in pool.harmonics
        ),
        ripple_period=pool.ripple_period,
        islands=pool.islands,
    )
    return _frame(steady, seed, time_s, params or SynthParams())


def synth_sequence(
    seed: int = 0, length: int = 8, params: SynthParams | None = None
) -> list[SynthFrame]:
    """``length`` consecutive frames (at ``params.fps``) of the weld run ``seed``."""
    if length < 1:
        raise InvalidInputError(f"A sequence needs at least one frame, not {length}.")
    params = params or SynthParams()
    pool = _Pool.draw(np.random.default_rng(seed))
    return [_frame(pool, seed, index / params.fps, params) for index in range(length)]


def nudge_outline(mask: NDArray[np.bool_], seed: int, amplitude: float) -> NDArray[np.bool_]:
    """``mask`` with its outline moved by a smooth random displacement of about ``amplitude``
    pixels (a noise field on a 40 px grid, cubic-interpolated, added to the signed distance):
    the small disagreement between two careful annotators, or two frames of a steady pool."""
    inside = cv2.distanceTransform(mask.astype(np.uint8), cv2.DIST_L2, 5)
    outside = cv2.distanceTransform((~mask).astype(np.uint8), cv2.DIST_L2, 5)
    rng = np.random.default_rng(seed)
    cells = rng.standard_normal((mask.shape[0] // 40 + 2, mask.shape[1] // 40 + 2))
    noise = cv2.resize(cells.astype(np.float32), mask.shape[::-1], interpolation=cv2.INTER_CUBIC)
    return np.asarray(inside - outside + amplitude * noise > 0)
