"""Records as the stream makes them, for the output tests."""

from __future__ import annotations

import time
from typing import Any


def record(frame: int, width_px: float = 50.0, scaled: bool = False) -> dict[str, Any]:
    """A stream record (``weldpool_core.cell.stream.record_fields``) following ``frame``."""
    mm = 0.1 if scaled else None
    return {
        "frame": frame,
        "captured_at": time.time(),
        "time_s": frame / 30,
        "keypoints": [[10.0 + frame, 20.0], None],
        "keypoints_raw": None,
        "area_px": 4000 + frame,
        "length_px": 80.0 + frame,
        "width_px": width_px,
        "centroid": [300.0, 200.0 + frame],
        "travel_deg": 0.0,
        "area_mm2": None if mm is None else (4000 + frame) * mm * mm,
        "length_mm": None if mm is None else (80.0 + frame) * mm,
        "width_mm": None if mm is None else width_px * mm,
        "stability_cv": 0.05,
        "unstable": False,
        "ambiguity": 0.05,
        "uncertainty": None,
        "dropped": 0,
        "latency_ms": 4.0,
    }
