"""Algorithm 1: a weld-pool mask → its k keypoints and an H×W×2 (heatmap, mask) training target.

The steps of METHOD.md ("Heatmap: Algorithm 1"), with the choices the paper leaves open made
explicit in ``HeatmapParams``:

1. ``S`` is the mask box-blurred (``blur_size``); the contour is the outer boundary of the
   largest region of ``S ≥ 0.5`` (``cv2.findContours``, every pixel kept, holes ignored).
2. Sobel x and y on ``S`` give the normal angle θᵢ = atan2(gy, gx) at each contour point.
3. The turn Δθᵢ = wrap(θᵢ₊ₛ − θᵢ₋ₛ): a central difference, so it does not depend on where the
   contour starts or which way it runs; s is ``turn_step`` of the contour's points, so that a
   bend is judged alike at any resolution. Points with |Δθᵢ| > λ (``turn_threshold``) are the
   high-curvature points.
4. K-means groups them into at most k groups. It starts from the means of the k strongest
   bends (runs of consecutive high-curvature points, by summed |Δθ|) rather than from random
   seeds, which would depend on the order of the points and so break mirror symmetry. A group's
   keypoint is the contour point nearest its mean; its Gaussian has the group's covariance plus
   ``covariance_floor``·I (never singular).
5. Distinct parts: groups closer than ``min_separation``·perimeter along the contour merge (on
   real pools the sharpest bends crowd in the wire's notch). Completion then adds keypoints
   until there are k, spread over the gaps between the chosen ones so that the smallest spacing
   is as large as possible: each goes to the gap whose pieces are now longest, and a gap with n
   new keypoints is cut into n + 1 equal arcs. Without any bend, the first keypoint is the
   contour point farthest from the centroid (the middle of a flat run of such points).
   Completion keypoints get an isotropic Gaussian of ``completion_sigma``.
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
from typing import Any, Literal

import cv2
import numpy as np
from numpy.typing import NDArray

from weldpool_core.errors import InvalidInputError
from weldpool_core.keypoints import ORDER_START_DEG, Points, order_by_angle

KeypointRule = Literal["curvature", "completion"]
"""Which rule placed a keypoint: a K-means group of high-curvature points, or completion."""

_TIE = 1e-9
_NEIGHBOURS = 5
_PLATEAU = 1.0


@dataclass(frozen=True)
class HeatmapParams:
    """Every open choice of Algorithm 1, with its default (see the module doc for the steps).

    Attributes:
        k: number of keypoints.
        blur_size: odd box-blur size in pixels for S (the paper's Block_B).
        turn_step: s in Δθᵢ = θᵢ₊ₛ − θᵢ₋ₛ, as a fraction of the contour's points (at least 2
            points), so λ means the same at 256×256 and at 1280×800.
        turn_threshold: λ in radians; |Δθᵢ| above it marks a high-curvature point. 0.5 is
            sharper than the ends of a 2:1 ellipse: only real corners (the wire's notch, a
            pointed tail) count, and weak bends do not flicker in and out between frames.
        covariance_floor: pixels² added to each group's covariance (σ ≥ √floor everywhere).
        kmeans_iterations: most Lloyd iterations of K-means (it starts from the strongest
            bends, so it has no random seed and needs no restarts).
        min_separation: smallest arc distance between keypoints, as a fraction of the perimeter;
            at most 1 / (2(k − 1)), which completion can always honour. None: 0.4 / k (0.1 for
            k = 4, so four keypoints keep at least 40 % of an even spacing).
        completion_sigma: standard deviation in pixels of a completion keypoint's Gaussian.
        window_sigmas: a Gaussian is rendered within this many standard deviations.
        order_start_deg: start direction of the order rule (see ``weldpool_core.keypoints``).
        min_area: smallest region (pixels², after smoothing) that gets keypoints.
    """

    k: int = 4
    blur_size: int = 9
    turn_step: float = 0.01
    turn_threshold: float = 0.5
    covariance_floor: float = 4.0
    kmeans_iterations: int = 30
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
        if not 0 < self.turn_step < 0.25 or self.kmeans_iterations < 1:
            problems.append("turn_step must lie in (0, 0.25), kmeans_iterations be at least 1")
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


def _smoothed(foreground: NDArray[np.bool_], blur_size: int) -> _Smoothed:
    """S = box blur of the mask, computed on its bounding box padded with zeros."""
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
    return _Smoothed(values, (x0, y0))


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


def _first_of_ties(scores: NDArray[Any], contour: NDArray[Any]) -> int:
    """Index of the largest score; among ties, the contour point with the smallest (y, x)."""
    tied = np.flatnonzero(scores >= scores.max() - _TIE)
    return int(tied[np.lexsort((contour[tied, 0], contour[tied, 1]))[0]])


@dataclass(frozen=True)
class _Group:
    """A group of high-curvature contour points, where its keypoint sits and its Gaussian."""

    members: NDArray[np.intp]
    keypoint: NDArray[np.float64]
    arc: float
    covariance: NDArray[np.float64]


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


def _group(
    members: NDArray[np.intp],
    contour: NDArray[np.int32],
    arcs: NDArray[Any],
    perimeter: float,
    floor: float,
) -> _Group:
    """A group: its keypoint is the contour point nearest its mean (equally near ones: averaged)."""
    points = contour[members].astype(np.float64)
    mean = points.mean(axis=0)
    keypoint, tied = _nearest(np.hypot(contour[:, 0] - mean[0], contour[:, 1] - mean[1]), contour)
    centred = points - mean
    return _Group(
        members=members,
        keypoint=keypoint,
        arc=_circular_mean(arcs[tied], perimeter),
        covariance=centred.T @ centred / len(points) + floor * np.eye(2),
    )


def _bend_runs(is_bend: NDArray[np.bool_], bridge: int) -> list[NDArray[np.intp]]:
    """Runs of consecutive high-curvature contour points (cyclic); gaps ≤ ``bridge`` joined."""
    count = len(is_bend)
    bends = np.flatnonzero(is_bend)
    if bends.size in (0, count):
        return [bends] if bends.size else []
    steps = (np.roll(bends, -1) - bends) % count
    breaks = np.flatnonzero(steps > bridge + 1)
    if breaks.size == 0:
        return [bends]
    bends = np.roll(bends, -(int(breaks[0]) + 1))  # start right after a break
    return np.split(bends, np.flatnonzero(np.diff(bends) % count > bridge + 1) + 1)


def _kmeans(
    points: NDArray[np.float64], centres: NDArray[np.float64], iterations: int
) -> NDArray[np.intp]:
    """Lloyd's K-means from the given centres; returns each point's group."""
    labels = np.zeros(len(points), np.intp)
    for _ in range(iterations):
        distance = ((points[:, None, :] - centres[None, :, :]) ** 2).sum(axis=2)
        labels = np.argmin(distance, axis=1)
        moved = np.array(
            [
                points[labels == j].mean(axis=0) if np.any(labels == j) else centres[j]
                for j in range(len(centres))
            ]
        )
        if np.array_equal(moved, centres):
            break
        centres = moved
    return labels


def _curvature_groups(
    contour: NDArray[np.int32],
    turns: NDArray[Any],
    arcs: NDArray[Any],
    perimeter: float,
    params: HeatmapParams,
) -> list[_Group]:
    """Step 4: K-means on the high-curvature points; groups closer than the separation merge.

    K-means starts from the means of the k strongest bends (runs of high-curvature points,
    by summed |Δθ|). Unlike random k-means++ seeds, this start does not depend on the order of
    the points, so the groups do not change when the contour starts elsewhere or is mirrored.
    """
    runs = _bend_runs(turns > params.turn_threshold, _step(len(contour), params))
    if not runs:
        return []
    strength = [float(turns[run].sum()) for run in runs]
    means = [contour[run].mean(axis=0) for run in runs]
    strongest = sorted(range(len(runs)), key=lambda i: (-strength[i], means[i][1], means[i][0]))
    members = np.concatenate(runs)
    points = contour[members].astype(np.float64)
    centres = np.array([means[i] for i in strongest[: params.k]], np.float64)
    labels = _kmeans(points, centres, params.kmeans_iterations)
    floor = params.covariance_floor
    groups = [
        _group(members[labels == label], contour, arcs, perimeter, floor)
        for label in range(len(centres))
        if np.any(labels == label)
    ]
    separation = params.separation * perimeter
    while len(groups) > 1:
        positions = np.array([g.arc for g in groups])
        gaps = _arc_distance(positions, positions, perimeter)
        np.fill_diagonal(gaps, np.inf)
        first, second = np.unravel_index(int(np.argmin(gaps)), gaps.shape)
        if gaps[first, second] >= separation:
            break
        merged = np.concatenate((groups[first].members, groups[second].members))
        groups = [g for i, g in enumerate(groups) if i not in (first, second)]
        groups.append(_group(merged, contour, arcs, perimeter, floor))
    return groups


def _plateau_middle(scores: NDArray[Any], contour: NDArray[Any]) -> int:
    """Index of the largest score; on a plateau (a run of points within 1 px of it), its middle.

    A pixel contour has flat runs (the end of an ellipse), so the exact maximum would jump along
    the run under a flip; the run's middle does not. Ties between runs go to the smaller (y, x).
    """
    near = scores >= scores.max() - _PLATEAU
    if near.all():
        return _first_of_ties(scores, contour)
    best = _first_of_ties(scores, contour)
    # Walk both ways from the best point while the score stays on the plateau.
    count = len(scores)
    forward = backward = 0
    while near[(best + forward + 1) % count]:
        forward += 1
    while near[(best - backward - 1) % count]:
        backward += 1
    run = (best + np.arange(-backward, forward + 1)) % count
    steps = np.concatenate(([0.0], np.cumsum(np.hypot(*np.diff(contour[run], axis=0).T))))
    return int(run[int(np.argmin(np.abs(steps - steps[-1] / 2)))])


def _point_at_arc(
    target: float, contour: NDArray[Any], arcs: NDArray[Any], perimeter: float
) -> Any:
    """The contour point at arc position ``target`` (two equally near: their mean)."""
    return _nearest(_arc_distance(arcs, np.array([target]), perimeter)[:, 0], contour)[0]


def _spread_along_gaps(taken: list[float], count: int, perimeter: float) -> list[float]:
    """Arc positions of ``count`` new keypoints that keep the smallest spacing as large as possible.

    Each new keypoint goes to the gap (between chosen keypoints) whose pieces are now longest; a
    gap that receives n keypoints is cut into n + 1 equal pieces. It depends only on the gaps, not
    on where the contour starts or which way it runs.
    """
    starts = sorted(taken)
    lengths = [*np.diff(starts), starts[0] + perimeter - starts[-1]]
    given = [0] * len(starts)
    for _ in range(count):
        pieces = [length / (n + 1) for length, n in zip(lengths, given, strict=True)]
        widest = max(range(len(pieces)), key=lambda i: (pieces[i], -i))
        given[widest] += 1
    return [
        float((start + length * j / (n + 1)) % perimeter)
        for start, length, n in zip(starts, lengths, given, strict=True)
        for j in range(1, n + 1)
    ]


def _select_keypoints(
    contour: NDArray[np.int32],
    turns: NDArray[Any],
    centre: tuple[float, float],
    params: HeatmapParams,
) -> tuple[list[NDArray[np.float64]], list[NDArray[np.float64]], list[KeypointRule]]:
    """Step 5: the separated curvature groups, then completion along the contour up to k."""
    arcs, perimeter = _arc_positions(contour)
    groups = _curvature_groups(contour, turns, arcs, perimeter, params)
    keypoints = [g.keypoint for g in groups]
    covariances = [g.covariance for g in groups]
    rules: list[KeypointRule] = ["curvature"] * len(groups)
    taken = [g.arc for g in groups]
    if not taken:
        distance = np.hypot(contour[:, 0] - centre[0], contour[:, 1] - centre[1])
        farthest = _plateau_middle(distance, contour)
        taken = [float(arcs[farthest])]
        keypoints.append(contour[farthest].astype(np.float64))
        covariances.append(params.completion_sigma**2 * np.eye(2))
        rules.append("completion")
    for target in _spread_along_gaps(taken, params.k - len(taken), perimeter):
        keypoints.append(_point_at_arc(target, contour, arcs, perimeter))
        covariances.append(params.completion_sigma**2 * np.eye(2))
        rules.append("completion")
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


def heatmap_from_mask(mask: NDArray[Any], params: HeatmapParams | None = None) -> HeatmapResult:
    """Algorithm 1 on a mask (H×W; bool, nonzero integers or floats ≥ 0.5 are the pool).

    Returns the H×W×2 (heatmap, mask) array, the k keypoints in the order rule and which rule
    placed each. Raises InvalidInputError for an empty, tiny or too-thin mask.
    """
    params = params or HeatmapParams()
    foreground = _foreground(mask)
    smoothed = _smoothed(foreground, params.blur_size)
    local = _outer_contour(smoothed.values, params.min_area)
    turns = _turns(smoothed.values, local, _step(len(local), params))
    centre = _centroid(local)
    keypoints, covariances, rules = _select_keypoints(local, turns, centre, params)
    origin = np.array(smoothed.origin, np.float64)
    contour = local.astype(np.float64) + origin
    points = np.array(keypoints) + origin
    order = order_by_angle(
        points, (centre[0] + origin[0], centre[1] + origin[1]), params.order_start_deg
    )
    points, spread = points[order], np.array(covariances)[order]
    heat = np.zeros(foreground.shape, np.float32)
    _render(heat, smoothed, points, spread, params.window_sigmas)
    heatmap = np.asarray(cv2.merge([heat, foreground.astype(np.float32)]), np.float32)
    return HeatmapResult(
        heatmap=heatmap,
        keypoints=points,
        rules=tuple(rules[i] for i in order),
        covariances=spread,
        contour=contour,
    )
