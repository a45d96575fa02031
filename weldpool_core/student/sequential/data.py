"""The sequential student's clips: labelled frames of videos, the windows of frames they need."""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from weldpool_core.errors import InvalidInputError
from weldpool_core.student.data import (
    FrameGeometry,
    TrainingFrame,
)
from weldpool_core.student.model import StudentConfig
from weldpool_core.student.sequential.config import SequentialConfig


@dataclass(frozen=True)
class LabelledClip:
    """A video's frames (in order, any frame rate) and the labelled ones among them.

    Attributes:
        frames: a callable giving frame ``index`` as H×W×3 RGB uint8 (a decoded video, or a
            list's ``__getitem__``), and ``length`` frames in all.
        labels: frame index → its label (a ``TrainingFrame`` of that frame).
        name: for messages.
        unlabelled: the last frames of unlabelled windows (the steadiness term's; their
            ``window`` frames, stride 1, must be readable).
        placed: when set, ``frames`` gives each frame already placed on the student's S×S
            input by this geometry (the frames' own size is ``placed.height × width``), so a
            clip holds its windows at model resolution, not the camera's.
    """

    frames: Callable[[int], NDArray[np.uint8]]
    length: int
    labels: dict[int, TrainingFrame]
    name: str = ""
    unlabelled: tuple[int, ...] = ()
    placed: FrameGeometry | None = None


def unlabelled_ends(length: int, config: SequentialConfig) -> tuple[int, ...]:
    """The last frames of up to ``unlabelled_windows`` evenly spaced unlabelled windows."""
    first = config.window - 1
    if length <= first or not config.unlabelled_windows or not config.consistency:
        return ()
    ends = np.linspace(first, length - 1, min(config.unlabelled_windows, length - first))
    return tuple(sorted({int(e) for e in np.rint(ends)}))


def needed_frames(
    labels: Sequence[int], config: SequentialConfig, unlabelled: Sequence[int] = ()
) -> set[int]:
    """The frame indices the training windows of ``labels`` (and of the unlabelled window
    ends) read."""
    wanted = {
        index - stride * back
        for index in labels
        for stride in config.strides
        for back in range(config.window)
        if index - stride * (config.window - 1) >= 0
    }
    wanted |= {end - back for end in unlabelled for back in range(config.window)}
    return wanted


def video_clip(
    path: str | Path,
    labels: dict[int, TrainingFrame],
    config: SequentialConfig,
    unlabelled: Sequence[int] | None = None,
    student: StudentConfig | None = None,
) -> LabelledClip:
    """A ``LabelledClip`` of a video file that decodes only the frames its windows read.
    ``unlabelled``: the unlabelled windows' last frames (default ``unlabelled_ends`` of the
    video's length). With ``student``, each frame is kept placed on that student's input as it
    is decoded (a 1280×800 frame: 64 KB instead of 1 MB gray, 3 MB colour); without, as stored
    (gray for a grayscale camera). The windows are the same either way."""
    from weldpool_core.io import to_rgb8
    from weldpool_core.video import iter_video_frames, probe_video

    if unlabelled is None:
        ends = unlabelled_ends(probe_video(path).frame_count, config)
    else:
        ends = tuple(sorted({int(e) for e in unlabelled if e >= config.window - 1}))
    wanted = needed_frames(list(labels), config, ends)
    kept: dict[int, NDArray[np.uint8]] = {}
    placed: FrameGeometry | None = None
    length = 0
    for frame in iter_video_frames(path):
        length = frame.index + 1
        if frame.index in wanted:
            pixels = frame.pixels
            if student is not None:
                if placed is None:
                    placed = _placement(pixels.shape[:2], labels, student, Path(path).name)
                pixels = placed.image_to_input(pixels)
            kept[frame.index] = pixels
        if wanted and frame.index >= max(wanted):
            break
    missing = sorted(i for i in labels if i >= length)
    if missing:
        raise InvalidInputError(
            f"{Path(path).name} has {length} frames; labelled frame {missing[0]} is not in it."
        )
    readable = tuple(e for e in ends if e < length)  # the header's count may overstate

    def read(index: int) -> NDArray[np.uint8]:
        return to_rgb8(kept[index])

    return LabelledClip(
        read,
        max(length, max(labels, default=0) + 1),
        labels,
        Path(path).stem,
        unlabelled=readable,
        placed=placed,
    )


def _placement(
    shape: tuple[int, ...], labels: dict[int, TrainingFrame], student: StudentConfig, name: str
) -> FrameGeometry:
    """The geometry that places a video's frames on the student's input; its labelled frames
    must land on the same part of the input (the video's size, or a scaled copy of it)."""
    height, width = int(shape[0]), int(shape[1])
    placed = FrameGeometry.fit(height, width, student.input_size, student.aspect)
    for index, label in labels.items():
        rows, columns = int(label.image.shape[0]), int(label.image.shape[1])
        own = FrameGeometry.fit(rows, columns, student.input_size, student.aspect)
        if (own.inner_rows, own.inner_columns) != (placed.inner_rows, placed.inner_columns):
            raise InvalidInputError(
                f"Labelled frame {index} of {name} is {label.image.shape[1]}×"
                f"{label.image.shape[0]}, another shape than the video's {width}×{height} frames."
            )
    return placed


FRAME_STEM = re.compile(r"^(?P<video>.+)_f(?P<index>\d+)$")
"""A labelled frame's stem names its video and its 0-based frame index: ``<video>_f0050``."""
VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".mkv")


def dataset_clips(
    dataset: str | Path,
    videos: str | Path,
    config: SequentialConfig,
    student: StudentConfig | None = None,
) -> list[LabelledClip]:
    """The labelled videos of a DATASET whose stems are ``<video>_f<index>`` (their videos in
    ``videos``), one clip per video; a one-sentence error for a stem or video that does not fit."""
    from weldpool_core.student.data import read_dataset

    by_video: dict[str, dict[int, TrainingFrame]] = {}
    for frame in read_dataset(dataset):
        match = FRAME_STEM.match(frame.name)
        if match is None:
            raise InvalidInputError(
                f"{frame.name} does not name its video frame; name labelled frames "
                "<video>_f<index> (for example weld3_f0050)."
            )
        by_video.setdefault(match["video"], {})[int(match["index"])] = frame
    clips = []
    for name, labels in sorted(by_video.items()):
        found = [Path(videos) / f"{name}{suffix}" for suffix in VIDEO_SUFFIXES]
        path = next((p for p in found if p.is_file()), None)
        if path is None:
            raise InvalidInputError(f"No video {name}.mp4 (or .avi, .mov, .mkv) in {videos}.")
        clips.append(video_clip(path, labels, config, student=student))
    return clips
