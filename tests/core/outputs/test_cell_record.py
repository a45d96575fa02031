"""The one rule for what a cell reads: millimetres when the run has a scale, keypoints flat."""

from __future__ import annotations

import math

from tests.core.outputs.common import record
from weldpool_core.cell.outputs import CELL_FIELDS, CellInfo, CellRecord


def test_a_scaled_run_gives_millimetres_and_an_unscaled_one_pixels() -> None:
    scaled = CellRecord.of(record(3, width_px=50.0, scaled=True), CellInfo("m", 2, mm_per_px=0.1))
    assert (scaled.width, scaled.length) == (5.0, 8.3)
    assert math.isclose(scaled.area, 4003 * 0.01)
    plain = CellRecord.of(record(3, width_px=50.0), CellInfo("m", 2))
    assert (plain.width, plain.length, plain.area) == (50.0, 83.0, 4003.0)
    assert (plain.cx, plain.cy, plain.frame) == (300.0, 203.0, 3)
    info = CellInfo("m", 2, mm_per_px=0.1)
    units = {spec.name: info.unit(spec) for spec in CELL_FIELDS}
    assert (units["Width"], units["Area"], units["CentroidX"]) == ("mm", "mm²", "px")
    assert CellInfo("m", 2).unit(next(s for s in CELL_FIELDS if s.name == "Area")) == "px²"


def test_keypoints_are_flat_with_nan_for_a_missing_one_and_pairs_in_the_message() -> None:
    cell = CellRecord.of(record(2), CellInfo("m", 2))
    assert cell.keypoints[:2] == (12.0, 20.0)
    assert all(math.isnan(v) for v in cell.keypoints[2:])
    message = cell.message()
    assert message["keypoints"] == [[12.0, 20.0], None]
    assert message["uncertainty"] is None and message["width"] == 50.0
    assert (message["stability_cv"], message["unstable"]) == (0.05, False)
    shaky = CellRecord.of(record(2) | {"stability_cv": 0.12, "unstable": True}, CellInfo("m", 2))
    assert (shaky.message()["stability_cv"], shaky.unstable) == (0.12, True)
    assert set(message) == {spec.key for spec in CELL_FIELDS}


def test_a_model_the_gate_found_unusable_is_not_healthy() -> None:
    assert CellRecord.of(record(1), CellInfo("m", 2)).healthy
    assert not CellRecord.of(record(1), CellInfo("m", 2, model_usable=False)).healthy


def test_a_records_learned_classes_ride_in_the_mqtt_message() -> None:
    geometry = {"wire tip": {"tip": [412.5, 96.0]}, "wire": {"area_px": 830, "centroid": None}}
    cell = CellRecord.of(record(4) | {"classes": geometry}, CellInfo("m", 2))
    assert cell.message()["classes"] == geometry
    assert "classes" not in CellRecord.of(record(4), CellInfo("m", 2)).message()
