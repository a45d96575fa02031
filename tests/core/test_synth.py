"""Synthetic WAAM frames: seeded, self-consistent ground truth, smooth sequences."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from tests.helpers import SHARED_DATA
from weldpool_core.errors import InvalidInputError
from weldpool_core.heatmap import HeatmapParams, heatmap_from_mask
from weldpool_core.io import encode_png, read_image
from weldpool_core.metrics import iou
from weldpool_core.synth import SynthParams, synth_frame, synth_sequence

SMALL = SynthParams(width=320, height=200)
REAL_FRAMES = SHARED_DATA / "waam" / "frames"


def _bands(image: np.ndarray) -> tuple[float, float]:
    """Mean grey of the top fifth (background) and of the middle band (plate and pool)."""
    height = image.shape[0]
    middle = image[int(0.35 * height) : int(0.85 * height)]
    return float(image[: height // 5].mean()), float(middle.mean())


@pytest.mark.parametrize("seed", range(12))
def test_ground_truth_is_algorithm_1_on_the_generated_mask(seed: int) -> None:
    frame = synth_frame(seed, SMALL, time_s=0.1 * seed)
    truth = heatmap_from_mask(frame.mask, SMALL.heatmap)
    assert np.array_equal(frame.keypoints, truth.keypoints)
    assert np.array_equal(frame.heatmap, truth.heatmap)
    assert frame.image.shape == frame.mask.shape == (200, 320) and frame.image.dtype == np.uint8
    rows, cols = np.nonzero(frame.mask)
    assert rows.min() > 0 and rows.max() < 199 and cols.min() > 0 and cols.max() < 319


def test_the_ground_truth_follows_the_heatmap_parameters() -> None:
    params = SynthParams(width=320, height=200, heatmap=HeatmapParams(k=6))
    frame = synth_frame(3, params)
    assert frame.keypoints.shape == (6, 2)
    assert np.array_equal(frame.keypoints, heatmap_from_mask(frame.mask, params.heatmap).keypoints)


def test_same_seed_same_frame_and_different_seeds_differ() -> None:
    first, again, other = synth_frame(5, SMALL), synth_frame(5, SMALL), synth_frame(6, SMALL)
    assert np.array_equal(first.image, again.image) and np.array_equal(first.mask, again.mask)
    assert not np.array_equal(first.mask, other.mask)


def test_frame_looks_like_a_waam_frame() -> None:
    frame = synth_frame(2, SMALL)
    image, mask = frame.image.astype(np.float64), frame.mask
    top, middle = _bands(image)
    assert top < 40 < middle  # dark background above the lit plate
    electrode = image[:20, 150:260].max()
    assert electrode > 200  # the bright electrode comes down from the top
    assert image[40:110, 310:].max() > 150  # the wire enters from the right
    ring = np.logical_xor(np.pad(mask, 3)[:-6, 3:-3] | np.pad(mask, 3)[6:, 3:-3], mask)
    bead = image[80:140, :40].mean()
    pool_dark = np.percentile(image[mask], 25)
    assert pool_dark < bead and pool_dark < image[ring & ~mask].mean()  # dark pool, brighter edge


def test_sixteen_bit_frames() -> None:
    frame = synth_frame(1, SynthParams(width=320, height=200, bit_depth=16))
    assert frame.image.dtype == np.uint16 and frame.image.max() > 255
    decoded = read_image(encode_png(frame.image))
    assert decoded.info.bit_depth == 16
    eight = synth_frame(1, SMALL)
    assert np.array_equal(frame.mask, eight.mask)


def test_sequences_deform_smoothly() -> None:
    frames = synth_sequence(4, 6, SMALL)
    assert [f.time_s for f in frames] == pytest.approx([i / 15 for i in range(6)])
    for before, after in itertools.pairwise(frames):
        assert 0.93 < iou(before.mask, after.mask) < 1.0  # it moves, a little
    assert np.array_equal(frames[2].mask, synth_frame(4, SMALL, time_s=2 / 15).mask)


def test_bad_parameters_are_clear_errors() -> None:
    with pytest.raises(InvalidInputError):
        SynthParams(width=10)
    with pytest.raises(InvalidInputError):
        SynthParams(bit_depth=12)  # type: ignore[arg-type]
    with pytest.raises(InvalidInputError):
        synth_sequence(0, 0, SMALL)


@pytest.mark.skipif(not REAL_FRAMES.is_dir(), reason=f"real WAAM frames not found in {REAL_FRAMES}")
def test_brightness_bands_match_the_real_camera() -> None:
    real = [read_image(path).pixels for path in sorted(REAL_FRAMES.glob("*.png"))[::10]]
    synthetic = synth_frame(0).image
    assert synthetic.shape == real[0].shape[:2]
    real_top, real_middle = np.mean([_bands(image) for image in real], axis=0)
    top, middle = _bands(synthetic)
    assert abs(top - real_top) < 15 and 0.7 < middle / real_middle < 1.4
