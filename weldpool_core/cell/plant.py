"""A simulated weld pool to close a loop on: its width follows travel speed and heat input with a
lag, a PI controller that holds it, and a camera that renders it as synthetic frames.

The plant (``WeldPoolPlant``):

- **Steady width** from Rosenthal's moving point source on a thick plate (Rosenthal 1946, "The
  theory of moving sources of heat and its application to metal treatments", Trans. ASME 68):
  at high Péclet number the melt isotherm's width grows with the square root of the heat input
  per unit length, w ∝ √(P / v) (P the arc power reaching the part, v the travel speed), so
  ``steady_width = width_mm · √((P / P₀) / (v / v₀))`` around a nominal point.
- **Dynamics**: the pool's thermal inertia as a first-order lag (time constant ``tau_s``) after a
  transport delay (``dead_time_s``); identified GTAW/WAAM pool-width models are of this
  first-order-plus-dead-time form with lags of a fraction of a second to a few seconds (e.g.
  Doumanidis & Hardt 1989, J. Dyn. Sys. Meas. Control 111). Defaults: 8 mm at 2 kW and 5 mm/s,
  τ = 0.8 s, 0.1 s delay.

The controller (``PIController``) acts on travel speed: a wider pool than the set point speeds
the torch up. Its default gains follow Skogestad's SIMC rules (Skogestad 2003, J. Process
Control 13) for the plant's gain at the nominal point (∂w/∂v = −w / 2v), its lag and delay plus
one frame of measurement, with a closed-loop time constant of 0.5 s; the speed is clamped to the
robot's range and the integral stops growing while it is clamped (anti-windup).

The camera (``PlantCamera``) draws the plant's width as the steady synthetic pool
(``synth.steady_pool_frame``) scaled by width / nominal width, and knows its millimetres per
pixel from the nominal frame's true mask, so a student's ``width_mm`` is comparable with the
plant's.
"""

from __future__ import annotations

import collections
import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from weldpool_core.errors import InvalidInputError
from weldpool_core.geometry import pool_geometry
from weldpool_core.synth import SynthFrame, SynthParams, steady_pool_frame


@dataclass(frozen=True)
class PlantParams:
    """The nominal working point and the dynamics (see the module doc)."""

    power_w: float = 2000.0
    speed_mm_s: float = 5.0
    width_mm: float = 8.0
    tau_s: float = 0.8
    dead_time_s: float = 0.1

    def steady_width(self, power_w: float, speed_mm_s: float) -> float:
        """The width the pool settles at for this power and speed (mm)."""
        if power_w <= 0 or speed_mm_s <= 0:
            raise InvalidInputError("Arc power and travel speed must be positive.")
        return self.width_mm * math.sqrt((power_w / self.power_w) / (speed_mm_s / self.speed_mm_s))


class WeldPoolPlant:
    """The pool's width over time, stepped at ``dt_s`` (see the module doc)."""

    def __init__(self, params: PlantParams | None = None, dt_s: float = 0.05) -> None:
        self.params = params or PlantParams()
        self.dt_s = dt_s
        self.width_mm = self.params.width_mm
        delay = max(0, round(self.params.dead_time_s / dt_s))
        self._delayed: collections.deque[float] = collections.deque(
            [self.params.width_mm] * delay, maxlen=delay or None
        )
        self._decay = math.exp(-dt_s / self.params.tau_s)

    def step(self, power_w: float, speed_mm_s: float) -> float:
        """Advance one step with this power and speed; the width after it (mm)."""
        target = self.params.steady_width(power_w, speed_mm_s)
        if self._delayed.maxlen:  # what was asked ``dead_time_s`` ago acts now
            acting = self._delayed[0]
            self._delayed.append(target)
            target = acting
        self.width_mm = target + (self.width_mm - target) * self._decay
        return self.width_mm


@dataclass
class PIController:
    """Travel speed from the measured width (see the module doc)."""

    setpoint_mm: float
    kp: float = 1.5
    """mm/s of speed per mm of width error."""
    ki: float = 1.9
    """mm/s per mm·s of integrated error."""
    nominal_speed: float = 5.0
    min_speed: float = 2.0
    max_speed: float = 12.0
    integral: float = field(default=0.0, init=False)

    def update(self, measured_mm: float | None, dt_s: float) -> float:
        """The speed to command now (mm/s); a frame without a pool holds the integral."""
        if measured_mm is None or not math.isfinite(measured_mm):
            return self._clamped(self.nominal_speed + self.ki * self.integral)
        error = measured_mm - self.setpoint_mm
        unclamped = self.nominal_speed + self.kp * error + self.ki * (self.integral + error * dt_s)
        speed = self._clamped(unclamped)
        if speed == unclamped or (unclamped > speed) != (error > 0):  # anti-windup
            self.integral += error * dt_s
        return speed

    def _clamped(self, speed: float) -> float:
        return min(self.max_speed, max(self.min_speed, speed))


class PlantCamera:
    """Frames of the plant's pool (see the module doc)."""

    def __init__(
        self, plant: PlantParams | None = None, seed: int = 3, params: SynthParams | None = None
    ) -> None:
        self.plant = plant or PlantParams()
        self.seed = seed
        self.params = params or SynthParams(width=320, height=200)
        nominal = steady_pool_frame(seed, self.params, 0.0, 1.0)
        width_px = pool_geometry(nominal.mask).width_px
        if not width_px:
            raise InvalidInputError("The synthetic pool has no width at this frame size.")
        self.nominal_width_px = width_px
        self.mm_per_px = self.plant.width_mm / width_px

    def render(self, width_mm: float, time_s: float) -> SynthFrame:
        """The frame at ``time_s`` of a pool ``width_mm`` wide."""
        return steady_pool_frame(self.seed, self.params, time_s, width_mm / self.plant.width_mm)

    def bgr(self, frame: SynthFrame) -> NDArray[np.uint8]:
        """The frame as the stream reads a camera's (H×W×3 BGR uint8)."""
        gray = np.asarray(frame.image, np.uint8)
        return np.ascontiguousarray(np.repeat(gray[:, :, None], 3, axis=2))
