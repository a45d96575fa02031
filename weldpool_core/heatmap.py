"""Algorithm 1: a weld-pool mask → its k keypoints and an H×W×2 (heatmap, mask) training target.

The steps of METHOD.md ("Heatmap: Algorithm 1"), with the choices the paper leaves open made
explicit in ``HeatmapParams``:

1. ``S`` is the mask box-blurred (``blur_size``); the contour is the outer boundary of the
   largest region of ``S ≥ 0.5`` (``cv2.findContours``, every pixel kept, holes ignored).
2. Sobel x and y on ``S`` give the normal angle θᵢ = atan2(gy, gx) at each contour point.
3. The turn Δθᵢ = wrap(θᵢ₊ₛ − θᵢ₋ₛ): a central difference, so it does not depend on where the
   contour starts or which way it runs; s is ``turn_step`` of the contour's points (5 %: bends
   are judged at the scale of the pool, so a hand-drawn wiggle is not a corner, and alike at
   any resolution). Points with |Δθᵢ| > λ (``turn_threshold``) are the high-curvature points,
   each weighing its excess |Δθᵢ| − λ.
4. Groups with an identity. The paper's K-means on the high-curvature points gives groups that
   change when a weak bend appears or a strong one splits: on the 9 real WAAM labels a
   keypoint moved 130 px on average when the outline moved by 4–8 px (``bench/keypoints.py``).
   Here group j is anchored at the contour point seen from the centroid in direction
   ``order_start_deg`` + (j + ½)·360°/k (for k = 4 and the default start: the pool's back-top,
   front-top, front-bottom and back-bottom "corners", where a weld pool's bends are); every
   high-curvature point belongs to the two nearest groups with weights that fall linearly with
   its angle from their directions (a partition of unity), and group j's keypoint is the
   anchor moved along the contour by the weighted mean arc offset of its points, with the
   anchor itself weighing ``anchor_weight``·(contour points). A strong bend pulls its keypoint
   onto it; weak or absent bends leave it at the anchor (the completion rule). Every step is a
   continuous function of the outline, so small changes of the mask move keypoints a little
   and never renumber them.
5. Distinct parts: neighbouring keypoints closer than ``min_separation``·perimeter along the
   contour are pushed apart symmetrically. A keypoint's Gaussian has the covariance of the
   high-curvature points within s/2 of it along the contour (weighted by excess turn; over a
   whole group a long bend would spread it into a ridge with no clear peak for the student)
   plus ``covariance_floor``·I. A keypoint its bends did not place (their total weight under
   the anchor's, or none of them near it) is a completion keypoint with an isotropic Gaussian
   of ``completion_sigma``.
6. F = Σⱼ fⱼ with peak-1 Gaussians (so each keypoint is equally visible to the student), rendered
   only within ``window_sigmas`` standard deviations; channel 0 is F ⊙ S, channel 1 the mask.
   S is taken at full strength on the outline, min(1, 2S): the heatmap still fades out over the
   blur width outside the pool, but peaks exactly at the keypoints (with S itself, 0.5 on the
   outline, every peak would move inward by up to half the blur).

Keypoints are ``(x, y)`` pixel coordinates (origin at the top-left pixel's centre) in the order
rule of ``weldpool_core.keypoints`` (clockwise on screen around the pool's centroid from
``order_start_deg``). Exact ties are broken by averaging the tied points where that is
symmetric, else by the smaller ``(y, x)``.

Degenerate masks: an empty mask, or one whose largest region is smaller than ``min_area`` or
too thin to survive the blur, raises ``InvalidInputError``. With several regions the keypoints
mark the largest one by area after smoothing (equal areas: the one reaching higher, then
further left); the heatmap keeps every region in S. Holes are ignored. A region that
touches the image border is cut by it: the border is part of its outline.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal

from weldpool_core.errors import InvalidInputError
from weldpool_core.keypoints import ORDER_START_DEG, Points, angles_around, order_by_angle

if TYPE_CHECKING:
    import cv2
    import numpy as np
    from numpy.typing import NDArray
else:
    from weldpool_core.lazy import cv2, np

KeypointRule = Literal["curvature", "completion"]
"""Which rule placed a keypoint: its group's high-curvature points, or its anchor (completion)."""

_TIE = 1e-9
_NEIGHBOURS = 5


@dataclass(frozen=True)
class HeatmapParams:
    """Every open choice of Algorithm 1, with its default (see the module doc for the steps).

    Attributes:
        k: number of keypoints.
        blur_size: odd box-blur size in pixels for S (the paper's Block_B).
        turn_step: s in Δθᵢ = θᵢ₊ₛ − θᵢ₋ₛ, as a fraction of the contour's points (at least 2
            points), so λ means the same at 256×256 and at 1280×800.
        turn_threshold: λ in radians; |Δθᵢ| above it marks a high-curvature point (1.0 over
            ±5 % of the outline: a corner, not the end of a 2:1 ellipse).
        covariance_floor: pixels² added to each curvature keypoint's covariance.
        anchor_weight: weight of a group's anchor, per contour point, against the excess turns
            (radians) of its high-curvature points; larger keeps keypoints nearer the anchors.
        min_separation: smallest arc distance between keypoints, as a fraction of the perimeter;
            at most 1 / (2(k − 1)). None: 0.4 / k (0.1 for k = 4).
        completion_sigma: standard deviation in pixels of a completion keypoint's Gaussian.
        window_sigmas: a Gaussian is rendered within this many standard deviations.
        order_start_deg: start direction of the order rule (see ``weldpool_core.keypoints``).
        min_area: smallest region (pixels², after smoothing) that gets keypoints.
    """

    k: int = 4
    blur_size: int = 9
    turn_step: float = 0.05
    turn_threshold: float = 1.0
    covariance_floor: float = 4.0
    anchor_weight: float = 0.015
    min_separation: float | None = None
    completion_sigma: float = 3.0
    window_sigmas: float = 3.0
    order_start_deg: float = ORDER_START_DEG
    min_area: int = 16

    @property
    def separation(self) -> float:
        """``min_separation`` with its default resolved for this k."""
        return 0.4 / max(self.k, 1) if self.min_separation is None else self.min_separation

    def __post_init__(self) -> None:
        problems = []
        if self.k < 1:
            problems.append(f"k must be at least 1, not {self.k}")
        if self.blur_size < 1 or self.blur_size % 2 == 0:
            problems.append(f"blur_size must be a positive odd number, not {self.blur_size}")
        if not 0 < self.turn_step < 0.25 or self.anchor_weight <= 0:
            problems.append("turn_step must lie in (0, 0.25) and anchor_weight be positive")
        if self.turn_threshold < 0 or self.covariance_floor <= 0 or self.completion_sigma <= 0:
            problems.append("turn_threshold must be ≥ 0, covariance_floor and completion_sigma > 0")
        limit = 0.5 / (self.k - 1) if self.k > 1 else 0.5
        if not 0 <= self.separation <= limit:
            problems.append(f"min_separation must lie in [0, {limit:.3g}] for k={self.k}")
        if self.window_sigmas <= 0 or self.min_area < 1:
            problems.append("window_sigmas and min_area must be positive")
        if problems:
            raise InvalidInputError(f"Bad heatmap parameters: {'; '.join(problems)}.")


@dataclass(frozen=True)
class HeatmapResult:
    """Algorithm 1's output.

    Attributes:
        heatmap: H×W×2 float32: channel 0 the keypoint heatmap F ⊙ S, channel 1 the mask (0/1).
        keypoints: k×2 ``(x, y)`` in the order rule.
        rules: which rule placed each keypoint.
        covariances: k×2×2 covariance (pixels²) of each keypoint's Gaussian.
        contour: N×2 ``(x, y)`` outer contour of the region the keypoints mark, in order.
    """

    heatmap: NDArray[np.float32]
    keypoints: Points
    rules: tuple[KeypointRule, ...]
    covariances: NDArray[np.float64]
    contour: NDArray[np.float64]


@dataclass(frozen=True)
class _Smoothed:
    """S on a zero-padded crop around the mask; ``origin`` is the crop's top-left in the image."""

    values: NDArray[np.float32]
    origin: tuple[int, int]


def _foreground(mask: NDArray[Any]) -> NDArray[np.bool_]:
    """The pool pixels: True, nonzero integers, or floats ≥ 0.5 (a predicted probability)."""
    array = np.asarray(mask)
    if array.ndim == 3 and array.shape[2] == 1:
        array = array[:, :, 0]
    if array.ndim != 2 or array.size == 0:
        raise InvalidInputError(
            f"A mask must be a non-empty 2-D array, not of shape {array.shape}."
        )
    if array.dtype == np.bool_:
        return array
    if np.issubdtype(array.dtype, np.floating):
        return np.asarray(array >= 0.5)
    if np.issubdtype(array.dtype, np.integer):
        return np.asarray(array != 0)
    raise InvalidInputError(f"A mask must hold booleans or numbers, not {array.dtype}.")


def _smoothed(
    foreground: NDArray[np.bool_], blur_size: int, origin: tuple[int, int] = (0, 0)
) -> _Smoothed:
    """S = box blur of the mask, computed on its bounding box padded with zeros; ``origin``:
    where the mask lies in its frame (the part of a frame around its pool: the same S)."""
    x, y, w, h = cv2.boundingRect(foreground.view(np.uint8))
    if w == 0 or h == 0:
        raise InvalidInputError("The mask is empty: it has no foreground pixel to outline.")
    pad = blur_size // 2 + 2
    height, width = foreground.shape
    x0, y0, x1, y1 = x - pad, y - pad, x + w + pad, y + h + pad
    crop = foreground[max(y0, 0) : min(y1, height), max(x0, 0) : min(x1, width)]
    padded = cv2.copyMakeBorder(
        crop.view(np.uint8),
        max(-y0, 0),
        max(y1 - height, 0),
        max(-x0, 0),
        max(x1 - width, 0),
        cv2.BORDER_CONSTANT,
        value=0,
    )
    values = np.asarray(cv2.blur(padded.astype(np.float32), (blur_size, blur_size)), np.float32)
    return _Smoothed(values, (x0 + origin[0], y0 + origin[1]))


def _outer_contour(smoothed: NDArray[np.float32], min_area: int) -> NDArray[np.int32]:
    """Ordered outer contour (N×2, x y) of the largest region of S ≥ 0.5."""
    binary = (smoothed >= 0.5).astype(np.uint8)
    contours, _ = cv2.findContours(binary, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if not contours:
        raise InvalidInputError(
            "The mask region is too small or too thin to outline after smoothing; use a larger "
            "region or a smaller blur_size."
        )
    outlines = [c.reshape(-1, 2) for c in contours]
    areas = [cv2.contourArea(c) for c in outlines]
    best = min(
        range(len(outlines)),
        key=lambda i: (-areas[i], int(outlines[i][:, 1].min()), int(outlines[i][:, 0].min())),
    )
    if areas[best] < min_area:
        raise InvalidInputError(
            f"The mask region is too small for keypoints ({areas[best]:.0f} px² after smoothing, "
            f"at least {min_area} needed)."
        )
    return np.asarray(outlines[best], np.int32)


def _centroid(contour: NDArray[np.int32]) -> tuple[float, float]:
    """Centroid of the area the contour encloses (of its points, for a region without area)."""
    moments = cv2.moments(contour)
    if moments["m00"] > 0:
        return moments["m10"] / moments["m00"], moments["m01"] / moments["m00"]
    return float(contour[:, 0].mean()), float(contour[:, 1].mean())


def _step(points: int, params: HeatmapParams) -> int:
    """s of the turn Δθᵢ = θᵢ₊ₛ − θᵢ₋ₛ for a contour of ``points`` points."""
    return max(2, round(params.turn_step * points))


def _turns(smoothed: NDArray[np.float32], contour: NDArray[np.int32], step: int) -> NDArray[Any]:
    """|Δθᵢ|: how much the normal turns across each contour point (central difference)."""
    gx = cv2.Sobel(smoothed, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(smoothed, cv2.CV_32F, 0, 1, ksize=3)
    xs, ys = contour[:, 0], contour[:, 1]
    normal = np.arctan2(gy[ys, xs].astype(np.float64), gx[ys, xs].astype(np.float64))
    change = np.roll(normal, -step) - np.roll(normal, step)
    return np.abs(np.mod(change + math.pi, 2 * math.pi) - math.pi)


def _arc_positions(contour: NDArray[Any]) -> tuple[NDArray[np.float64], float]:
    """Arc length from the first contour point to each point, and the perimeter."""
    steps = np.linalg.norm(np.diff(contour, axis=0, append=contour[:1]), axis=1)
    positions = np.concatenate(([0.0], np.cumsum(steps)[:-1]))
    return positions, float(steps.sum())


def _arc_distance(a: NDArray[Any], b: NDArray[Any], perimeter: float) -> NDArray[np.float64]:
    """Distance along a closed contour between every arc position in ``a`` and in ``b``."""
    gap = np.mod(np.abs(np.subtract.outer(a, b)), perimeter)
    distance: NDArray[np.float64] = np.minimum(gap, perimeter - gap)
    return distance


def _nearest(distance: NDArray[Any], contour: NDArray[Any]) -> tuple[Any, NDArray[np.intp]]:
    """The contour point of smallest ``distance`` and the indices of the equally near points.

    Equally near neighbours (a target between two pixels) are averaged, which is symmetric;
    equally near points far apart along the contour are not: the smaller ``(y, x)`` wins.
    """
    tied = np.flatnonzero(distance <= distance.min() + _TIE)
    points = contour[tied].astype(np.float64)
    if np.ptp(points, axis=0).max() <= _NEIGHBOURS:
        return points.mean(axis=0), tied
    first = tied[np.lexsort((points[:, 0], points[:, 1]))[:1]]
    return contour[first[0]].astype(np.float64), first


def _circular_mean(positions: NDArray[Any], perimeter: float) -> float:
    """Mean of arc positions on a closed contour (so that 0 and the perimeter are neighbours)."""
    angles = positions * (2 * math.pi / perimeter)
    mean = math.atan2(float(np.sin(angles).mean()), float(np.cos(angles).mean()))
    return (mean % (2 * math.pi)) * perimeter / (2 * math.pi)


def _point_at_arc(
    target: float, contour: NDArray[Any], arcs: NDArray[Any], perimeter: float
) -> Any:
    """The contour point at arc position ``target`` (two equally near: their mean)."""
    return _nearest(_arc_distance(arcs, np.array([target]), perimeter)[:, 0], contour)[0]


def _signed_arc(arcs: NDArray[Any], origin: float, perimeter: float) -> NDArray[np.float64]:
    """Arc offset of each position from ``origin``, wrapped to [−perimeter/2, perimeter/2)."""
    offset: NDArray[np.float64] = np.mod(arcs - origin + perimeter / 2, perimeter) - perimeter / 2
    return offset


def _anchor_arc(off: NDArray[Any], arcs: NDArray[Any], perimeter: float) -> float:
    """Arc position of the contour point seen from the centroid in a direction, each point
    being ``off`` it (radians); equally near points average (on the circle of arc positions)."""
    tied = np.flatnonzero(off <= off.min() + _TIE)
    return _circular_mean(arcs[tied], perimeter)


def _separate(positions: list[float], perimeter: float, separation: float) -> list[float]:
    """Push neighbouring keypoints (in group order around the contour) apart to ``separation``.

    Each pair closer than that moves apart symmetrically about its middle; a few sweeps settle
    chains. Positions only move continuously with the shape, so a small change of the mask
    never renumbers or swaps keypoints.
    """
    out = list(positions)
    count = len(out)
    if count < 2 or separation <= 0:
        return out
    for _ in range(4 * count):
        moved = False
        for j in range(count):
            nxt = (j + 1) % count
            # ``_signed_arc`` of one position, in Python's floats (the same operations)
            gap = (out[nxt] - out[j] + perimeter / 2) % perimeter - perimeter / 2
            # groups go round the contour in one direction; the gap is the signed step to the next
            step = abs(gap)
            if step < separation - 1e-9:
                push = (separation - step) / 2 * (1 if gap >= 0 else -1)
                out[j] = (out[j] - push) % perimeter
                out[nxt] = (out[nxt] + push) % perimeter
                moved = True
        if not moved:
            break
    return out


def _select_keypoints(
    contour: NDArray[np.int32],
    turns: NDArray[Any],
    centre: tuple[float, float],
    params: HeatmapParams,
    with_spread: bool = True,
) -> tuple[list[NDArray[np.float64]], list[NDArray[np.float64]], list[KeypointRule]]:
    """Steps 4–5: k groups of high-curvature points anchored around the pool (module doc);
    ``with_spread`` False: no covariances (zeros), the keypoints alone, as a label stores them."""
    arcs, perimeter = _arc_positions(contour)
    angles = angles_around(contour, centre, params.order_start_deg)
    width = 2 * math.pi / params.k
    excess = np.clip(turns - params.turn_threshold, 0.0, None)
    prior = params.anchor_weight * len(contour)
    reach = 0.5 * _step(len(contour), params) * perimeter / len(contour)
    positions: list[float] = []
    weights: list[float] = []
    for j in range(params.k):
        direction = (j + 0.5) * width
        off = np.abs(np.mod(angles - direction + math.pi, 2 * math.pi) - math.pi)
        anchor = _anchor_arc(off, arcs, perimeter)
        share = excess * np.clip(1.0 - off / width, 0.0, None)
        pull = float((share * _signed_arc(arcs, anchor, perimeter)).sum())
        positions.append((anchor + pull / (float(share.sum()) + prior)) % perimeter)
        weights.append(float(share.sum()))
    positions = _separate(positions, perimeter, params.separation * perimeter)
    keypoints: list[NDArray[np.float64]] = []
    covariances: list[NDArray[np.float64]] = []
    rules: list[KeypointRule] = []
    points = contour.astype(np.float64)
    for position, weight in zip(positions, weights, strict=True):
        keypoint = _point_at_arc(position, contour, arcs, perimeter)
        near = excess * (np.abs(_signed_arc(arcs, position, perimeter)) <= reach)
        curved = weight >= prior and float(near.sum()) > _TIE
        if not with_spread:
            covariance = np.zeros((2, 2))
        elif curved:
            centred = points - keypoint
            spread = (near[:, None, None] * centred[:, :, None] * centred[:, None, :]).sum(0)
            covariance = spread / float(near.sum()) + params.covariance_floor * np.eye(2)
        else:
            covariance = params.completion_sigma**2 * np.eye(2)
        keypoints.append(np.asarray(keypoint, np.float64))
        covariances.append(covariance)
        rules.append("curvature" if curved else "completion")
    return keypoints, covariances, rules


def gaussian_window(
    centre: tuple[float, float],
    covariance: NDArray[np.float64],
    limits: tuple[int, int, int, int],
    window_sigmas: float,
) -> tuple[slice, slice, NDArray[np.float32]] | None:
    """A peak-1 Gaussian at ``centre`` (``(x, y)``) within ``window_sigmas`` standard deviations.

    ``limits`` ``(x0, y0, x1, y1)`` bound the window (the image, or a crop of it). Returns the
    window's rows and columns and the Gaussian's values there (float32), or None when the window
    lies outside the limits.
    """
    mx, my = centre
    half_x = window_sigmas * math.sqrt(covariance[0, 0])
    half_y = window_sigmas * math.sqrt(covariance[1, 1])
    x0 = max(math.floor(mx - half_x), limits[0])
    y0 = max(math.floor(my - half_y), limits[1])
    x1 = min(math.ceil(mx + half_x) + 1, limits[2])
    y1 = min(math.ceil(my + half_y) + 1, limits[3])
    if x0 >= x1 or y0 >= y1:
        return None
    inverse = np.linalg.inv(covariance)
    dx = np.arange(x0, x1, dtype=np.float32)[None, :] - np.float32(mx)
    dy = np.arange(y0, y1, dtype=np.float32)[:, None] - np.float32(my)
    quadratic = (
        np.float32(inverse[0, 0]) * dx * dx
        + np.float32(2 * inverse[0, 1]) * dx * dy
        + np.float32(inverse[1, 1]) * dy * dy
    )
    return slice(y0, y1), slice(x0, x1), np.exp(np.float32(-0.5) * quadratic)


def _render(
    heatmap: NDArray[np.float32],
    smoothed: _Smoothed,
    keypoints: Points,
    covariances: NDArray[np.float64],
    window_sigmas: float,
) -> None:
    """Step 6: add each Gaussian times min(1, 2S) into ``heatmap``, within its window only."""
    height, width = heatmap.shape
    ox, oy = smoothed.origin
    crop_h, crop_w = smoothed.values.shape
    limits = (max(0, ox), max(0, oy), min(width, ox + crop_w), min(height, oy + crop_h))
    for (mx, my), covariance in zip(keypoints, covariances, strict=True):
        window = gaussian_window((mx, my), covariance, limits, window_sigmas)
        if window is None:
            continue
        rows, columns, gaussian = window
        crop_rows = slice(rows.start - oy, rows.stop - oy)
        pool = smoothed.values[crop_rows, columns.start - ox : columns.stop - ox]
        heatmap[rows, columns] += gaussian * np.minimum(pool + pool, np.float32(1))


@dataclass(frozen=True)
class _Placed:
    """Algorithm 1 up to its keypoints (what the heatmap is then rendered from)."""

    foreground: NDArray[np.bool_]
    smoothed: _Smoothed
    points: NDArray[np.float64]
    spread: NDArray[np.float64]
    rules: tuple[KeypointRule, ...]
    contour: NDArray[np.float64]


def _placed(
    mask: NDArray[Any],
    params: HeatmapParams,
    origin: tuple[int, int] = (0, 0),
    with_spread: bool = True,
) -> _Placed:
    foreground = _foreground(mask)
    smoothed = _smoothed(foreground, params.blur_size, origin)
    local = _outer_contour(smoothed.values, params.min_area)
    turns = _turns(smoothed.values, local, _step(len(local), params))
    centre = _centroid(local)
    keypoints, covariances, rules = _select_keypoints(local, turns, centre, params, with_spread)
    offset = np.array(smoothed.origin, np.float64)
    points = np.array(keypoints) + offset
    order = order_by_angle(
        points, (centre[0] + offset[0], centre[1] + offset[1]), params.order_start_deg
    )
    return _Placed(
        foreground=foreground,
        smoothed=smoothed,
        points=points[order],
        spread=np.array(covariances)[order],
        rules=tuple(rules[i] for i in order),
        contour=local.astype(np.float64) + offset,
    )


def keypoints_from_mask(
    mask: NDArray[Any], params: HeatmapParams | None = None, origin: tuple[int, int] = (0, 0)
) -> NDArray[np.float64]:
    """Algorithm 1's k×2 keypoints of a mask, without rendering the heatmap (a sixth of
    ``heatmap_from_mask``'s time on a 1280×800 frame): what a label stores. ``origin``
    ``(left, top)``: where ``mask`` lies when it is only the part of a frame around its pool
    (the keypoints are the whole frame's, in its pixels)."""
    return _placed(mask, params or HeatmapParams(), origin, with_spread=False).points


def heatmap_from_mask(mask: NDArray[Any], params: HeatmapParams | None = None) -> HeatmapResult:
    """Algorithm 1 on a mask (H×W; bool, nonzero integers or floats ≥ 0.5 are the pool).

    Returns the H×W×2 (heatmap, mask) array, the k keypoints in the order rule and which rule
    placed each. Raises InvalidInputError for an empty, tiny or too-thin mask.
    """
    params = params or HeatmapParams()
    placed = _placed(mask, params)
    heat = np.zeros(placed.foreground.shape, np.float32)
    _render(heat, placed.smoothed, placed.points, placed.spread, params.window_sigmas)
    heatmap = np.asarray(cv2.merge([heat, placed.foreground.astype(np.float32)]), np.float32)
    return HeatmapResult(
        heatmap=heatmap,
        keypoints=placed.points,
        rules=placed.rules,
        covariances=placed.spread,
        contour=placed.contour,
    )


def mask_keypoints(mask: NDArray[np.bool_], origin: tuple[int, int] = (0, 0)) -> list[list[float]]:
    """Algorithm 1's keypoints of a label's mask (one drawn or imported; the part at ``origin``
    of its frame, as ``keypoints_from_mask``), as [[x, y], …]."""
    try:
        points = keypoints_from_mask(mask, origin=origin)
    except InvalidInputError as exc:
        raise InvalidInputError(
            f"Keypoints cannot be computed for this mask: {exc.message}"
        ) from None
    return [[float(x), float(y)] for x, y in np.asarray(points)]


def heatmap_rgba(heat: NDArray[Any]) -> NDArray[np.uint8]:
    """A heatmap channel (H×W, ≥ 0) as an RGBA colour map for display: inferno scaled to its
    maximum, transparent where it is zero (alpha = the scaled heat)."""
    scaled = np.clip(heat / max(float(heat.max()), 1e-6), 0, 1)
    level = (scaled * 255).astype(np.uint8)
    colours = cv2.applyColorMap(level, cv2.COLORMAP_INFERNO)
    return np.dstack([colours[:, :, ::-1], level]).astype(np.uint8)
