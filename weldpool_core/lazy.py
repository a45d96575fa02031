"""NumPy, OpenCV, Pillow and PyYAML, loaded the first time they are used.

`weldpool serve` answers its first request before anything needs an array: importing these four
libraries is ~0.13 s of its start (a fifth of what the service adds to FastAPI's own import).
The modules a server imports at start name them through the stand-ins below (``np``, ``cv2``,
``Image``, ``yaml``) and type checkers through the real modules::

    if TYPE_CHECKING:
        import numpy as np
    else:
        from weldpool_core.lazy import np

A stand-in imports its library on the first attribute read (once, however many threads read at
once), copies the library's public names into itself and becomes a plain module, so that later
reads cost what a module's do (other names are read from the library). The settings weldpool
applies to a library are applied here, when it loads.
"""

from __future__ import annotations

import importlib
import threading
from collections.abc import Callable
from functools import partial
from types import ModuleType
from typing import Any


def _quiet_opencv(cv2: ModuleType) -> None:
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)  # errors are raised as ours


def _no_pillow_pixel_limit(image: Any) -> None:
    image.MAX_IMAGE_PIXELS = None  # our own limit (io's max_pixels) applies, before any decoding


class LazyModule(ModuleType):
    """A module that imports `name` on the first attribute read, then becomes a plain module
    holding the library's public names, with the module `__getattr__` (PEP 562) forwarding any
    other name to the library: after the first read, a read costs what a module's does."""

    def __init__(self, name: str, on_load: Callable[[ModuleType], None] | None = None) -> None:
        super().__init__(name)
        self._on_load = on_load
        self._loaded: ModuleType | None = None
        self._lock = threading.Lock()

    def __getattr__(self, attr: str) -> Any:  # until the library is loaded
        with self._lock:  # the settings once, however many threads read first
            if self._loaded is None:
                module = importlib.import_module(self.__name__)
                if self._on_load is not None:
                    self._on_load(module)
                self.__dict__.update({k: v for k, v in vars(module).items() if k[0] != "_"})
                self.__dict__["__getattr__"] = partial(getattr, module)
                self._loaded = module
                object.__setattr__(self, "__class__", ModuleType)
        return getattr(self._loaded, attr)


np = LazyModule("numpy")
cv2 = LazyModule("cv2", _quiet_opencv)
Image = LazyModule("PIL.Image", _no_pillow_pixel_limit)
yaml = LazyModule("yaml")
