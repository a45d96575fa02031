"""The one image reader: formats, bit depths, channels, refusals, the 16-bit mapping."""

from __future__ import annotations

import io
import struct
import zlib

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


# --- check_image: every frame checked at ingest without keeping its pixels ---------------------


def _chunk(kind: bytes, body: bytes) -> bytes:
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))


def _png(
    width: int, height: int, stream: bytes, colour: int = 0, depth: int = 8, extra=()
) -> bytes:
    """A PNG from its raw parts: header, any extra chunks, one IDAT of ``stream``, IEND."""
    header = struct.pack(">IIBBBBB", width, height, depth, colour, 0, 0, 0)
    chunks = [_chunk(b"IHDR", header), *extra, _chunk(b"IDAT", stream), _chunk(b"IEND", b"")]
    return b"\x89PNG\r\n\x1a\n" + b"".join(chunks)


def _rows(pixels: np.ndarray, filter_type: int = 0) -> bytes:
    """Scanlines with a filter byte in front of each (type 0: the bytes as they are)."""
    rows = pixels.reshape(pixels.shape[0], -1)
    return b"".join(bytes([filter_type]) + row.tobytes() for row in rows)


def _kinds_of_png() -> list[bytes]:
    """PNGs of every layout: the plain ones check_image verifies and those it decodes."""
    buffer = io.BytesIO()
    Image.new("P", (12, 9), 3).save(buffer, "PNG")  # palette: decoded
    palette = buffer.getvalue()
    buffer = io.BytesIO()
    Image.new("LA", (12, 9), (40, 200)).save(buffer, "PNG")  # gray + alpha: decoded
    gray_alpha = buffer.getvalue()
    buffer = io.BytesIO()
    Image.new("L", (31, 17), 90).save(buffer, "PNG", interlace=1)  # Adam7: decoded
    interlaced = buffer.getvalue()
    gray = np.arange(9 * 12, dtype=np.uint8).reshape(9, 12)
    transparent = _png(12, 9, zlib.compress(_rows(gray)), extra=[_chunk(b"tRNS", b"\x00\x05")])
    text = _png(12, 9, zlib.compress(_rows(gray)), extra=[_chunk(b"tEXt", b"Camera\x00cam 2")])
    return [
        image_bytes(37, 23, channels=1, bit_depth=8),
        image_bytes(37, 23, channels=3, bit_depth=8),
        image_bytes(37, 23, channels=4, bit_depth=16),
        image_bytes(37, 23, channels=1, bit_depth=16),
        palette,
        gray_alpha,
        interlaced,
        transparent,
        text,
    ]


@pytest.mark.parametrize("index", range(9))
def test_check_image_says_what_decoding_says(index: int) -> None:
    data = _kinds_of_png()[index]
    assert check_image(data) == read_image(data).info


def test_check_image_inflates_the_whole_stream_not_only_the_checksums() -> None:
    """Damage that only decoding the stream can see: every chunk's CRC is right."""
    pixels = np.random.default_rng(3).integers(0, 255, (20, 30), dtype=np.uint8)
    good = _png(30, 20, zlib.compress(_rows(pixels)))
    assert check_image(good).width == 30
    stream = bytearray(zlib.compress(_rows(pixels), 9))
    stream[len(stream) // 2] ^= 0x10  # a flipped bit inside the deflate data
    short = zlib.compress(_rows(pixels)[:-30])  # a whole stream, one row too short
    bad_filter = zlib.compress(_rows(pixels, filter_type=5))  # no such row filter
    for stream_bytes in (bytes(stream), short, bad_filter):
        damaged = _png(30, 20, stream_bytes)
        with pytest.raises(InvalidInputError, match="truncated or corrupt"):
            check_image(damaged)
        with pytest.raises(InvalidInputError):
            read_image(damaged)  # the decoder refuses each too
    # One row too many: libpng only warns; a frame whose stream disagrees with its header is
    # refused here all the same (and a stream cannot inflate past the header's size).
    with pytest.raises(InvalidInputError, match="truncated or corrupt"):
        check_image(_png(30, 20, zlib.compress(_rows(pixels) + b"\x00" * 31)))


def test_check_image_refuses_a_changed_byte_only_the_chunk_checksum_covers() -> None:
    gray = np.arange(9 * 12, dtype=np.uint8).reshape(9, 12)
    data = bytearray(_png(12, 9, zlib.compress(_rows(gray)), extra=[_chunk(b"tEXt", b"a\x00b")]))
    assert check_image(bytes(data)).height == 9
    data[data.index(b"tEXt") + 4] ^= 0x01  # the text's first byte: its CRC no longer matches
    with pytest.raises(InvalidInputError, match="truncated or corrupt"):
        check_image(bytes(data))


def test_check_image_refuses_every_truncation_and_no_damage_the_decoder_refuses() -> None:
    """Truncated at every length, and bytes flipped at random: whatever the decoder refuses,
    check_image refuses too; what it accepts, the decoder reads with the same info."""
    rng = np.random.default_rng(0)
    originals = [image_bytes(23, 11, channels=c, bit_depth=b) for c, b in ((1, 8), (3, 16))]
    for original in originals:
        for length in range(len(original)):
            with pytest.raises(InvalidInputError):
                check_image(original[:length])
        for _ in range(400):
            damaged = bytearray(original)
            for position in rng.integers(0, len(original), size=int(rng.integers(1, 4))):
                damaged[position] ^= 1 << int(rng.integers(0, 8))
            try:
                info = check_image(bytes(damaged))
            except InvalidInputError:
                continue
            assert read_image(bytes(damaged)).info == info


def _window(stream: bytes, cinfo: int) -> bytes:
    """The same zlib stream claiming a window of 2**(cinfo + 8) bytes (its check bits mended)."""
    cmf = (cinfo << 4) | 8
    flg = stream[1] & 0xE0
    flg |= (31 - (cmf * 256 + flg) % 31) % 31
    return bytes([cmf, flg]) + stream[2:]


def _odd_pngs() -> dict[str, bytes]:
    """PNGs whose oddity one library refuses and the other may not (found in review)."""
    gray = np.random.default_rng(4).integers(0, 255, (20, 300), dtype=np.uint8)
    stream = zlib.compress(_rows(np.tile(gray[:, :150], 2)))  # repeats 150 bytes back and more
    ok = zlib.compress(_rows(gray))
    header = _chunk(b"IHDR", struct.pack(">IIBBBBB", 300, 20, 8, 0, 0, 0, 0))
    return {
        "two IHDR": _png(300, 20, ok, extra=[header]),
        "a chunk name with a digit": _png(300, 20, ok, extra=[_chunk(b"a123", b"x")]),
        "a chunk name with the reserved bit": _png(300, 20, ok, extra=[_chunk(b"abcd", b"x")]),
        "iCCP of compression 1": _png(
            300, 20, ok, extra=[_chunk(b"iCCP", b"p\x00\x01" + zlib.compress(b"x"))]
        ),
        "zTXt of compression 1": _png(
            300, 20, ok, extra=[_chunk(b"zTXt", b"k\x00\x01" + zlib.compress(b"x"))]
        ),
        "a truncated gAMA": _png(300, 20, ok, extra=[_chunk(b"gAMA", b"\x00")]),
        "an empty bKGD": _png(300, 20, ok, extra=[_chunk(b"bKGD", b"")]),
        "a short APNG acTL": _png(300, 20, ok, extra=[_chunk(b"acTL", b"\x00")]),
        "a private chunk over 8 MB": _png(  # libpng's chunk limit: OpenCV refuses it
            300, 20, ok, extra=[_chunk(b"weLd", b"x" * 8_000_001)]
        ),
        "a zlib window too small for its distances": _png(300, 20, _window(stream, 0)),
        "a zlib window smaller than 32 KiB but enough": _png(300, 20, _window(stream, 5)),
        "a private chunk": _png(300, 20, ok, extra=[_chunk(b"weLd", b"\x00" * 7)]),
        "2,000,000 pixels in a row": _png(
            2_000_000, 1, zlib.compress(b"\x00" + bytes(2_000_000)), colour=0
        ),
    }


@pytest.mark.parametrize("name", list(_odd_pngs()))
def test_check_image_agrees_with_decoding_on_odd_pngs(name: str) -> None:
    """Whatever the decoder refuses is refused; what it reads is read with the same info."""
    data = _odd_pngs()[name]

    def outcome(read) -> object:  # type: ignore[no-untyped-def]
        try:
            return read(data)
        except InvalidInputError:
            return "refused"

    assert outcome(check_image) == outcome(lambda d: read_image(d).info)


def test_check_image_applies_the_pixel_limit_before_inflating() -> None:
    with pytest.raises(InvalidInputError, match="WELDPOOL_MAX_IMAGE_PIXELS"):
        check_image(image_bytes(100, 100), max_pixels=5000)


def test_check_image_on_the_real_frames() -> None:
    frames = sorted((SHARED_DATA / "waam" / "frames").glob("*.png"))[:4]
    if not frames:
        pytest.skip("../shared/data/waam is absent (a fresh checkout has no ../shared)")
    for path in frames:
        data = path.read_bytes()
        assert check_image(data) == read_image(data).info
        with pytest.raises(InvalidInputError):
            check_image(data[: len(data) - 100])
