"""A CVAT mask built from the stored COCO RLE over its box is the one built from the whole
decoded frame: same runs, same box, holes and regions touching the frame's edges kept."""

from __future__ import annotations

import numpy as np

from weldpool_core.annotations.cvat import cvat_box_mask, cvat_mask
from weldpool_core.annotations.shapes import cvat_rle
from weldpool_core.outline import coco_mask, rle_boxed, rle_counts, rle_mask


def _masks() -> list[np.ndarray]:
    ring = np.zeros((60, 80), bool)
    ring[10:40, 20:70] = True
    ring[20:30, 30:50] = False  # a hole
    edges = np.zeros((60, 80), bool)
    edges[0:5, 0:10] = True  # touches the top-left corner
    edges[50:60, 75:80] = True  # and the bottom-right one
    rng = np.random.default_rng(3)
    speckled = rng.random((60, 80)) > 0.7
    return [ring, edges, speckled]


def test_the_rle_over_a_box_is_the_decoded_mask_cropped_to_the_box() -> None:
    for mask in _masks():
        coco = coco_mask(mask)
        x, y, w, h = coco.bbox
        boxed = rle_boxed(coco.rle, coco.bbox)
        box = boxed.pixels
        assert boxed.origin == (x, y) and boxed.size == mask.shape
        assert box.dtype == np.bool_ and box.flags.c_contiguous
        assert np.array_equal(box, rle_mask(coco.rle)[y : y + h, x : x + w])
        assert box[0].any() and box[-1].any() and box[:, 0].any() and box[:, -1].any()  # tight
        for inner in ([x + 1, y + 2, w - 3, h - 2], [x + w // 2, y, w - w // 2, h // 2]):
            left, top, width, height = inner  # a box cutting the mask: the pixels inside it
            cut = rle_boxed(coco.rle, inner).pixels
            assert np.array_equal(cut, mask[top : top + height, left : left + width])


def test_the_cvat_mask_from_the_stored_box_is_the_one_from_the_whole_frame() -> None:
    for mask in _masks():
        coco = coco_mask(mask)
        whole = cvat_mask(mask)
        from_box = cvat_box_mask(rle_boxed(coco.rle, coco.bbox).pixels, coco.bbox[0], coco.bbox[1])
        assert whole == from_box
        assert whole is not None
        # and CVAT's reader gives the mask back, holes kept
        runs = [int(v) for v in whole.rle.split(", ")]
        back = np.zeros_like(mask)
        back[whole.top : whole.top + whole.height, whole.left : whole.left + whole.width] = (
            cvat_rle(runs, whole.width, whole.height)
        )
        assert np.array_equal(back, mask)
    assert cvat_mask(np.zeros((4, 4), bool)) is None


def test_the_runs_read_from_the_compressed_string_are_pycocotools_own() -> None:
    """``rle_counts`` reads COCO's string as pycocotools writes it: counts of several 5-bit
    groups, differences to the run two before (negative ones too), on a frame of 12 million
    pixels; the box laid out from them is the decoded frame's."""
    mask = np.zeros((3000, 4000), bool)
    mask[5:2990, 7:3990] = True
    mask[100:200, 100:3000] = False  # long runs, then short ones: differences of both signs
    mask[2500:2502, 3000:3002] = False
    rng = np.random.default_rng(8)
    mask[1000:1100, 1000:1100] = rng.random((100, 100)) > 0.5
    coco = coco_mask(mask)
    runs = rle_counts(coco.rle["counts"])
    assert int(runs.sum()) == mask.size and (runs[1:] > 0).all()
    flat = np.repeat(np.arange(runs.size) % 2 == 1, runs)
    assert np.array_equal(flat.reshape(4000, 3000).T, mask)  # column-major, 0s first
    x, y, w, h = coco.bbox
    assert np.array_equal(rle_boxed(coco.rle, coco.bbox).pixels, mask[y : y + h, x : x + w])
