"""Reading weld videos: probe a file, and iterate over every n-th frame with its time stamp."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

from weldpool_core.errors import InvalidInputError

if TYPE_CHECKING:
    import cv2
    import numpy as np
    from numpy.typing import NDArray
else:
    from weldpool_core.lazy import cv2, np

_SUPPORTED = "upload an MP4 or AVI video"
T = TypeVar("T")
VIDEO_SUFFIXES = frozenset({".mp4", ".mov", ".avi", ".mkv"})
"""File names of the containers ``sniff_container`` knows."""


@dataclass(frozen=True)
class VideoInfo:
    """What a video file holds."""

    container: str
    width: int
    height: int
    fps: float
    frame_count: int


@dataclass(frozen=True)
class VideoFrame:
    """One decoded frame: gray (H×W) when the video's three channels are equal, else RGB."""

    index: int
    timestamp_s: float
    pixels: NDArray[np.uint8]


def sniff_container(head: bytes) -> str | None:
    """The container of a video from its first bytes: mp4, mov, avi, mkv; None otherwise."""
    if len(head) >= 12 and head[4:8] == b"ftyp":
        return "mov" if head[8:10] == b"qt" else "mp4"
    if head[:4] == b"RIFF" and head[8:12] == b"AVI ":
        return "avi"
    if head[:4] == b"\x1a\x45\xdf\xa3":
        return "mkv"
    return None


def _open(path: Path) -> cv2.VideoCapture:
    capture = cv2.VideoCapture(str(path), cv2.CAP_FFMPEG)
    if not capture.isOpened():
        raise InvalidInputError(f"The video cannot be opened; {_SUPPORTED}.")
    return capture


def probe_video(path: str | Path) -> VideoInfo:
    """Check that ``path`` is a readable video (its first frame decodes) and describe it."""
    path = Path(path)
    with open(path, "rb") as handle:
        container = sniff_container(handle.read(16))
    if container is None:
        raise InvalidInputError(f"The file is not a video; {_SUPPORTED}.")
    capture = _open(path)
    try:
        ok, frame = capture.read()
        if not ok or frame is None:
            raise InvalidInputError(f"The video has no readable frame; {_SUPPORTED}.")
        fps = float(capture.get(cv2.CAP_PROP_FPS)) or 0.0
        count = int(capture.get(cv2.CAP_PROP_FRAME_COUNT))
        return VideoInfo(container, frame.shape[1], frame.shape[0], fps, max(count, 1))
    finally:
        capture.release()


def _as_stored(frame: NDArray[Any]) -> NDArray[np.uint8]:
    """Gray when B, G and R are equal (grayscale cameras), else RGB."""
    if frame.ndim == 2:
        return frame.astype(np.uint8, copy=False)
    blue, green, red = frame[:, :, 0], frame[:, :, 1], frame[:, :, 2]
    if np.array_equal(blue, green) and np.array_equal(green, red):
        gray: NDArray[np.uint8] = np.ascontiguousarray(blue, dtype=np.uint8)
        return gray
    rgb: NDArray[np.uint8] = np.asarray(cv2.cvtColor(frame, cv2.COLOR_BGR2RGB), np.uint8)
    return rgb


def iter_video_frames(path: str | Path, every_nth: int = 1) -> Iterator[VideoFrame]:
    """Every ``every_nth`` frame (0, n, 2n, …) with its index and time stamp in seconds.

    Skipped frames are only grabbed, not converted. The time stamp is the container's
    presentation time where it has one, else index / fps.
    """
    if every_nth < 1:
        raise InvalidInputError("every_nth must be 1 or more.")
    capture = _open(Path(path))
    fps = float(capture.get(cv2.CAP_PROP_FPS)) or 0.0
    try:
        index = 0
        while capture.grab():
            if index % every_nth == 0:
                ok, frame = capture.retrieve()
                if not ok or frame is None:
                    break
                stamp_ms = float(capture.get(cv2.CAP_PROP_POS_MSEC))
                if stamp_ms <= 0 and index > 0:
                    stamp_ms = 1000.0 * index / fps if fps else 0.0
                yield VideoFrame(index, stamp_ms / 1000.0, _as_stored(frame))
            index += 1
    finally:
        capture.release()


def spread_evenly(items: Sequence[T], count: int) -> list[T]:
    """Up to ``count`` of ``items`` spread evenly over them, first and last included (all of
    them when there are no more than ``count``): frames of a run to calibrate on."""
    if len(items) <= count:
        return list(items)
    return [items[round(i)] for i in np.linspace(0, len(items) - 1, count)]


def spread_frames(path: str | Path, count: int) -> list[NDArray[np.uint8]]:
    """Up to ``count`` frames spread evenly through a video (gray or RGB, as stored)."""
    every = max(1, probe_video(path).frame_count // max(count, 1))
    return spread_evenly([frame.pixels for frame in iter_video_frames(path, every)], count)
