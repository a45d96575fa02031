"""The PNG verifier of ingest: a plain PNG checked down to its last byte without decoding it.

``io.check_image`` must say what ``io.read_image`` says about a file — accept it with the same
info, or refuse it — while keeping no pixels. For a *plain* PNG (8- or 16-bit gray, RGB or
RGBA, not interlaced, no ``tRNS``, only chunks both OpenCV and Pillow read alike:
``_plain_chunk``) that is done here, in two steps around the pixel limit:

1. ``plain_png``: every chunk's CRC-32, the chunk layout and the header (None for a PNG that is
   not plain: the decoder then says what it makes of it);
2. ``verify_stream``: the whole image stream inflated (libdeflate, 2× zlib's speed) with its
   Adler-32, exactly the header's number of bytes, and a valid filter type on every row. Only
   undoing the row filters is left out: it cannot fail, and ingest needs no pixel.

Differential tests (``tests/core/test_pngcheck.py``) mutate real frames chunk by chunk and
check that the two paths agree.
"""

from __future__ import annotations

import re
import struct
from dataclasses import dataclass
from typing import TYPE_CHECKING

import deflate

from weldpool_core.errors import InvalidInputError

if TYPE_CHECKING:
    import numpy as np
else:
    from weldpool_core.lazy import np

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
CORRUPT = "The image is truncated or corrupt and cannot be decoded."
_PNG_CHANNELS = {0: 1, 2: 3, 6: 4}
"""Colour types whose decoded channels follow from the header alone (gray, RGB, RGBA); the
others (palette, gray + alpha) and any ``tRNS`` chunk change what OpenCV returns, so they are
decoded."""
_PNG_CHUNK = struct.Struct(">I4s")
_PNG_MAX_SIDE = 1_000_000
"""libpng's default limit on a side (OpenCV's decoder refuses larger)."""
_PNG_MAX_CHUNK = 8_000_000
"""libpng's default limit on a chunk other than IDAT."""
_PNG_NAME = re.compile(rb"[A-Za-z]{2}[A-Z][A-Za-z]")
"""A valid chunk name: four letters, the third (reserved bit) upper case."""
_PNG_ANCILLARY = {
    b"tEXt",
    b"iTXt",
    b"pHYs",
    b"gAMA",
    b"sRGB",
    b"cHRM",
    b"sBIT",
    b"tIME",
    b"eXIf",
}
"""Public ancillary chunks that change nothing OpenCV returns and that Pillow's header checks
(``io._probe``) read; any other public one (iCCP, zTXt, APNG's acTL / fcTL / fdAT, tRNS…) is
decoded; so is bKGD, which OpenCV reads itself (an empty one fails there). Private chunks
(second letter lower case) are skipped by both libraries."""
_APNG = {b"acTL", b"fcTL", b"fdAT"}


@dataclass(frozen=True)
class PlainPng:
    """A plain PNG's header and its image stream (the IDAT chunks joined), CRCs checked."""

    width: int
    height: int
    channels: int
    depth: int
    compressed: bytes

    @property
    def row(self) -> int:
        """Bytes of one scanline, its filter byte included."""
        return 1 + self.width * self.channels * self.depth // 8


def _plain_chunk(kind: bytes, length: int) -> bool:
    """Whether a chunk leaves a PNG plain (see the module doc)."""
    if kind in (b"IHDR", b"IDAT", b"IEND"):
        return True
    private = kind[1:2].islower() and kind not in _APNG
    named = _PNG_NAME.fullmatch(kind) is not None
    return named and length <= _PNG_MAX_CHUNK and (kind in _PNG_ANCILLARY or private)


def _chunks(data: bytes) -> list[tuple[bytes, memoryview]]:
    """Every chunk up to IEND, each CRC checked; InvalidInputError for a truncated file or a
    wrong CRC."""
    view = memoryview(data)
    chunks: list[tuple[bytes, memoryview]] = []
    position = len(PNG_SIGNATURE)
    while True:
        if position + 12 > len(data):
            raise InvalidInputError(CORRUPT)  # truncated before IEND
        length, kind = _PNG_CHUNK.unpack_from(data, position)
        end = position + 8 + length
        if length > 2**31 - 1 or end + 4 > len(data):
            raise InvalidInputError(CORRUPT)
        body = view[position + 8 : end]
        if deflate.crc32(view[position + 4 : end]) != int.from_bytes(view[end : end + 4], "big"):
            raise InvalidInputError(CORRUPT)
        chunks.append((kind, body))
        position = end + 4
        if kind == b"IEND":
            return chunks


def plain_png(data: bytes) -> PlainPng | None:
    """The header and stream of a plain PNG, its chunks verified; None for any other PNG.
    InvalidInputError for a truncated file or a wrong chunk CRC."""
    chunks = _chunks(data)
    kinds = [kind for kind, _ in chunks]
    if kinds[0] != b"IHDR" or len(chunks[0][1]) != 13:
        return None  # let the decoder say what is wrong
    width, height, depth, colour, compression, filtering, interlace = struct.unpack(
        ">IIBBBBB", chunks[0][1]
    )
    idat = [index for index, kind in enumerate(kinds) if kind == b"IDAT"]
    plain = (
        0 < width <= _PNG_MAX_SIDE
        and 0 < height <= _PNG_MAX_SIDE
        and colour in _PNG_CHANNELS
        and depth in (8, 16)
        and (compression, filtering, interlace) == (0, 0, 0)
        and kinds.count(b"IHDR") == 1
        and all(_plain_chunk(kind, len(body)) for kind, body in chunks)
        and bool(idat)
        and idat == list(range(idat[0], idat[-1] + 1))  # consecutive, as PNG requires
    )
    if not plain:
        return None  # the decoder says what it makes of it
    compressed = b"".join(chunks[i][1] for i in idat)
    return PlainPng(width, height, _PNG_CHANNELS[colour], depth, compressed)


def verify_stream(png: PlainPng) -> bool:
    """Inflate and check the image stream (see the module doc): True when it is whole, False
    when only the decoder can judge it (a zlib window under 32 KiB, which libdeflate does not
    enforce and zlib does); InvalidInputError when it is damaged."""
    compressed, size = png.compressed, png.row * png.height
    if compressed[:1] != b"\x78" and (not compressed or size > 1 << (compressed[0] // 16 + 8)):
        return False
    try:
        stream = deflate.zlib_decompress(compressed, size)
    except deflate.DeflateError:
        raise InvalidInputError(CORRUPT) from None
    if len(stream) != size:
        raise InvalidInputError(CORRUPT)
    if int(np.frombuffer(stream, np.uint8)[:: png.row].max()) > 4:
        raise InvalidInputError(CORRUPT)  # a row filter type PNG does not have
    return True
