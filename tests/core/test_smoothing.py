"""The one-euro keypoint smoother: its formula, what it removes, what it costs, track identity."""

from __future__ import annotations

import math

import numpy as np
import pytest

from weldpool_core.cell.smoothing import KeypointSmoother, SmoothingParams, jitter, lag_frames
from weldpool_core.errors import InvalidInputError

FPS = 15.0


def _run(smoother: KeypointSmoother, frames: np.ndarray, fps: float = FPS) -> np.ndarray:
    out = [smoother.update(points, index / fps) for index, points in enumerate(frames)]
    return np.array([[p if p is not None else [np.nan, np.nan] for p in row] for row in out])


def test_one_step_follows_the_one_euro_formula() -> None:
    """From 0 to 10 in one second with beta 0: alpha = 1 / (1 + tau / T), tau = 1 / (2π fc)."""
    smoother = KeypointSmoother(1, SmoothingParams(min_cutoff=1.0, beta=0.0))
    smoother.update(np.array([[0.0, 0.0]]), 0.0)
    moved = smoother.update(np.array([[10.0, -4.0]]), 1.0)
    alpha = 1.0 / (1.0 + 1.0 / (2 * math.pi))
    assert moved == [[pytest.approx(10 * alpha), pytest.approx(-4 * alpha)]]
    # The time step is the capture times', not a frame count: a tenth of a second moves less.
    quick = KeypointSmoother(1, SmoothingParams(min_cutoff=1.0, beta=0.0))
    quick.update(np.array([[0.0, 0.0]]), 0.0)
    tenth = 1.0 / (1.0 + 10.0 / (2 * math.pi))
    assert quick.update(np.array([[10.0, 0.0]]), 0.1)[0][0] == pytest.approx(10 * tenth)


def test_a_still_pool_keeps_its_place_with_far_less_jitter() -> None:
    rng = np.random.default_rng(0)
    truth = np.array([[100.0, 50.0], [160.0, 60.0], [150.0, 110.0], [90.0, 100.0]])
    noisy = truth[None] + rng.normal(0, 2.0, (300, 4, 2))
    smoothed = _run(KeypointSmoother(4), noisy)
    assert jitter(smoothed) < 0.4 * jitter(noisy)  # measured: 0.28 (defaults, 15 fps)
    assert np.abs(smoothed[50:].mean(axis=0) - truth).max() < 0.5  # no drift, x/y not swapped


def test_a_moving_pool_is_followed_within_a_frame_and_beta_is_what_does_it() -> None:
    speed = 6.0  # px per frame, a fast torch at 15 fps
    path = np.stack([np.arange(120) * speed, np.full(120, 40.0)], axis=1)[:, None, :]
    followed = _run(KeypointSmoother(1), path)
    trail = (path[60:, 0, 0] - followed[60:, 0, 0]).mean() / speed
    assert 0 <= trail <= 1.0  # frames behind at steady speed (measured 0.34)
    stiff = _run(KeypointSmoother(1, SmoothingParams(beta=0.0)), path)
    assert (path[60:, 0, 0] - stiff[60:, 0, 0]).mean() / speed > 2.0  # no speed term: lags


def test_keypoints_keep_their_tracks_when_their_order_changes() -> None:
    smoother = KeypointSmoother(2)
    a, b = [10.0, 10.0], [90.0, 10.0]
    smoother.update(np.array([a, b]), 0.0)
    swapped = smoother.update(np.array([b, a]), 1 / FPS)  # the order rule renumbered them
    assert swapped[0] == pytest.approx(a) and swapped[1] == pytest.approx(b)


def test_a_jump_restarts_a_track_and_a_missing_keypoint_is_held_then_dropped() -> None:
    params = SmoothingParams(gate=50.0, hold=2)
    smoother = KeypointSmoother(2, params)
    smoother.update(np.array([[10.0, 10.0], [90.0, 10.0]]), 0.0)
    jumped = smoother.update(np.array([[10.0, 10.0], [300.0, 200.0]]), 0.1)
    assert jumped[1] == pytest.approx([300.0, 200.0])  # not smoothed across the jump
    held = [smoother.update(np.array([[10.0, 10.0]]), 0.2 + 0.1 * i)[1] for i in range(3)]
    assert held[0] == held[1] == pytest.approx([300.0, 200.0]) and held[2] is None


def test_jitter_and_lag_measure_what_they_say() -> None:
    zigzag = np.array([[[0.0, 0.0]], [[1.0, 0.0]]] * 10)
    assert jitter(zigzag) == pytest.approx(2.0)  # |1 − 2·0 + 1|
    one_jump = np.concatenate([np.zeros((10, 1, 2)), np.full((10, 1, 2), 90.0)])
    assert jitter(one_jump, "median") == 0.0 and jitter(one_jump) > 10  # the mean sees jumps
    line = np.stack([np.arange(20.0), np.zeros(20)], axis=1)[:, None, :]
    assert jitter(line) == 0.0
    raw = np.random.default_rng(1).normal(0, 5, (60, 1, 2)).cumsum(axis=0)
    delayed = np.concatenate([np.repeat(raw[:1], 3, axis=0), raw[:-3]])
    assert lag_frames(raw, delayed) == 3 and lag_frames(raw, raw) == 0
    with pytest.raises(InvalidInputError):
        jitter(zigzag[:2])
    with pytest.raises(InvalidInputError):
        SmoothingParams(min_cutoff=0)
