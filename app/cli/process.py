"""`weldpool process-map`: the process map for scripts (JSON, or CSV with ``--csv``)."""

from __future__ import annotations

import json
import sys
from typing import get_args

import click

from app.cli.base import friendly_errors, load_settings, main, open_sessions


@main.command("process-map")
@click.option("--x", "x", default="heat_input_j_mm", show_default=True, type=click.Choice(
    ["voltage_v", "current_a", "wire_feed_m_min", "robot_speed_cm_min",
     "arc_length_correction_pct", "heat_input_j_mm", "wire_per_travel"]))  # fmt: skip
@click.option("--y", "y", default="width_mm", show_default=True, type=click.Choice(
    ["width_mm", "length_mm", "area_mm2", "width_iqr_mm", "length_iqr_mm", "area_iqr_mm2",
     "width_cv", "oscillation_hz", "oscillation_strength", "unstable_frames"]))  # fmt: skip
@click.option("--color", default=None, help="A third name (x or y), as each run's colour column.")
@click.option("--csv", "as_csv", is_flag=True, help="CSV on stdout instead of JSON.")
@friendly_errors
def process_map_cmd(x: str, y: str, color: str | None, as_csv: bool) -> None:
    """Every weld run as a point, X (a process parameter or heat_input_j_mm = U·I/v) against Y
    (a figure of its signature), with the power law y = a·x^b through them and the runs far from
    it flagged: what GET /api/v1/process-map answers. Signatures of runs whose labels or
    proposals changed are measured again first."""
    from app.process.service import XName, YName, map_csv, process_map
    from app.storage import open_storage

    if color is not None and color not in (*get_args(XName), *get_args(YName)):
        raise click.BadParameter(f"{color!r} is neither an x nor a y name.", param_hint="--color")
    settings = load_settings()
    with open_sessions(settings)() as session:
        result = process_map(session, open_storage(settings), x, y, color)
    click.echo(map_csv(result) if as_csv else json.dumps(result, indent=2), nl=not as_csv)
    sys.exit(0)
