"""The one image reader and the one mask codec of weldpool.

``read_image`` accepts PNG, JPEG, TIFF and BMP files, 8- or 16-bit, gray, RGB or RGBA, checks
them (format by content, pixel limit before decoding, truncation) and decodes them once.
``to_rgb8`` turns any decoded frame into what the models take: RGB ``uint8``.
``check_image`` checks a file without keeping its pixels (ingest): a plain PNG is decompressed in
full and verified (``pngcheck``), any other file is decoded by ``read_image``.

16-bit → 8-bit mapping (``stretch_to_uint8``): a linear stretch between the 0.5th percentile
(the background) and the 99.99th percentile of the frame (so that a few hot pixels do not set
the white point, while a small bright melt pool keeps its inner gradient instead of being
clipped flat). Frames whose values span less than 1 grey level map to black.
"""

from __future__ import annotations

import io
import struct
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeAlias

from isal import isal_zlib
from PIL import UnidentifiedImageError  # PIL's package, without its Image module

from weldpool_core.defaults import DEFAULT_MAX_PIXELS
from weldpool_core.errors import InvalidInputError
from weldpool_core.pngcheck import CORRUPT as _CORRUPT
from weldpool_core.pngcheck import PNG_SIGNATURE, plain_png, verify_stream

if TYPE_CHECKING:
    import cv2
    import numpy as np
    from numpy.typing import NDArray
    from PIL import Image
else:
    from weldpool_core.lazy import Image, cv2, np


MEDIA_TYPES = {"PNG": "image/png", "JPEG": "image/jpeg", "TIFF": "image/tiff", "BMP": "image/bmp"}
EXTENSIONS = {"PNG": ".png", "JPEG": ".jpg", "TIFF": ".tif", "BMP": ".bmp"}
LOW_PERCENTILE = 0.5
HIGH_PERCENTILE = 99.99
_SUPPORTED = "upload PNG, JPEG, TIFF or BMP"

ImageArray: TypeAlias = "NDArray[Any]"
"""Pixels of a frame: H×W or H×W×C (RGB order), uint8 or uint16."""


@dataclass(frozen=True)
class ImageInfo:
    """What a frame file is: format, size, channels and bits per channel."""

    format: str
    media_type: str
    extension: str
    width: int
    height: int
    channels: int
    bit_depth: int


@dataclass(frozen=True)
class DecodedImage:
    """A decoded frame: ``pixels`` is H×W (gray) or H×W×C in RGB(A) order, uint8 or uint16."""

    pixels: ImageArray
    info: ImageInfo


_SIGNATURES = {
    PNG_SIGNATURE: ".png",
    b"\xff\xd8\xff": ".jpg",
    b"II*\x00": ".tif",
    b"MM\x00*": ".tif",
    b"BM": ".bmp",
}


def header_extension(data: bytes) -> str | None:
    """The extension a file's first bytes announce (PNG, JPEG, TIFF, BMP), or None; nothing is
    checked: ``check_image`` says whether it is one (and names the same extension)."""
    return next((e for head, e in _SIGNATURES.items() if data.startswith(head)), None)


def _sniff_text(data: bytes) -> str | None:
    head = data[:512].lstrip().lower()
    if head.startswith(b"<?xml") or b"<svg" in head:
        return "SVG images are not supported"
    if head.startswith((b"<!doctype", b"<html")) or b"<html" in head:
        return "HTML files are not images"
    return None


def _probe(data: bytes, max_pixels: int) -> tuple[str, int, int]:
    """The format of ``data`` (PNG, JPEG, TIFF, BMP) and its width and height, from its header
    (nothing decoded); refuses the rest."""
    if not data:
        raise InvalidInputError("The file is empty.")
    text = _sniff_text(data)
    if text:
        raise InvalidInputError(f"{text}; {_SUPPORTED}.")
    try:
        with Image.open(io.BytesIO(data)) as probe:
            fmt, (width, height) = str(probe.format), probe.size
    except UnidentifiedImageError:
        raise InvalidInputError(
            f"The file is not a readable image (or is truncated); {_SUPPORTED}."
        ) from None
    except (OSError, ValueError, SyntaxError) as exc:
        raise InvalidInputError(
            f"The image is truncated or its header is corrupt ({exc})."
        ) from None
    if fmt not in MEDIA_TYPES:
        raise InvalidInputError(f"{fmt} files are not supported; {_SUPPORTED}.")
    if width * height > max_pixels:
        raise InvalidInputError(
            f"The image has {width}×{height} pixels, more than the limit of {max_pixels:,} "
            "(WELDPOOL_MAX_IMAGE_PIXELS)."
        )
    return fmt, width, height


def read_image(source: bytes | str | Path, *, max_pixels: int = DEFAULT_MAX_PIXELS) -> DecodedImage:
    """Check and decode a frame file (bytes or a path); the original values are kept.

    A PNG is verified as ``check_image`` verifies it (``pngcheck``) before it is decoded, so the
    two refuse the same files: libpng alone passes over a wrong CRC after the image data and
    does not read the stream's Adler-32. Raises InvalidInputError with one sentence for empty,
    truncated, corrupt, oversized or unsupported files.
    """
    data = source if isinstance(source, bytes) else Path(source).read_bytes()
    fmt, _, _ = _probe(data, max_pixels)
    if fmt == "PNG":  # as strict as check_image: every chunk's CRC, a plain PNG's stream
        png = plain_png(data)
        if png is not None:
            verify_stream(png)
    pixels = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if pixels is None:
        raise InvalidInputError(_CORRUPT)
    if pixels.dtype not in (np.uint8, np.uint16):
        raise InvalidInputError(
            f"{pixels.dtype} pixels are not supported; use 8- or 16-bit integer images."
        )
    if pixels.ndim == 3 and pixels.shape[2] == 1:
        pixels = pixels[:, :, 0]
    if pixels.ndim == 3:
        code = cv2.COLOR_BGRA2RGBA if pixels.shape[2] == 4 else cv2.COLOR_BGR2RGB
        pixels = cv2.cvtColor(pixels, code)
    height, width = pixels.shape[:2]
    info = ImageInfo(
        format=fmt,
        media_type=MEDIA_TYPES[fmt],
        extension=EXTENSIONS[fmt],
        width=width,
        height=height,
        channels=1 if pixels.ndim == 2 else pixels.shape[2],
        bit_depth=16 if pixels.dtype == np.uint16 else 8,
    )
    return DecodedImage(pixels, info)


def check_image(data: bytes, *, max_pixels: int = DEFAULT_MAX_PIXELS) -> ImageInfo:
    """What ``read_image(data).info`` says, checked as strictly, without keeping the pixels.

    A plain PNG (``pngcheck.plain_png``: 8- or 16-bit gray, RGB or RGBA, not interlaced, no
    ``tRNS``, only chunks both OpenCV and Pillow read alike) is verified down to its last byte
    instead (``pngcheck``), after Pillow's header checks and the pixel limit, before anything
    is inflated. Any other file is decoded by ``read_image``.

    Raises InvalidInputError with one sentence, as ``read_image`` does.
    """
    png = plain_png(data) if data.startswith(PNG_SIGNATURE) else None
    if png is not None:
        _probe(data, max_pixels)  # Pillow's header checks and the pixel limit, as read_image
        if verify_stream(png):
            return ImageInfo(
                format="PNG",
                media_type=MEDIA_TYPES["PNG"],
                extension=EXTENSIONS["PNG"],
                width=png.width,
                height=png.height,
                channels=png.channels,
                bit_depth=png.depth,
            )
    return read_image(data, max_pixels=max_pixels).info


def stretch_to_uint8(
    pixels: ImageArray,
    low_percentile: float = LOW_PERCENTILE,
    high_percentile: float = HIGH_PERCENTILE,
) -> NDArray[np.uint8]:
    """Map 16-bit values to 8 bits linearly between two percentiles (see the module doc)."""
    histogram = np.bincount(pixels.ravel(), minlength=65536)
    cumulative = np.cumsum(histogram) / pixels.size
    low = int(np.searchsorted(cumulative, low_percentile / 100))
    high = int(np.searchsorted(cumulative, high_percentile / 100))
    if high - low < 1:
        return np.zeros(pixels.shape, np.uint8)
    lut = np.clip((np.arange(65536, dtype=np.float32) - low) * (255.0 / (high - low)), 0, 255)
    mapped: NDArray[np.uint8] = lut.round().astype(np.uint8)[pixels]
    return mapped


def to_rgb8(image: DecodedImage | ImageArray) -> NDArray[np.uint8]:
    """RGB uint8 (H×W×3) for the models: gray is repeated, alpha dropped, 16-bit stretched."""
    pixels = image.pixels if isinstance(image, DecodedImage) else image
    if pixels.dtype == np.uint16:
        pixels = stretch_to_uint8(pixels)  # one mapping for all channels keeps colours
    if pixels.ndim == 2:
        return np.ascontiguousarray(np.repeat(pixels[:, :, None], 3, axis=2), dtype=np.uint8)
    return np.ascontiguousarray(pixels[:, :, :3], dtype=np.uint8)


def load_rgb8(path: str | Path, *, max_pixels: int = DEFAULT_MAX_PIXELS) -> NDArray[np.uint8]:
    """Read a frame file and return it as RGB uint8."""
    return to_rgb8(read_image(path, max_pixels=max_pixels))


def encode_png(pixels: ImageArray, compression: int = 1) -> bytes:
    """PNG bytes of a gray, RGB or RGBA array (RGB order), 8- or 16-bit; fast compression."""
    if pixels.ndim == 3:
        code = cv2.COLOR_RGBA2BGRA if pixels.shape[2] == 4 else cv2.COLOR_RGB2BGR
        pixels = cv2.cvtColor(pixels, code)
    ok, buffer = cv2.imencode(".png", pixels, [cv2.IMWRITE_PNG_COMPRESSION, compression])
    if not ok:
        raise InvalidInputError("The array cannot be encoded as PNG.")
    return buffer.tobytes()


MASK_PNG_LEVEL = 1
"""ISA-L's deflate level for a mask PNG's one image stream (levels 1 and 2 give the same file
on a pool mask; 0 is five times larger)."""


def _png_chunk(kind: bytes, body: bytes) -> bytes:
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))


def encode_mask_png(mask: ImageArray) -> bytes:
    """A mask as a single-channel 8-bit PNG with values 0 and 255.

    The file is framed here (header, one image stream, end) because its cost is the deflate:
    ISA-L's (``isal``) compresses a 1280×800 mask's rows 17× faster than the zlib OpenCV
    and Pillow use (0.09 against 1.56 ms, and a smaller file: every click in the review page
    and every imported label makes one). Rows are unfiltered: a mask is long runs of 0 and
    255, which the filters do not shorten. Any PNG reader reads it (tests: OpenCV, Pillow and
    the ingest's own verifier)."""
    if mask.ndim != 2:
        raise InvalidInputError(f"A mask must be a 2-D array, not of shape {mask.shape}.")
    height, width = mask.shape
    if height == 0 or width == 0:
        raise InvalidInputError("The mask cannot be encoded as PNG: it has no pixels.")
    binary = mask if mask.dtype == np.bool_ else mask > 0
    rows = np.zeros((height, width + 1), np.uint8)  # each row: filter type 0, then its pixels
    np.multiply(binary.view(np.uint8), np.uint8(255), out=rows[:, 1:])
    header = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)  # 8-bit gray, plain
    stream = isal_zlib.compress(rows, MASK_PNG_LEVEL)
    return b"".join(
        (
            PNG_SIGNATURE,
            _png_chunk(b"IHDR", header),
            _png_chunk(b"IDAT", stream),
            _png_chunk(b"IEND", b""),
        )
    )


def decode_mask_png(
    data: bytes,
    *,
    max_pixels: int = DEFAULT_MAX_PIXELS,
    shape: tuple[int, int] | None = None,
) -> NDArray[np.bool_]:
    """A boolean mask from a PNG: 0/255 (or 0/1) single channel; colour masks use channel max.

    Values ≥ 128 are foreground, or > 0 when the image holds only 0 and 1. ``shape``: the
    (height, width) the mask must have (a frame's), checked on the header before anything is
    decoded, so a mask sent for a frame never costs more than the frame's pixels.
    """
    if shape is not None:
        _, width, height = _probe(data, max_pixels)
        if (height, width) != tuple(shape):
            raise InvalidInputError(
                f"The mask is {width}×{height}; the frame is {shape[1]}×{shape[0]}."
            )
        max_pixels = height * width
    image = read_image(data, max_pixels=max_pixels)
    if image.info.format != "PNG":
        raise InvalidInputError(f"A mask must be a PNG file, not {image.info.format}.")
    pixels = mask_gray(image.pixels)
    return pixels > mask_level(pixels)


def mask_gray(pixels: ImageArray) -> NDArray[np.uint8]:
    """A mask image's one gray channel: the max of its colour channels, 16-bit scaled to 8."""
    if pixels.ndim == 3:
        pixels = pixels[:, :, :3].max(axis=2)
    if pixels.dtype == np.uint16:
        pixels = (pixels >> 8).astype(np.uint8)
    return np.asarray(pixels, np.uint8)


def mask_level(gray: NDArray[np.uint8]) -> int:
    """The gray level above which a mask pixel is pool: 0 for a mask of 0 and 1 only, else 127
    (values ≥ 128 are foreground). The one rule of every mask reader."""
    peak = int(gray.max()) if gray.size else 0
    return 0 if peak <= 1 else 127


def read_mask(path: str | Path) -> NDArray[np.bool_]:
    """A boolean mask from a PNG file (see ``decode_mask_png``)."""
    return decode_mask_png(Path(path).read_bytes())
