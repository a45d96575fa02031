"""Frames spread evenly over a run (calibration frames for the int8 student)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from tests.helpers import write_video
from weldpool_core.video import spread_evenly, spread_frames


def test_spread_evenly_takes_the_ends_and_even_steps() -> None:
    assert spread_evenly(list(range(10)), 4) == [0, 3, 6, 9]
    assert spread_evenly(list(range(101)), 5) == [0, 25, 50, 75, 100]
    assert spread_evenly(["a", "b"], 4) == ["a", "b"]  # no more than there are
    assert spread_evenly([], 3) == []


def test_spread_frames_reads_frames_from_the_whole_video(tmp_path: Path) -> None:
    # Frame i's corner holds 6·(i mod 40): the chosen frames' indices can be read back.
    video = write_video(tmp_path / "run.avi", 30)
    frames = spread_frames(video, 4)
    assert len(frames) == 4
    indices = [round(float(np.mean(frame[2:6, 2:6])) / 6) for frame in frames]
    assert indices[0] == 0 and indices[-1] >= 27  # from the start to the end, not the first 4
    assert indices == sorted(indices) and len(set(indices)) == 4
