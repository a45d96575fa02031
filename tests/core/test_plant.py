"""The simulated weld pool a loop closes on: Rosenthal's √(P/v) width, a first-order lag after
a delay, a PI controller that holds the width through a heat-input step, and the camera."""

from __future__ import annotations

import math

import pytest

from weldpool_core.cell.plant import PIController, PlantCamera, PlantParams, WeldPoolPlant
from weldpool_core.errors import InvalidInputError
from weldpool_core.geometry import pool_geometry


def test_the_steady_width_grows_with_the_root_of_heat_input_per_length() -> None:
    plant = PlantParams()
    assert plant.steady_width(2000, 5) == pytest.approx(8.0)
    assert plant.steady_width(4000, 5) == pytest.approx(8.0 * math.sqrt(2))  # more power: wider
    assert plant.steady_width(2000, 10) == pytest.approx(8.0 / math.sqrt(2))  # faster: narrower
    assert plant.steady_width(4000, 10) == pytest.approx(8.0)  # the same heat per millimetre
    with pytest.raises(InvalidInputError, match="must be positive"):
        plant.steady_width(2000, 0)


def test_a_step_shows_after_the_delay_and_reaches_63_percent_one_lag_later() -> None:
    plant = WeldPoolPlant(PlantParams(tau_s=0.8, dead_time_s=0.1), dt_s=0.01)
    target = PlantParams().steady_width(2000 * 1.44, 5)  # 9.6 mm
    widths = [plant.step(2000 * 1.44, 5) for _ in range(400)]
    assert widths[9] == 8.0 < widths[10]  # the 0.1 s transport delay is 10 steps of 10 ms
    at_lag = widths[round((0.1 + 0.8) / 0.01) - 1]
    assert (at_lag - 8.0) / (target - 8.0) == pytest.approx(1 - math.exp(-1), abs=0.02)
    assert widths[-1] == pytest.approx(target, rel=0.01)


def _loop(controlled: bool, ki: float = 1.9, kp: float = 1.5) -> list[tuple[float, float]]:
    """20 Hz for 15 s, +30 % heat input from 4 s; the controller sees the previous frame."""
    dt = 0.05
    plant, controller = WeldPoolPlant(dt_s=dt), PIController(8.0, kp=kp, ki=ki)
    speed, measured, trace = 5.0, 8.0, []
    for step in range(300):
        t = step * dt
        if controlled:
            speed = controller.update(measured, dt)
        measured = plant.step(2000 * (1.3 if t >= 4 else 1.0), speed)
        trace.append((t, measured))
    return trace


def test_the_controller_holds_the_width_through_a_heat_input_step() -> None:
    settled = [w for t, w in _loop(True) if t >= 8]
    assert max(abs(w - 8.0) / 8.0 for w in settled) < 0.01
    open_loop = [w for t, w in _loop(False) if t >= 8]
    assert open_loop[-1] == pytest.approx(8.0 * math.sqrt(1.3), rel=0.01)  # +14 %: uncontrolled
    proportional = [w for t, w in _loop(True, ki=0.0) if t >= 8]  # no integral: an offset stays
    assert abs(proportional[-1] - 8.0) / 8.0 > 0.05
    assert max(w for _t, w in _loop(True)) < 8.0 * 1.08  # the overshoot of the disturbance


def test_the_controller_clamps_speed_and_does_not_wind_up() -> None:
    controller = PIController(8.0, max_speed=6.0)
    for _ in range(200):
        assert controller.update(12.0, 0.05) == 6.0
    assert controller.integral < 1.0  # it did not integrate while clamped
    assert controller.update(7.5, 0.05) < 6.0  # so it leaves the clamp at once


def test_the_camera_draws_the_plants_width_in_its_millimetres() -> None:
    camera = PlantCamera()
    nominal = pool_geometry(camera.render(8.0, 0.0).mask).width_px
    wide = pool_geometry(camera.render(9.6, 0.0).mask).width_px
    assert wide / nominal == pytest.approx(1.2, rel=0.02)
    assert wide * camera.mm_per_px == pytest.approx(9.6, rel=0.02)
    later = camera.render(8.0, 1.0)
    assert (later.image != camera.render(8.0, 0.0).image).any()  # noise and ripples move
    assert (later.mask == camera.render(8.0, 0.0).mask).all()  # the pool does not
