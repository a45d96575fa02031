"""Defaults the service's settings share with the library, in a module that imports nothing:
the web process reads its settings long before it needs NumPy or OpenCV (``serve``'s start)."""

from __future__ import annotations

DEFAULT_WEIGHTS = {
    "teacher_iou": 1.0,
    "instability": 1.0,
    "disagreement": 1.0,
    "student_uncertainty": 1.0,
    "propagation_doubt": 1.0,
}
"""The uncertainty components' weights when the settings give none
(``WELDPOOL_UNCERTAINTY_WEIGHTS``; the components are ``weldpool_core.active``'s)."""

DEFAULT_MAX_PIXELS = 25_000_000
"""Largest frame read by default (5000×5000; weld cameras are far smaller): a guard against
decompression bombs, checked from the header before decoding."""
