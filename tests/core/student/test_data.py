"""Frame geometry both ways, training targets, augmentation that keeps keypoints consistent,
and the DATASET folder."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from tests.core.student.common import TINY_FRAME, synthetic_frames
from weldpool_core.errors import InvalidInputError
from weldpool_core.heatmap import HeatmapParams, heatmap_from_mask
from weldpool_core.io import encode_mask_png
from weldpool_core.keypoints import keypoints_from_heatmap
from weldpool_core.student.data import (
    Augmentation,
    FrameGeometry,
    FrameSet,
    TrainingFrame,
    make_targets,
    photometric,
    prepare_frame,
    random_affine,
    read_dataset,
    shrink,
)
from weldpool_core.synth import synth_frame


@pytest.mark.parametrize("aspect", ["letterbox", "resize"])
@pytest.mark.parametrize(("height", "width"), [(800, 1280), (160, 256), (300, 100), (64, 64)])
def test_points_map_to_the_input_and_back(aspect: str, height: int, width: int) -> None:
    geometry = FrameGeometry.fit(height, width, 256, aspect)  # type: ignore[arg-type]
    points = np.array([[0.0, 0.0], [width - 1.0, height - 1.0], [width / 3, height / 2]])
    assert np.allclose(geometry.to_frame(geometry.to_input(points)), points)
    corners = geometry.to_input(np.array([[-0.5, -0.5], [width - 0.5, height - 0.5]]))
    assert np.allclose(corners[0], [geometry.offset_x - 0.5, geometry.offset_y - 0.5])
    assert np.allclose(
        corners[1],
        [
            geometry.offset_x + geometry.inner_width - 0.5,
            geometry.offset_y + geometry.inner_height - 0.5,
        ],
    )
    if aspect == "letterbox":
        assert geometry.scale_x == pytest.approx(geometry.scale_y, rel=0.02)
        assert max(geometry.inner_width, geometry.inner_height) == 256
    else:
        assert geometry.inner_width == geometry.inner_height == 256


@pytest.mark.parametrize("channels", [0, 1, 3, 4])
def test_shrink_gives_opencvs_area_pixels_for_every_whole_factor(channels: int) -> None:
    # The box filter's way (odd factors up to 5) and OpenCV's own (the rest) must give
    # INTER_AREA's pixels exactly: a student sees the same input whichever way it was made.
    rng = np.random.default_rng(channels)
    for fx in range(1, 8):
        for fy in range(1, 8):
            width, height = int(rng.integers(3, 40)), int(rng.integers(3, 40))
            shape = (height * fy, width * fx) + ((channels,) if channels else ())
            noise = rng.integers(0, 256, shape, dtype=np.uint8)
            binary = np.where(rng.random(shape) < 0.5, 0, 255).astype(np.uint8)
            for image in (noise, binary):
                expected = cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA)
                got = shrink(image, width, height)
                assert got.shape == expected.shape, (fx, fy)
                assert np.array_equal(got, expected), (fx, fy)
    frame = rng.integers(0, 65536, (800, 1280), dtype=np.uint16)  # 16-bit: OpenCV's way
    expected = cv2.resize(frame, (256, 160), interpolation=cv2.INTER_AREA)
    assert np.array_equal(shrink(frame, 256, 160), expected)


@pytest.mark.parametrize(
    "factors", [(3, 1), (1, 3), (3, 3), (5, 1), (1, 5), (3, 5), (5, 3), (5, 5)]
)
def test_shrink_rounds_every_possible_block_sum_as_opencv_does(factors: tuple[int, int]) -> None:
    # One block per possible sum (0 … 255·area, saturated pool pixels included): the box
    # filter's fixed-point division must round each exactly as INTER_AREA does.
    fx, fy = factors
    area = fx * fy
    sums = np.arange(255 * area + 1)
    columns = 64
    rows = -(-len(sums) // columns)
    sums = np.concatenate([sums, np.zeros(rows * columns - len(sums), int)])
    ranks = np.arange(area).reshape(fy, fx)  # a block's pixels share its sum as evenly as can be
    blocks = sums[:, None, None] // area + (ranks[None] < (sums % area)[:, None, None])
    image = (
        blocks.reshape(rows, columns, fy, fx).transpose(0, 2, 1, 3).reshape(rows * fy, -1)
    ).astype(np.uint8)
    assert np.array_equal(image.reshape(rows, fy, columns, fx).sum((1, 3)).ravel(), sums)
    expected = cv2.resize(image, (columns, rows), interpolation=cv2.INTER_AREA)
    assert np.array_equal(shrink(image, columns, rows), expected)


def test_a_real_frame_goes_to_the_input_by_the_box_filter_unchanged(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    frame = cv2.GaussianBlur(
        np.random.default_rng(3).integers(0, 256, (800, 1280, 3), dtype=np.uint8), (0, 0), 3
    )
    expected = cv2.resize(frame, (256, 160), interpolation=cv2.INTER_AREA)

    def no_resize(*_args: object, **_kwargs: object) -> None:
        raise AssertionError("a 1280×800 frame takes the box filter's way")

    monkeypatch.setattr(cv2, "resize", no_resize)
    geometry = FrameGeometry.fit(800, 1280, 256)
    placed = geometry.image_to_input(frame)
    assert np.array_equal(placed[geometry.inner_rows, geometry.inner_columns], expected)
    assert not placed[: geometry.offset_y].any() and not placed[geometry.offset_y + 160 :].any()


@pytest.mark.parametrize("aspect", ["letterbox", "resize"])
def test_a_spot_in_the_frame_lands_where_the_geometry_says(aspect: str) -> None:
    frame = np.zeros((800, 1280), np.float32)
    cv2.circle(frame, (900, 250), 40, 1.0, -1)
    geometry = FrameGeometry.fit(800, 1280, 256, aspect)  # type: ignore[arg-type]
    scaled = geometry.image_to_input(frame)
    moments = cv2.moments(scaled)
    centre = (moments["m10"] / moments["m00"], moments["m01"] / moments["m00"])
    assert np.allclose(centre, geometry.to_input(np.array([[900.0, 250.0]]))[0], atol=0.3)
    back = geometry.map_to_frame(scaled)
    assert back.shape == (800, 1280)
    assert abs(float(back.sum()) - float(frame.sum())) / float(frame.sum()) < 0.02
    if aspect == "letterbox":
        assert not scaled[: geometry.offset_y].any()  # the pad stays black


def test_targets_come_from_algorithm_1_or_from_given_keypoints() -> None:
    frame = synthetic_frames(1)[0]
    params = HeatmapParams()
    derived = prepare_frame(frame, 64, "letterbox", params)
    truth = heatmap_from_mask(frame.mask, params)
    assert np.allclose(derived.frame_keypoints, truth.keypoints)
    assert np.allclose(derived.geometry.to_frame(derived.keypoints), truth.keypoints)
    assert np.array_equal(derived.truth_mask(), frame.mask)
    given = np.array([[10.0, 20.0], [50.0, 30.0]])
    labelled = prepare_frame(TrainingFrame(frame.image, frame.mask, given), 64, "letterbox", params)
    assert np.allclose(labelled.frame_keypoints, given) and len(labelled.keypoints) == 2


def test_an_empty_mask_trains_with_an_empty_heatmap() -> None:
    image = np.zeros((40, 60, 3), np.uint8)
    prepared = prepare_frame(
        TrainingFrame(image, np.zeros((40, 60), bool)), 64, "letterbox", HeatmapParams()
    )
    targets = make_targets(prepared, 3.0)
    assert prepared.keypoints.shape == (0, 2)
    assert float(targets.heatmap.max()) == 0.0 and float(targets.mask.max()) == 0.0


def test_the_heatmap_peaks_at_the_keypoints_on_the_pool() -> None:
    prepared = prepare_frame(synthetic_frames(1)[0], 96, "letterbox", HeatmapParams())
    targets = make_targets(prepared, 2.0)
    heat = targets.heatmap.numpy()
    assert heat.max() <= 1.0 and heat.min() >= 0.0
    modes = keypoints_from_heatmap(heat, k=4)
    distances = np.linalg.norm(modes[:, None] - prepared.keypoints[None], axis=2).min(axis=1)
    assert distances.max() < 2.0
    near_pool = cv2.dilate((targets.mask.numpy() > 0).astype(np.uint8), np.ones((3, 3)))
    assert near_pool[heat > 0.5].all()  # min(1, 2S) lets a peak reach one pixel past the outline


def test_augmentation_moves_image_mask_and_keypoints_together() -> None:
    prepared = prepare_frame(synthetic_frames(1)[0], 96, "letterbox", HeatmapParams())
    geometric = Augmentation(
        gamma=0, gain=0, offset=0, glare_probability=0, noise_sigma=0, blur_probability=0
    )
    rng = np.random.default_rng(5)
    targets = make_targets(prepared, 2.0, geometric, rng)
    matrix = random_affine(np.random.default_rng(5), 96, geometric)
    moved = prepared.keypoints @ matrix[:, :2].T + matrix[:, 2]
    modes = keypoints_from_heatmap(targets.heatmap.numpy(), k=4)
    distances = np.linalg.norm(modes[:, None] - moved[None], axis=2).min(axis=1)
    assert distances.max() < 2.0
    warped = cv2.warpAffine(prepared.image.astype(np.float32), matrix, (96, 96)) / 255
    assert np.allclose(targets.image.numpy().transpose(1, 2, 0), warped, atol=1e-5)
    assert not np.allclose(targets.mask.numpy(), prepared.mask / 255.0)


def test_gamma_bends_mid_greys_both_ways_and_keeps_black_and_white() -> None:
    only_gamma = Augmentation(
        gain=0, offset=0, glare_probability=0, noise_sigma=0, blur_probability=0
    )
    image = np.zeros((8, 8, 3), np.float32)
    image[:, 2:4], image[:, 4:] = 128.0, 255.0
    draws = [
        photometric(image.copy(), np.random.default_rng(seed), only_gamma) for seed in range(20)
    ]
    middle = np.array([d[0, 2, 0] for d in draws])
    assert (middle > 140).any() and (middle < 116).any()  # brighter and darker exposures
    assert all(np.allclose(d[:, :2], 0) and np.allclose(d[:, 4:], 255, atol=1e-3) for d in draws)
    assert np.abs(np.log(middle / 255) / np.log(128 / 255)).max() <= 1.5 + 1e-4  # within 1 + γ
    off = replace(only_gamma, gamma=0.0)
    assert np.allclose(photometric(image.copy(), np.random.default_rng(0), off), image)


def test_augmentation_depends_only_on_seed_epoch_and_index() -> None:
    prepared = [prepare_frame(f, 64, "letterbox", HeatmapParams()) for f in synthetic_frames(2)]
    first = FrameSet(prepared, 3.0, Augmentation(), seed=1, epoch=3)
    second = FrameSet(prepared, 3.0, Augmentation(), seed=1, epoch=3)
    assert np.array_equal(first[1].image.numpy(), second[1].image.numpy())
    second.epoch = 4
    assert not np.array_equal(first[1].image.numpy(), second[1].image.numpy())


def _write_dataset(root: Path, count: int = 3) -> None:
    (root / "images").mkdir(parents=True)
    (root / "masks").mkdir()
    (root / "keypoints").mkdir()
    for seed in range(count):
        frame = synth_frame(seed, TINY_FRAME)
        cv2.imwrite(str(root / "images" / f"f{seed}.png"), frame.image)
        (root / "masks" / f"f{seed}.png").write_bytes(encode_mask_png(frame.mask))
    (root / "keypoints" / "f1.json").write_text(json.dumps({"keypoints": [[5, 6], [7, 8]]}))
    cv2.imwrite(str(root / "images" / "unlabelled.png"), np.zeros((8, 8), np.uint8))


def test_a_dataset_folder_reads_frames_masks_and_keypoints(tmp_path: Path) -> None:
    _write_dataset(tmp_path / "data")
    frames = list(read_dataset(tmp_path / "data"))
    assert [f.name for f in frames] == ["f0", "f1", "f2"]
    assert frames[0].image.shape == (64, 96, 3) and frames[0].image.dtype == np.uint8
    assert frames[0].keypoints is None
    assert frames[1].keypoints is not None and frames[1].keypoints.tolist() == [[5, 6], [7, 8]]


def test_bad_dataset_folders_are_one_sentence(tmp_path: Path) -> None:
    with pytest.raises(InvalidInputError, match="not a DATASET folder"):
        list(read_dataset(tmp_path))
    _write_dataset(tmp_path / "data")
    (tmp_path / "data" / "masks" / "f2.png").write_bytes(
        encode_mask_png(np.ones((10, 10), np.uint8))
    )
    with pytest.raises(InvalidInputError, match=r"f2: .*mask is 10×10"):
        list(read_dataset(tmp_path / "data"))
    (tmp_path / "data" / "keypoints" / "f1.json").write_text("[1, 2]")
    with pytest.raises(InvalidInputError, match="not a keypoints file"):
        list(read_dataset(tmp_path / "data"))
    cv2.imwrite(str(tmp_path / "data" / "images" / "f0.jpg"), np.zeros((8, 8), np.uint8))
    with pytest.raises(InvalidInputError, match="several images named 'f0'"):
        list(read_dataset(tmp_path / "data"))
