"""Steady keypoints over a stream: a one-euro filter on keypoint tracks, and how to measure it.

A per-frame student answers each frame alone, so its keypoints jitter by a pixel or more from
frame to frame where the pool barely moves; a servo controller turns that into torch
oscillation. ``KeypointSmoother`` keeps k tracks:

- **Identity.** Each frame's keypoints (at most k, in the order rule) are matched to the tracks
  by the smallest total distance (Hungarian, ``scipy.optimize.linear_sum_assignment``), so a
  keypoint that crosses the order rule's start direction keeps its track. A match farther than
  ``gate`` pixels starts the track anew (no smoothing across a jump); a track without a match
  holds its last value for ``hold`` frames, then is empty (None) until a keypoint arrives.
- **The one-euro filter** (Casiez, Roussel and Vogel, CHI 2012) on x and y of each track: an
  exponential low-pass whose cutoff rises with the track's speed, so a still pool is smoothed
  hard and a moving one is followed with little lag. ``min_cutoff`` (Hz) sets the smoothing at
  rest, ``beta`` how fast the cutoff opens with speed (px/s). Timestamps are the frames' capture
  times, so a dropped frame is a longer step, not a wrong one.

It is written here (twenty lines of arithmetic, vectorised over the k×2 coordinates) rather than
taken from the scalar one-euro packages on PyPI, which filter one float at a time.

``jitter`` and ``lag_frames`` measure the result without labels: jitter is the mean (or median)
size of the second difference of each track (a pool moving at a steady speed has none; noise
has it at about √6 times its standard deviation), lag the shift in frames that best aligns the
smoothed tracks with the raw ones.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import linear_sum_assignment

from weldpool_core.errors import InvalidInputError


@dataclass(frozen=True)
class SmoothingParams:
    """The one-euro filter's settings, and the track keeping around it.

    Attributes:
        min_cutoff: cutoff frequency at rest, in Hz (lower: steadier, more lag).
        beta: how fast the cutoff rises with speed, per px/s (higher: less lag when moving).
        derivative_cutoff: cutoff of the speed estimate, in Hz.
        gate: a keypoint farther than this (pixels) from its track restarts the track.
        hold: frames a track keeps its last value without a matching keypoint.
    """

    min_cutoff: float = 1.0
    beta: float = 0.05
    derivative_cutoff: float = 1.0
    gate: float = 60.0
    hold: int = 3

    def __post_init__(self) -> None:
        if min(self.min_cutoff, self.derivative_cutoff, self.gate) <= 0 or self.beta < 0:
            raise InvalidInputError(
                "Smoothing needs positive cutoffs and gate and a beta of 0 or more."
            )
        if self.hold < 0:
            raise InvalidInputError(f"hold must be 0 or more frames, not {self.hold}.")


def _alpha(cutoff: NDArray[Any] | float, step: float) -> Any:
    """Smoothing factor of an exponential low-pass with this cutoff (Hz) for a step (s)."""
    tau = 1.0 / (2.0 * math.pi * np.asarray(cutoff))
    return 1.0 / (1.0 + tau / step)


class KeypointSmoother:
    """k keypoint tracks through a stream, one-euro filtered (see the module doc)."""

    def __init__(self, k: int, params: SmoothingParams | None = None) -> None:
        if k < 1:
            raise InvalidInputError(f"k must be at least 1, not {k}.")
        self.k = k
        self.params = params or SmoothingParams()
        self._value = np.full((k, 2), np.nan)  # filtered position per track
        self._speed = np.zeros((k, 2))  # filtered derivative, px/s
        self._missed = np.zeros(k, np.intp)
        self._time: float | None = None

    def update(self, keypoints: NDArray[Any], time_s: float) -> list[list[float] | None]:
        """Filter one frame's keypoints (m×2, m ≤ k) captured at ``time_s``; one entry per track.

        Returns k entries in track order: ``[x, y]``, or None for a track that has no keypoint.
        """
        points = np.asarray(keypoints, np.float64).reshape(-1, 2)[: self.k]
        step = None if self._time is None else time_s - self._time
        self._time = time_s
        live = np.flatnonzero(~np.isnan(self._value[:, 0]))
        matched: dict[int, int] = {}
        if len(points) and len(live):
            cost = np.linalg.norm(points[:, None, :] - self._value[None, live, :], axis=2)
            rows, columns = linear_sum_assignment(cost)
            matched = {
                int(live[c]): int(r)
                for r, c in zip(rows, columns, strict=True)
                if cost[r, c] <= self.params.gate
            }
        taken = set(matched.values())
        free = [t for t in range(self.k) if t not in matched]
        # Unmatched keypoints go to empty tracks first, then to the longest-missed ones.
        free.sort(key=lambda t: (not np.isnan(self._value[t, 0]), -self._missed[t]))
        restarted = set()
        for index in (i for i in range(len(points)) if i not in taken):
            if free:
                track = free.pop(0)
                self._value[track], self._speed[track] = points[index], 0.0
                self._missed[track] = 0
                restarted.add(track)
        for track, index in matched.items():
            self._filter(track, points[index], step)
        for track in set(range(self.k)) - set(matched) - restarted:
            self._missed[track] += 1
            if self._missed[track] > self.params.hold:
                self._value[track] = np.nan
        return [None if np.isnan(v[0]) else [float(v[0]), float(v[1])] for v in self._value]

    def _filter(self, track: int, point: NDArray[Any], step: float | None) -> None:
        self._missed[track] = 0
        if not step or step <= 0:
            self._value[track] = point
            return
        p = self.params
        previous = self._value[track]
        speed = (point - previous) / step
        self._speed[track] += _alpha(p.derivative_cutoff, step) * (speed - self._speed[track])
        cutoff = p.min_cutoff + p.beta * np.abs(self._speed[track])
        self._value[track] = previous + _alpha(cutoff, step) * (point - previous)


def jitter(tracks: NDArray[Any], statistic: str = "mean") -> float:
    """Mean (or median) length of the second difference of T×k×2 tracks, px (NaN: empty).

    The mean counts jumps (a keypoint moving to another part of the outline) at full size; the
    median is the frame-to-frame noise of a keypoint that stays in place.
    """
    values = np.asarray(tracks, np.float64)
    if values.shape[0] < 3:
        raise InvalidInputError("Jitter needs at least three frames.")
    second = values[2:] - 2 * values[1:-1] + values[:-2]
    sizes = np.linalg.norm(second, axis=-1)
    if statistic == "median":
        return float(np.nanmedian(sizes))
    return float(np.nanmean(sizes))


def lag_frames(raw: NDArray[Any], smoothed: NDArray[Any], most: int = 10) -> int:
    """The shift d in frames (0…``most``) for which smoothed[t] is closest to raw[t − d]."""
    a, b = np.asarray(raw, np.float64), np.asarray(smoothed, np.float64)
    errors = []
    for shift in range(min(most, len(a) - 2) + 1):
        aligned = b[shift:] - a[: len(a) - shift]
        errors.append(float(np.nanmean(np.linalg.norm(aligned, axis=-1))))
    return int(np.argmin(errors))
