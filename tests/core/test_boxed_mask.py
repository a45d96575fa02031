"""A label's mask by its box (``outline.BoxedMask``): decoded from a COCO RLE's runs without a
frame-sized array, and worked on (outline, Algorithm 1, mask PNG) with the whole frame's
results, bit for bit."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from pycocotools import mask as coco

from tests.core.shapes import pool_blob
from weldpool_core.annotations.content import label_content
from weldpool_core.annotations.shapes import CocoRle, ImportedLabel
from weldpool_core.heatmap import heatmap_from_mask, keypoints_from_mask, mask_keypoints
from weldpool_core.io import encode_mask_png
from weldpool_core.outline import (
    BoxedMask,
    coco_mask,
    mask_record,
    region_outlines,
    rle_boxed,
    rle_counts,
    rle_mask,
)


def _masks() -> list[np.ndarray]:
    """Pools, specks, holes, regions on every border and corner, a full frame, one pixel."""
    rng = np.random.default_rng(7)
    masks = [pool_blob(seed) for seed in range(4)]
    for index in range(12):
        height, width = int(rng.integers(8, 160)), int(rng.integers(8, 160))
        noise = cv2.resize(rng.random((height // 4 + 1, width // 4 + 1)), (width, height))
        mask = noise > rng.uniform(0.4, 0.8)
        mask[0, :] |= index % 2 == 0
        mask[:, -1] |= index % 3 == 0
        mask[-2:, :3] |= index % 4 == 0
        masks.append(mask)
    corner = np.zeros((30, 40), bool)
    corner[-1, -1] = True
    masks += [corner, np.ones((20, 30), bool)]
    return [m for m in masks if m.any()]


def _pycocotools_runs(mask: np.ndarray) -> list[int]:
    flat = np.asfortranarray(mask).ravel(order="F").astype(np.int8)
    edges = np.flatnonzero(np.diff(flat)) + 1
    runs = np.diff(np.concatenate(([0], edges, [flat.size]))).tolist()
    return [0, *runs] if flat[0] else runs


@pytest.mark.parametrize("index", range(len(_masks())))
def test_the_runs_and_the_box_of_an_rle_are_its_mask(index: int) -> None:
    mask = _masks()[index]
    rle = coco_mask(mask).rle
    assert rle_counts(rle["counts"]).tolist() == _pycocotools_runs(mask)
    boxed = rle_boxed(rle)
    assert np.array_equal(boxed.frame_mask(), rle_mask(rle))
    x, y, w, h = cv2.boundingRect(mask.view(np.uint8))
    assert boxed.origin == (x, y) and boxed.pixels.shape == (h, w) and boxed.size == mask.shape


@pytest.mark.parametrize("index", range(len(_masks())))
def test_a_mask_worked_on_by_its_box_gives_the_whole_frames_results(index: int) -> None:
    mask = _masks()[index]
    rle = coco_mask(mask).rle
    boxed = rle_boxed(rle)
    assert encode_mask_png(boxed.pixels, boxed.size, boxed.origin) == encode_mask_png(mask)
    assert region_outlines(boxed.pixels, boxed.origin) == region_outlines(mask)
    assert mask_record(boxed, rle) == mask_record(mask, rle)
    assert mask_record(boxed) == mask_record(mask)
    try:
        expected = mask_keypoints(mask)
    except Exception as exc:  # too small or thin for Algorithm 1: the same refusal
        with pytest.raises(type(exc), match="Keypoints cannot be computed"):
            mask_keypoints(boxed.pixels, boxed.origin)
        return
    assert mask_keypoints(boxed.pixels, boxed.origin) == expected
    assert np.array_equal(keypoints_from_mask(mask), heatmap_from_mask(mask).keypoints)


def test_a_label_of_many_runs_is_its_mask() -> None:
    """A run per pixel (stripes across the columns): the box laid out is the mask."""
    stripes = np.zeros((40, 50), bool)
    stripes[::2, 5:45] = True
    rle = coco_mask(stripes).rle
    assert rle_counts(rle["counts"]).size > 800
    assert np.array_equal(rle_boxed(rle).frame_mask(), stripes)
    assert BoxedMask.of(stripes).origin == (5, 0)


@pytest.mark.parametrize(
    ("counts", "why"),
    [
        ("0", "cover 0 pixels"),  # pycocotools' decode fills the rest with whatever memory held
        ("0P3", "cover"),
        ("0a", "end inside a number"),
        ("0 1", "outside the RLE code"),
        ("0ooooooooo0", "longer than an image"),
        ("06O", "negative run"),
    ],
)
def test_counts_that_are_no_rle_of_the_size_are_refused(counts: str, why: str) -> None:
    with pytest.raises(ValueError, match=why):
        rle_boxed({"size": [4, 4], "counts": counts})
    label = ImportedLabel(
        item="a.json", image="a.png", shapes=[CocoRle({"size": [4, 4], "counts": counts})]
    )
    content = label_content(label, (4, 4), True)
    assert content.problem is not None and content.problem.startswith(
        "The RLE mask cannot be decoded"
    )
    assert content.mask_png is None


def test_the_counts_decode_as_pycocotools_reads_them() -> None:
    """Negative differences (a run shorter than the one two before) and long runs."""
    mask = np.zeros((600, 700), bool)
    mask[100:500, 200:650] = True
    mask[300, 10] = True
    rle = coco_mask(mask).rle
    encoded = {"size": rle["size"], "counts": rle["counts"].encode("ascii")}
    assert int(rle_counts(rle["counts"]).sum()) == 600 * 700
    assert np.array_equal(rle_boxed(rle).frame_mask(), coco.decode(encoded).astype(bool))
