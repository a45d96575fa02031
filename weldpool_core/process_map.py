"""The process map: runs' signature figures against their process parameters, and the law that
joins them.

- **Derived parameters** (``derived_parameters``): the arc energy per unit length
  ``heat_input_j_mm = U·I / v`` (no arc efficiency: it is a process constant that moves ``a``,
  never the exponent), and ``wire_per_travel`` (wire fed per length of weld: wire feed over
  travel speed, both in m/min).
- **The fit** (``power_fit``): y = a·x^b by least squares on log x, log y
  (``scipy.stats.linregress``), with the 95 % confidence interval of b from Student's t on
  n − 2 degrees of freedom and R² in log space. Rosenthal's moving source predicts width ∝
  √(heat input) (b = 0.5); a line through the origin is b = 1.
- **Outliers**: a run whose log residual is over ``outlier_sigma`` robust standard deviations
  (1.4826 · median absolute residual) *and* over ``min_off`` (a relative distance: runs a few
  % apart on a near-perfect law are not outliers) is flagged; the law is then fitted again
  without the flagged runs and every run is judged again against it, until the flags settle —
  so one far-off run neither bends the law nor drags good runs out with it. Defaults: 3 σ, 5 %.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import numpy as np
    from numpy.typing import ArrayLike
else:
    from weldpool_core.lazy import np

PARAMETERS = (
    "voltage_v",
    "current_a",
    "wire_feed_m_min",
    "robot_speed_cm_min",
    "arc_length_correction_pct",
)
"""A run's process parameters (the paper's Table I), by their stored names."""
DERIVED = ("heat_input_j_mm", "wire_per_travel")
"""Parameters computed from the others (``derived_parameters``)."""


def derived_parameters(params: dict[str, Any]) -> dict[str, float | None]:
    """``heat_input_j_mm`` (U·I/v, J/mm, with v in cm/min turned to mm/s) and
    ``wire_per_travel`` (wire feed m/min over travel speed m/min); None where a parameter is
    missing or the speed is not positive."""
    volts, amps = params.get("voltage_v"), params.get("current_a")
    speed, wire = params.get("robot_speed_cm_min"), params.get("wire_feed_m_min")
    heat = per_travel = None
    if speed is not None and speed > 0:
        if volts is not None and amps is not None:
            heat = float(volts) * float(amps) / (float(speed) * 10.0 / 60.0)
        if wire is not None:
            per_travel = float(wire) / (float(speed) / 100.0)
    return {"heat_input_j_mm": heat, "wire_per_travel": per_travel}


@dataclass(frozen=True)
class PowerFit:
    """y = a·x^b over ``n`` runs (module doc)."""

    a: float
    b: float
    b_low: float
    b_high: float
    """The 95 % confidence interval of b (NaN-free: ±inf under 3 runs)."""
    r2: float
    n: int
    excluded: list[int] = field(default_factory=list)
    """Positions of the runs flagged as outliers and left out of this fit."""
    kind: str = "power"

    def predict(self, x: ArrayLike) -> Any:
        return self.a * np.asarray(x, dtype=np.float64) ** self.b

    def as_dict(self) -> dict[str, Any]:
        out = asdict(self)
        for key in ("b_low", "b_high"):
            out[key] = out[key] if math.isfinite(out[key]) else None
        return out


def _log_fit(lx: Any, ly: Any) -> tuple[float, float, float, float]:
    """log a, b, R² and the half width of b's 95 % interval, on logs."""
    from scipy import stats

    if len(lx) < 2 or np.ptp(lx) == 0:
        raise ValueError("a power law needs two runs at different x")
    fit = stats.linregress(lx, ly)
    r2 = float(fit.rvalue**2) if np.ptp(ly) > 0 else 1.0
    half = float(stats.t.ppf(0.975, len(lx) - 2) * fit.stderr) if len(lx) > 2 else math.inf
    return float(fit.intercept), float(fit.slope), r2, half


MAX_ROUNDS = 10
"""Fits and flags in turn until the flags settle (they do in two or three rounds)."""


def _outliers(lx: Any, ly: Any, off: Any, sigmas: float, min_off: float) -> Any:
    """The runs off the law fitted on the others (``off``: flagged so far): their log residual
    over ``sigmas`` robust standard deviations of the others' and over ``min_off``."""
    log_a, b, _, _ = _log_fit(lx[~off], ly[~off])
    residual = ly - (log_a + b * lx)
    inside = residual[~off]
    sigma = 1.4826 * float(np.median(np.abs(inside - np.median(inside))))
    flagged = (np.abs(residual) > sigmas * sigma) & (np.abs(residual) > math.log1p(min_off))
    if len(lx) - int(flagged.sum()) < 2 or np.ptp(lx[~flagged]) == 0:
        return np.zeros(len(lx), bool)
    return flagged


def power_fit(
    x: ArrayLike,
    y: ArrayLike,
    *,
    outlier_sigma: float = 3.0,
    min_off: float = 0.05,
) -> tuple[PowerFit | None, list[bool]]:
    """The power law through the runs with positive x and y, and per run whether it is an
    outlier (module doc). None (and no outliers) under two usable runs at different x."""
    xs, ys = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    usable = np.isfinite(xs) & np.isfinite(ys) & (xs > 0) & (ys > 0)
    index = np.flatnonzero(usable)
    flags = [False] * len(xs)
    if len(index) < 2 or np.ptp(xs[index]) == 0:
        return None, flags
    lx, ly = np.log(xs[index]), np.log(ys[index])
    off = np.zeros(len(index), bool)
    for _ in range(MAX_ROUNDS):
        flagged = _outliers(lx, ly, off, outlier_sigma, min_off)
        if np.array_equal(flagged, off):
            break
        off = flagged
    for position in index[off]:
        flags[int(position)] = True
    log_a, b, r2, half = _log_fit(lx[~off], ly[~off])
    fit = PowerFit(
        a=math.exp(log_a),
        b=b,
        b_low=b - half,
        b_high=b + half,
        r2=r2,
        n=int((~off).sum()),
        excluded=[int(p) for p in index[off]],
    )
    return fit, flags


def residual_pct(fit: PowerFit | None, x: float | None, y: float | None) -> float | None:
    """How far a run lies from the law, in % of the law's value there."""
    if fit is None or x is None or y is None or x <= 0:
        return None
    expected = float(fit.predict(x))
    return 100.0 * (y - expected) / expected if expected else None
