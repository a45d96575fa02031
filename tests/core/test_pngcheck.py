"""The PNG verifier of ingest (``weldpool_core.pngcheck``, through ``io.check_image``): it says
what decoding says, on every layout of PNG, on odd ones, on every truncation, and on random
chunk mutations of frames (a differential fuzz against ``io.read_image``)."""

from __future__ import annotations

import io
import struct
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from PIL import Image

from tests.helpers import SHARED_DATA, image_bytes
from weldpool_core.errors import InvalidInputError
from weldpool_core.io import check_image, read_image
from weldpool_core.synth import SynthParams, synth_frame


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


# --- differential fuzz: chunk mutations of frames ------------------------------------------------

MUTATION_KINDS = [
    *(b"tEXt", b"zTXt", b"iCCP", b"tRNS", b"bKGD", b"pHYs", b"gAMA", b"sRGB", b"eXIf"),
    *(b"acTL", b"fcTL", b"prVt", b"abcd", b"a1cd", b"IDAT", b"IEND", b"IHDR", b"PLTE"),
]
"""Chunk types a mutation renames a chunk to or inserts: public and private ancillary ones,
APNG's, invalid names, and the critical ones out of place."""


def _frames() -> list[bytes]:
    """Frames as a camera's software writes them (OpenCV's PNG: gray and colour, 8 and 16
    bit), and real WAAM frames where ../shared is here."""
    params = SynthParams(width=160, height=100)
    gray = synth_frame(1, params).image
    colour = cv2.cvtColor(synth_frame(2, params).image, cv2.COLOR_GRAY2BGR)
    deep = gray.astype(np.uint16) * 257
    frames = [cv2.imencode(".png", image)[1].tobytes() for image in (gray, colour, deep)]
    real = sorted((SHARED_DATA / "waam" / "frames").glob("*.png"))[:2]
    return frames + [Path(path).read_bytes() for path in real]


FRAMES = _frames()


def _chunks(data: bytes) -> list[tuple[bytes, bytes]]:
    out, position = [], 8
    while position + 12 <= len(data):
        length, kind = struct.unpack_from(">I4s", data, position)
        out.append((kind, data[position + 8 : position + 8 + length]))
        position += 12 + length
        if kind == b"IEND":
            break
    return out


def _assemble(chunks: list[tuple[bytes, bytes]], wrong_crc: int | None = None) -> bytes:
    parts = [b"\x89PNG\r\n\x1a\n"]
    for index, (kind, body) in enumerate(chunks):
        crc = zlib.crc32(kind + body) ^ (1 if index == wrong_crc else 0)
        parts.append(struct.pack(">I", len(body)) + kind + body + struct.pack(">I", crc))
    return b"".join(parts)


@st.composite
def mutated_frames(draw: st.DrawFn) -> bytes:
    """A frame with one chunk-level mutation, CRCs mended unless the mutation is a wrong CRC:
    a chunk dropped, doubled, swapped with the next, a byte of it flipped, cut short, renamed,
    a new chunk inserted, a header field changed, or a CRC made wrong."""
    chunks = _chunks(FRAMES[draw(st.integers(0, len(FRAMES) - 1))])
    index = draw(st.integers(0, len(chunks) - 1))
    kind, body = chunks[index]
    operation = draw(
        st.sampled_from(
            ["drop", "double", "swap", "flip", "cut", "rename", "insert", "header", "crc"]
        )
    )
    wrong_crc = None
    if operation == "drop":
        del chunks[index]
    elif operation == "double":
        chunks.insert(index, (kind, body))
    elif operation == "swap" and index + 1 < len(chunks):
        chunks[index], chunks[index + 1] = chunks[index + 1], chunks[index]
    elif operation == "flip" and body:
        flipped = bytearray(body)
        flipped[draw(st.integers(0, len(body) - 1))] ^= 1 << draw(st.integers(0, 7))
        chunks[index] = (kind, bytes(flipped))
    elif operation == "cut":
        chunks[index] = (kind, body[: draw(st.integers(0, len(body)))])
    elif operation == "rename":
        chunks[index] = (draw(st.sampled_from(MUTATION_KINDS)), body)
    elif operation == "insert":
        chunks.insert(index, (draw(st.sampled_from(MUTATION_KINDS)), draw(st.binary(max_size=24))))
    elif operation == "header":
        header = bytearray(chunks[0][1])
        header[draw(st.integers(0, 12))] = draw(st.integers(0, 255))
        chunks[0] = (chunks[0][0], bytes(header))
    else:
        wrong_crc = index
    return _assemble(chunks, wrong_crc)


def _outcome(read, data: bytes) -> object:  # type: ignore[no-untyped-def]
    try:
        return read(data)
    except InvalidInputError:
        return "refused"


def test_the_fuzzed_frames_are_frames_to_begin_with() -> None:
    for data in FRAMES:
        assert check_image(data) == read_image(data).info


@settings(max_examples=400, deadline=None, derandomize=True)
@given(mutated_frames())
def test_check_image_and_read_image_agree_on_mutated_frames(data: bytes) -> None:
    """Both refuse, or both accept with the same info (check_image keeps no pixel)."""
    assert _outcome(check_image, data) == _outcome(lambda d: read_image(d).info, data)
