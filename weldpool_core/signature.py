"""A weld run's signature: what its pool geometry over time says about the process.

From one run's per-frame width, length and area (millimetres with a scale, pixels without) and
the frames' times, ``run_signature`` gives:

- **Level and spread**: the median and the interquartile range of each figure (robust to the odd
  bad mask, as a welding engineer reads a bead's width).
- **Trend**: the least-squares slope of each figure over time (``scipy.stats.linregress``), and
  the change it makes over the whole run in % of the median — a run that drifts as the part
  heats up.
- **Stability**: the width's coefficient of variation (sample std / mean); its dominant
  oscillation frequency from a Lomb–Scargle periodogram of the detrended width
  (``scipy.signal.lombscargle``: frame times may be uneven — every n-th frame of a video, dropped
  frames — where an FFT needs even ones), in Hz with its strength (the share of the width's
  variance a sine at that frequency explains, 0..1); and the **unstable stretches**: runs of
  frames where the rolling coefficient of variation of the width over ``window_s`` exceeds
  ``unstable_cv``, each with its first and last frame.

``RollingStability`` is the same rolling figure one frame at a time, for the live stream.

Open choices, named parameters with their defaults (``SignatureParams``): a 0.5 s window
(a pool's thermal lag is a fraction of a second to a few seconds, ``plant.py``; half a second
holds one and a half periods of a 3 Hz humping oscillation), an unstable threshold of 8 %
rolling CV (steady GMAW pools vary by a few %), stretches shorter than 3 frames dropped,
frequencies from two periods per run up to the Nyquist rate of the median frame interval.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING, Any

from weldpool_core.errors import InvalidInputError

if TYPE_CHECKING:
    import numpy as np
    from numpy.typing import ArrayLike, NDArray
else:
    from weldpool_core.lazy import np

FIGURES = ("width", "length", "area")
"""The geometry figures a signature summarises."""


@dataclass(frozen=True)
class SignatureParams:
    """The open choices of a signature (module doc)."""

    window_s: float = 0.5
    """Rolling window of the unstable-stretch test, seconds (frames without times: 7 frames)."""
    window_frames: int = 7
    """The rolling window when the frames have no times."""
    unstable_cv: float = 0.08
    """Rolling coefficient of variation of the width above which a frame is unstable."""
    min_stretch_frames: int = 3
    """Unstable stretches shorter than this are noise, not instability."""
    min_periods: float = 2.0
    """The lowest frequency searched holds this many periods in the run."""
    oversample: int = 8
    """Frequency grid points per 1/duration (a finer grid finds the peak's centre)."""


@dataclass(frozen=True)
class Spread:
    """One figure over a run: median, quartiles and trend."""

    median: float | None
    q1: float | None
    q3: float | None
    frames: int
    trend_per_s: float | None = None
    """Least-squares slope over time (unit per second; per frame when frames have no times)."""
    trend_pct: float | None = None
    """The trend's change over the whole run, in % of the median."""

    @property
    def iqr(self) -> float | None:
        return None if self.q1 is None or self.q3 is None else self.q3 - self.q1


@dataclass(frozen=True)
class Oscillation:
    """The width's dominant oscillation."""

    hz: float
    strength: float
    """The share of the detrended width's variance a sine at ``hz`` explains (0..1)."""


@dataclass(frozen=True)
class Stretch:
    """A run of unstable frames: positions in the run's frame order and their times."""

    start: int
    end: int
    """Inclusive."""
    start_s: float | None
    end_s: float | None
    peak_cv: float


@dataclass(frozen=True)
class Signature:
    """A run's signature (module doc). ``unit`` is ``mm`` with a scale, else ``px``."""

    unit: str
    frames: int
    measured: int
    """Frames with a pool (the others are left out of every figure)."""
    width: Spread
    length: Spread
    area: Spread
    width_cv: float | None
    oscillation: Oscillation | None
    stretches: list[Stretch] = field(default_factory=list)
    rolling_cv: list[float | None] = field(default_factory=list)
    """Per frame in run order: the width's rolling CV (None where it cannot be measured)."""

    def as_dict(self) -> dict[str, Any]:
        out = asdict(self)
        for name in FIGURES:
            out[name]["iqr"] = getattr(self, name).iqr
        return out


def _finite(values: ArrayLike) -> NDArray[np.float64]:
    array = np.asarray(values, dtype=np.float64)
    return np.where(np.isfinite(array), array, np.nan)


def spread(values: ArrayLike, times: ArrayLike | None = None) -> Spread:
    """Median, quartiles and trend of one figure (NaN frames left out); ``times`` in seconds
    (frame positions when None)."""
    from scipy import stats

    y = _finite(values)
    t = np.arange(len(y), dtype=np.float64) if times is None else _finite(times)
    keep = np.isfinite(y) & np.isfinite(t)
    if not keep.any():
        return Spread(None, None, None, 0)
    q1, median, q3 = (float(v) for v in np.percentile(y[keep], [25, 50, 75]))
    trend = pct = None
    if keep.sum() >= 3 and np.ptp(t[keep]) > 0:
        trend = float(stats.linregress(t[keep], y[keep]).slope)
        if median:
            pct = 100.0 * trend * float(np.ptp(t[keep])) / median
    return Spread(median, q1, q3, int(keep.sum()), trend, pct)


def coefficient_of_variation(values: ArrayLike) -> float | None:
    """Sample standard deviation over mean (NaN left out); None under 2 values or a zero mean."""
    y = _finite(values)
    y = y[np.isfinite(y)]
    if len(y) < 2 or not y.mean():
        return None
    return float(y.std(ddof=1) / y.mean())


def dominant_oscillation(
    times: ArrayLike, values: ArrayLike, params: SignatureParams | None = None
) -> Oscillation | None:
    """The strongest periodic component of ``values`` sampled at ``times`` (seconds, even or
    not): a Lomb–Scargle periodogram of the linearly detrended series. None without times,
    under 8 samples or a flat series."""
    from scipy import signal

    params = params or SignatureParams()
    t, y = _finite(times), _finite(values)
    keep = np.isfinite(t) & np.isfinite(y)
    t, y = t[keep], y[keep]
    if len(t) < 8:
        return None
    order = np.argsort(t, kind="stable")
    t, y = t[order], y[order]
    duration = float(t[-1] - t[0])
    steps = np.diff(t)
    steps = steps[steps > 0]
    if duration <= 0 or not len(steps):
        return None
    y = y - np.polyval(np.polyfit(t - t[0], y, 1), t - t[0])
    if not np.any(np.abs(y) > 1e-12 * max(1.0, float(np.abs(_finite(values)[keep]).max()))):
        return None
    low, high = params.min_periods / duration, 0.5 / float(np.median(steps))
    if high <= low:
        return None
    count = max(16, int(params.oversample * (high - low) * duration))
    hz = np.linspace(low, high, count)
    power = signal.lombscargle(t, y, 2 * math.pi * hz, normalize=True)
    best = int(np.argmax(power))
    return Oscillation(float(hz[best]), float(np.clip(power[best], 0.0, 1.0)))


def rolling_cv(
    values: ArrayLike, times: ArrayLike | None = None, params: SignatureParams | None = None
) -> NDArray[np.float64]:
    """Per sample, the coefficient of variation of ``values`` over a centred window (``window_s``
    of ``times``, or ``window_frames`` samples without them); NaN where the window holds under
    3 measured values. Hand-written over a sorted time axis: windows in seconds over uneven
    frame times are not a fixed number of samples, which pandas-free numpy cannot roll."""
    params = params or SignatureParams()
    y = _finite(values)
    n = len(y)
    if times is None or not np.isfinite(_finite(times)).all():
        half = params.window_frames // 2
        lo = np.maximum(np.arange(n) - half, 0)
        hi = np.minimum(np.arange(n) + half + 1, n)
    else:
        t = _finite(times)
        lo = np.searchsorted(t, t - params.window_s / 2, side="left")
        hi = np.searchsorted(t, t + params.window_s / 2, side="right")
    ok = np.isfinite(y)
    zero = np.where(ok, y, 0.0)
    c0 = np.concatenate([[0], np.cumsum(ok)])
    c1 = np.concatenate([[0.0], np.cumsum(zero)])
    c2 = np.concatenate([[0.0], np.cumsum(zero**2)])
    count = (c0[hi] - c0[lo]).astype(np.float64)
    total, squares = c1[hi] - c1[lo], c2[hi] - c2[lo]
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = total / count
        var = np.maximum(squares - count * mean**2, 0.0) / (count - 1)
        cv = np.sqrt(var) / mean
    cv[(count < 3) | ~np.isfinite(cv)] = np.nan
    return np.asarray(cv, dtype=np.float64)


def unstable_stretches(
    cv: ArrayLike, times: ArrayLike | None = None, params: SignatureParams | None = None
) -> list[Stretch]:
    """Runs of consecutive samples whose rolling CV exceeds ``unstable_cv``, at least
    ``min_stretch_frames`` long."""
    params = params or SignatureParams()
    values = _finite(cv)
    over = np.nan_to_num(values, nan=0.0) > params.unstable_cv
    edges = np.flatnonzero(np.diff(np.concatenate([[0], over.astype(np.int8), [0]])))
    t = None if times is None else _finite(times)
    stretches = []
    for start, stop in zip(edges[::2], edges[1::2], strict=True):
        if stop - start < params.min_stretch_frames:
            continue
        end = int(stop - 1)
        stretches.append(
            Stretch(
                int(start),
                end,
                None if t is None or not np.isfinite(t[start]) else float(t[start]),
                None if t is None or not np.isfinite(t[end]) else float(t[end]),
                float(np.nanmax(values[start:stop])),
            )
        )
    return stretches


def run_signature(
    width: ArrayLike,
    length: ArrayLike,
    area: ArrayLike,
    times: ArrayLike | None = None,
    *,
    unit: str = "px",
    params: SignatureParams | None = None,
) -> Signature:
    """The signature of one run from its frames in run order (NaN where a frame has no pool);
    ``times`` in seconds, increasing (None: no oscillation in Hz, windows in frames)."""
    params = params or SignatureParams()
    w = _finite(width)
    if not (len(w) == len(np.asarray(length)) == len(np.asarray(area))):
        raise InvalidInputError("Width, length and area need one value per frame each.")
    t = None if times is None else _finite(times)
    if t is not None:
        if len(t) != len(w):
            raise InvalidInputError("The frame times need one value per frame.")
        if not np.isfinite(t).all() or np.any(np.diff(t) < 0):
            t = None  # a run without a time for every frame, in order, is measured in frames
    cv = rolling_cv(w, t, params)
    return Signature(
        unit=unit,
        frames=len(w),
        measured=int(np.isfinite(w).sum()),
        width=spread(w, t),
        length=spread(length, t),
        area=spread(area, t),
        width_cv=coefficient_of_variation(w),
        oscillation=None if t is None else dominant_oscillation(t, w, params),
        stretches=unstable_stretches(cv, t, params),
        rolling_cv=[None if not math.isfinite(v) else round(float(v), 5) for v in cv],
    )


class RollingStability:
    """The width's rolling coefficient of variation over the last ``window_s`` seconds, one
    frame at a time (the live stream's stability figure; the signature's rule)."""

    def __init__(self, params: SignatureParams | None = None) -> None:
        self.params = params or SignatureParams()
        self._samples: deque[tuple[float, float]] = deque()

    def update(self, time_s: float, width: float | None) -> float | None:
        """Add a frame's width (None: no pool) at ``time_s``; the rolling CV after it (None
        under 3 measured frames in the window)."""
        if width is not None and math.isfinite(width):
            self._samples.append((time_s, float(width)))
        while self._samples and self._samples[0][0] < time_s - self.params.window_s:
            self._samples.popleft()
        if len(self._samples) < 3:
            return None
        values = np.fromiter((w for _, w in self._samples), np.float64)
        mean = float(values.mean())
        return float(values.std(ddof=1) / mean) if mean else None

    def unstable(self, cv: float | None) -> bool:
        return cv is not None and cv > self.params.unstable_cv
