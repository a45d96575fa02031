"""The numerical libraries' stand-ins: nothing loads before it is used, then each is the library
with weldpool's settings applied."""

from __future__ import annotations

import threading
import time
from types import ModuleType

from tests.helpers import fresh_python
from weldpool_core.lazy import LazyModule

FRESH_PROCESS = """
import sys
from weldpool_core.lazy import Image, cv2, np, yaml
import weldpool_core.io, weldpool_core.outline, weldpool_core.annotations
print(sorted(m for m in ("numpy", "cv2", "PIL.Image", "yaml") if m in sys.modules))
import numpy
print(np.zeros(2).dtype, np.ndarray is numpy.ndarray, isinstance(np.ones(1), np.ndarray))
print(cv2.utils.logging.getLogLevel() == cv2.utils.logging.LOG_LEVEL_SILENT)
print(Image.MAX_IMAGE_PIXELS, yaml.safe_load("a: 1"))
"""


def test_nothing_loads_before_use_then_each_is_the_library_with_our_settings() -> None:
    out = fresh_python(FRESH_PROCESS)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split("\n")[:4] == [
        "[]",
        "float64 True True",
        "True",  # OpenCV silent: its errors are raised as ours
        "None {'a': 1}",  # Pillow without its pixel limit: io's max_pixels applies
    ]


def test_a_stand_in_loads_once_for_many_threads_and_then_reads_like_the_module() -> None:
    loads: list[str] = []

    def slow_settings(module: ModuleType) -> None:
        time.sleep(0.05)  # other threads read meanwhile
        loads.append(module.__name__)

    colorsys = LazyModule("colorsys", slow_settings)
    barrier = threading.Barrier(8)
    answers: list[object] = []

    def first_read() -> None:
        barrier.wait()
        answers.append(colorsys.rgb_to_hsv)

    threads = [threading.Thread(target=first_read) for _ in range(8)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    import colorsys as real

    assert answers == [real.rgb_to_hsv] * 8
    assert loads == ["colorsys"]  # the settings applied once
    assert colorsys.__dict__["hsv_to_rgb"] is real.hsv_to_rgb  # copied: no call per read
    assert type(colorsys) is ModuleType
    assert colorsys._v is vars(real)["_v"]  # a private name: read from the library
