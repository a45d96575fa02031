"""The process map: one point per weld run — a process parameter (or a derived one) against a
figure of its stored signature — with the power law through them and the runs far from it
(``weldpool_core.process_map``).

Figures in mm are only compared between runs that have a scale: a run without one measures in
pixels, and is listed under ``skipped`` with that reason instead of being drawn among mm.
"""

from __future__ import annotations

import csv
import io
from typing import Any, Literal

import sqlalchemy as sa
from sqlalchemy.orm import Session

from app.core.models import RunSignature, Sequence
from app.process.signatures import fresh_signatures
from app.storage import Storage
from weldpool_core.process_map import DERIVED, PARAMETERS, derived_parameters, power_fit
from weldpool_core.process_map import residual_pct as off_law

XName = Literal[
    "voltage_v",
    "current_a",
    "wire_feed_m_min",
    "robot_speed_cm_min",
    "arc_length_correction_pct",
    "heat_input_j_mm",
    "wire_per_travel",
]
YName = Literal[
    "width_mm",
    "length_mm",
    "area_mm2",
    "width_iqr_mm",
    "length_iqr_mm",
    "area_iqr_mm2",
    "width_cv",
    "oscillation_hz",
    "oscillation_strength",
    "unstable_frames",
]
X_NAMES: tuple[str, ...] = (*PARAMETERS, *DERIVED)
Y_FIGURES: dict[str, tuple[str, str | None]] = {
    "width_mm": ("width", "mm"),
    "length_mm": ("length", "mm"),
    "area_mm2": ("area", "mm"),
    "width_iqr_mm": ("width_iqr", "mm"),
    "length_iqr_mm": ("length_iqr", "mm"),
    "area_iqr_mm2": ("area_iqr", "mm"),
    "width_cv": ("width_cv", None),
    "oscillation_hz": ("oscillation_hz", None),
    "oscillation_strength": ("oscillation_strength", None),
    "unstable_frames": ("unstable_frames", None),
}
"""A map's y name → the signature's figure and the unit it needs (None: unitless)."""
LABELS = {
    "voltage_v": "voltage (V)",
    "current_a": "current (A)",
    "wire_feed_m_min": "wire feed (m/min)",
    "robot_speed_cm_min": "travel speed (cm/min)",
    "arc_length_correction_pct": "arc length correction (%)",
    "heat_input_j_mm": "heat input U·I/v (J/mm)",
    "wire_per_travel": "wire per travel (m/m)",
    "width_mm": "width, median (mm)",
    "length_mm": "length, median (mm)",
    "area_mm2": "area, median (mm²)",
    "width_iqr_mm": "width IQR (mm)",
    "length_iqr_mm": "length IQR (mm)",
    "area_iqr_mm2": "area IQR (mm²)",
    "width_cv": "width CV",
    "oscillation_hz": "oscillation (Hz)",
    "oscillation_strength": "oscillation strength",
    "unstable_frames": "unstable frames",
}
"""Axis titles, with units (the page and the CSV's readers see these)."""

_SIGNATURE_COLUMNS = [
    column
    for column in RunSignature.__table__.columns
    if column.name not in ("detail", "id", "sequence_id", "computed_at", "policy_source")
]
"""What the map reads of a signature: the figures (not the detail, nor the time it was made:
converting 1,000 timestamps alone costs a third of the map)."""
_RUN_COLUMNS = [Sequence.id, Sequence.name] + [getattr(Sequence, p) for p in PARAMETERS]


def _run_values(row: Any) -> dict[str, Any]:
    """Every x and y name of one run (None where it has no value)."""
    values: dict[str, Any] = {p: getattr(row, p) for p in PARAMETERS}
    values |= derived_parameters(values)
    for name in ("width", "length", "area"):
        q1, q3 = getattr(row, f"{name}_q1"), getattr(row, f"{name}_q3")
        values[name] = getattr(row, name)
        values[f"{name}_q1"], values[f"{name}_q3"] = q1, q3
        values[f"{name}_iqr"] = None if q1 is None or q3 is None else q3 - q1
    for name in ("width_cv", "oscillation_hz", "oscillation_strength", "unstable_frames"):
        values[name] = getattr(row, name)
    return values


def _value(values: dict[str, Any], name: str, unit: str) -> tuple[Any, str | None]:
    """A name's value for one run, or why the run cannot show it."""
    if name in X_NAMES:
        value = values[name]
        return value, None if value is not None else f"it has no {LABELS[name]}"
    figure, needs = Y_FIGURES[name]
    if needs == "mm" and unit != "mm":
        return None, "it has no scale: its geometry is in px"
    value = values[figure]
    return value, None if value is not None else f"its signature has no {LABELS[name]}"


def _point(row: Any, x: str, y: str, color: str | None) -> tuple[dict[str, Any] | None, str]:
    values = _run_values(row)
    xv, why_x = _value(values, x, row.unit)
    yv, why_y = _value(values, y, row.unit)
    if why_x or why_y:
        return None, str(why_x or why_y)
    figure = Y_FIGURES[y][0]
    cv = _value(values, color, row.unit)[0] if color else None
    return {
        "sequence_id": row.id,
        "name": row.name,
        "x": xv,
        "y": yv,
        "y_q1": values.get(f"{figure}_q1"),
        "y_q3": values.get(f"{figure}_q3"),
        "color": cv,
        "unit": row.unit,
        "stale": row.stale,
        "unstable_frames": row.unstable_frames,
        "first_unstable_frame_id": row.first_unstable_frame_id,
        "outlier": False,
        "residual_pct": None,
    }, ""


def process_map(
    session: Session, storage: Storage, x: str, y: str, color: str | None = None
) -> dict[str, Any]:
    """The map of every run (module doc): points, skipped runs with their reason, the fit."""
    fresh_signatures(session, storage)
    rows = session.execute(
        sa.select(*_RUN_COLUMNS, *_SIGNATURE_COLUMNS)
        .join(RunSignature, RunSignature.sequence_id == Sequence.id)
        .order_by(Sequence.id)
    ).all()
    points, skipped = [], []
    for row in rows:
        point, why = _point(row, x, y, color)
        if point is None:
            skipped.append({"sequence_id": row.id, "name": row.name, "reason": why})
        else:
            points.append(point)
    fit, flags = power_fit([p["x"] for p in points], [p["y"] for p in points])
    for point, flag in zip(points, flags, strict=True):
        point["outlier"] = flag
        point["residual_pct"] = off_law(fit, point["x"], point["y"])
    return {
        "x": x,
        "y": y,
        "color": color,
        "labels": {n: LABELS[n] for n in (x, y, color) if n},
        "points": points,
        "skipped": skipped,
        "fit": fit.as_dict() if fit is not None else None,
    }


CSV_COLUMNS = ("sequence_id", "name", "x", "y", "y_q1", "y_q3", "color", "unit", "outlier")


def map_csv(result: dict[str, Any]) -> str:
    """The map's points as CSV: the x, y and colour columns carry their names; the last
    column is each run's distance from the law in %."""
    out = io.StringIO()
    writer = csv.writer(out)
    names = {"x": result["x"], "y": result["y"], "color": result["color"] or "color"}
    writer.writerow([names.get(c, c) for c in CSV_COLUMNS] + ["residual_pct"])
    for point in result["points"]:
        cells = [point[c] for c in CSV_COLUMNS] + [point["residual_pct"]]
        writer.writerow(["" if v is None else _cell(v) for v in cells])
    return out.getvalue()


def _cell(value: Any) -> Any:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return f"{value:.6g}"
    return value
