"""The one image reader: formats, bit depths, channels, refusals, the 16-bit mapping."""

from __future__ import annotations

import io

import numpy as np
import pytest
from PIL import Image

from tests.helpers import SHARED_DATA, image_bytes
from weldpool_core.errors import InvalidInputError
from weldpool_core.io import (
    check_image,
    decode_mask_png,
    encode_mask_png,
    encode_png,
    read_image,
    stretch_to_uint8,
    to_rgb8,
)


@pytest.mark.parametrize(
    ("fmt", "channels", "bit_depth", "media_type"),
    [
        (".png", 1, 8, "image/png"),
        (".png", 1, 16, "image/png"),
        (".png", 3, 16, "image/png"),
        (".png", 4, 8, "image/png"),
        (".jpg", 3, 8, "image/jpeg"),
        (".jpg", 1, 8, "image/jpeg"),
        (".tif", 1, 16, "image/tiff"),
        (".tif", 3, 8, "image/tiff"),
        (".bmp", 3, 8, "image/bmp"),
    ],
)
def test_reads_every_supported_kind(fmt, channels, bit_depth, media_type) -> None:
    data = image_bytes(40, 30, channels=channels, bit_depth=bit_depth, fmt=fmt)
    image = read_image(data)
    assert image.info.media_type == media_type
    assert (image.info.width, image.info.height) == (40, 30)
    assert image.info.channels == channels and image.info.bit_depth == bit_depth
    rgb = to_rgb8(image)
    assert rgb.shape == (30, 40, 3) and rgb.dtype == np.uint8
    assert check_image(data) == image.info  # what ingest records without keeping pixels


def test_rgb_order_is_kept() -> None:
    pixels = np.zeros((4, 4, 3), np.uint8)
    pixels[:, :, 0] = 200  # red
    image = read_image(encode_png(pixels))
    assert image.pixels[0, 0].tolist() == [200, 0, 0]
    assert to_rgb8(image)[0, 0].tolist() == [200, 0, 0]


def test_sixteen_bit_stretch_keeps_a_small_bright_pool_visible() -> None:
    frame = np.full((200, 200), 1000, np.uint16)
    frame += np.random.default_rng(1).integers(0, 50, frame.shape).astype(np.uint16)
    yy, xx = np.mgrid[:200, :200]
    pool = (yy - 100) ** 2 + (xx - 100) ** 2 < 12**2  # 0.4 % of the frame
    frame[pool] = 20000 + (10000 * (1 - ((yy - 100) ** 2 + (xx - 100) ** 2) / 144))[pool]
    frame[0, 0] = 65535  # one hot pixel must not set the white point
    out = stretch_to_uint8(frame)
    assert out[~pool].mean() < 10  # background stays dark
    assert out[100, 100] > 200  # pool centre bright…
    assert out[pool].std() > 10  # …and not clipped flat: its gradient survives
    assert stretch_to_uint8(np.full((8, 8), 7, np.uint16)).max() == 0


def test_real_sixteen_bit_lpbf_frame() -> None:
    frames = sorted((SHARED_DATA / "lpbf").glob("normal_*.png"))
    if not frames:
        pytest.skip("../shared/data/lpbf is absent (a fresh checkout has no ../shared)")
    image = read_image(frames[0])
    assert image.info.bit_depth == 16 and image.info.channels == 1
    rgb = to_rgb8(image)
    hottest = np.unravel_index(np.argmax(image.pixels), image.pixels.shape)
    assert rgb[hottest].min() > 200 and np.median(rgb) < 60


@pytest.mark.parametrize(
    ("data", "reason"),
    [
        (b"", "The file is empty."),
        (b"hello, this is text", "not a readable image"),
        (b'<?xml version="1.0"?><svg xmlns="http://www.w3.org/2000/svg"/>', "SVG images"),
        (b"<!DOCTYPE html><html><body>x</body></html>", "HTML files are not images"),
        (image_bytes(fmt=".png")[:300], "truncated"),
        (image_bytes(fmt=".jpg", channels=3)[:500], "truncated"),
    ],
)
def test_refusals_are_one_sentence(data: bytes, reason: str) -> None:
    with pytest.raises(InvalidInputError) as caught:
        read_image(data)
    assert reason in caught.value.message
    assert caught.value.message.endswith(".")


def test_other_formats_are_refused_by_content_not_name() -> None:
    buffer = io.BytesIO()
    Image.new("RGB", (8, 8)).save(buffer, "GIF")
    with pytest.raises(InvalidInputError, match="GIF files are not supported"):
        read_image(buffer.getvalue())


def test_decompression_bomb_is_refused_before_decoding() -> None:
    buffer = io.BytesIO()
    Image.new("1", (20000, 20000)).save(buffer, "PNG")  # 400 MP in a few kB
    assert len(buffer.getvalue()) < 200_000
    with pytest.raises(InvalidInputError, match="more than the limit"):
        read_image(buffer.getvalue())
    with pytest.raises(InvalidInputError, match="WELDPOOL_MAX_IMAGE_PIXELS"):
        read_image(image_bytes(100, 100), max_pixels=5000)


def test_mask_codec_round_trip() -> None:
    mask = np.zeros((20, 30), bool)
    mask[5:15, 10:25] = True
    data = encode_mask_png(mask)
    image = read_image(data)
    assert image.info.channels == 1 and image.info.bit_depth == 8
    assert set(np.unique(image.pixels)) == {0, 255}
    assert np.array_equal(decode_mask_png(data), mask)
    assert np.array_equal(decode_mask_png(encode_png(mask.astype(np.uint8))), mask)  # 0/1
    with pytest.raises(InvalidInputError, match="must be a PNG"):
        decode_mask_png(image_bytes(fmt=".bmp"))


def test_a_mask_of_any_dtype_and_layout_encodes_to_its_foreground() -> None:
    from weldpool_core.io import decode_mask_png, encode_mask_png

    mask = np.random.default_rng(0).random((40, 50)) > 0.5
    for variant in (mask, mask.astype(np.uint8), mask * 0.7, mask[:, ::2], np.asfortranarray(mask)):
        assert np.array_equal(decode_mask_png(encode_mask_png(variant)), np.asarray(variant) > 0)


@pytest.mark.parametrize("shape", [(1, 1), (800, 1280), (3, 1281), (257, 2)])
def test_a_mask_png_reads_the_same_in_every_reader(shape: tuple[int, int]) -> None:
    """The mask PNG is framed by us (ISA-L's deflate): OpenCV, Pillow, zlib and the ingest's
    verifier all read it as the 8-bit gray 0/255 image of the mask."""
    import cv2

    mask = np.random.default_rng(shape[1]).random(shape) > 0.4
    data = encode_mask_png(mask)
    expected = mask.astype(np.uint8) * 255
    assert np.array_equal(
        cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED), expected
    )
    with Image.open(io.BytesIO(data)) as image:
        assert image.mode == "L" and np.array_equal(np.asarray(image), expected)
    info = check_image(data)  # a plain PNG: every CRC, the whole stream inflated and checked
    assert (info.width, info.height, info.channels, info.bit_depth) == (shape[1], shape[0], 1, 8)
    assert np.array_equal(read_image(data).pixels, expected)
    with pytest.raises(InvalidInputError, match="no pixels"):
        encode_mask_png(np.zeros((0, 4), bool))


def test_a_mask_for_a_frame_is_refused_on_its_header_before_any_pixel_is_decoded(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A mask sent for a frame of a given size costs no more than that frame: one of another
    size (a 40,000² PNG of zeros is a few hundred bytes) is refused from its header."""
    import weldpool_core.io as io_module
    from weldpool_core.io import decode_mask_png, encode_mask_png

    mask = np.zeros((6, 8), bool)
    mask[2:4, 3:6] = True
    data = encode_mask_png(mask)
    assert np.array_equal(decode_mask_png(data, shape=(6, 8)), mask)

    def no_decoding(*_args: object, **_kwargs: object) -> None:
        raise AssertionError("the mask was decoded")

    monkeypatch.setattr(io_module, "read_image", no_decoding)
    with pytest.raises(InvalidInputError, match=r"^The mask is 8×6; the frame is 8×7\.$"):
        decode_mask_png(data, shape=(7, 8))
