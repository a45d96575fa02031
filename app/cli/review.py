"""The review loop from the command line: export of the reviewed labels, and the demo."""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import click

from app.cli.base import friendly_errors, load_settings, main, open_sessions
from app.core.errors import WeldpoolError


@main.command("export")
@click.option(
    "--format",
    "fmt",
    type=click.Choice(["coco", "masks", "yolo", "cvat", "labelme"]),
    default="masks",
    show_default=True,
    help="COCO, the DATASET layout `weldpool train` reads (masks), YOLO, CVAT or LabelMe.",
)
@click.option(
    "--out",
    "out_path",
    required=True,
    type=click.Path(dir_okay=False, path_type=Path),
    help="The zip file to write.",
)
@click.option("--sequence", "sequence_name", default=None, help="Only this weld run.")
@click.option("--split", type=click.Choice(["train", "validation", "test"]), default=None)
@friendly_errors
def export_cmd(fmt: str, out_path: Path, sequence_name: str | None, split: str | None) -> None:
    """Export the accepted and corrected labels as a zip."""
    import sqlalchemy as sa

    from app.core.models import Sequence, Split
    from app.review.export import build_export
    from app.storage import open_storage

    settings = load_settings()
    skipped: list[tuple[int, str]] = []
    with open_sessions(settings)() as session:
        sequence_id = None
        if sequence_name:
            sequence_id = session.scalar(
                sa.select(Sequence.id).where(Sequence.name == sequence_name)
            )
            if sequence_id is None:
                raise WeldpoolError(f"There is no sequence named {sequence_name!r}.")
        temporary = build_export(
            session,
            open_storage(settings),
            fmt,  # type: ignore[arg-type]
            sequence_id=sequence_id,
            split=Split(split) if split else None,
            skipped=skipped,
        )
    out_path.parent.mkdir(parents=True, exist_ok=True)
    shutil.move(temporary, out_path)
    for _, reason in skipped:
        click.echo(f"left out: {reason}", err=True)
    click.echo(f"wrote {out_path}", err=True)


@main.command("demo")
@click.option("--frames", default=24, show_default=True, type=click.IntRange(4, 500))
@click.option("--seed", default=0, show_default=True, type=int)
@click.option(
    "--process-frames",
    default=45,
    show_default=True,
    type=click.IntRange(0, 500),
    help="Frames of each process-map run at 15 fps (0: no process runs).",
)
@friendly_errors
def demo_cmd(frames: int, seed: int, process_frames: int) -> None:
    """Fill this instance with a synthetic weld run, so the whole loop shows at once.

    Works on a fresh home: the database is migrated and, when there is no user yet, ``admin`` is
    created with its password in WELDPOOL_HOME/initial-admin-password (printed at the end).

    Frames come from weldpool_core.synth; half of them get labels from the generator's ground
    truth (user `demo`, status accepted) and a few get manual validation keypoints, so the
    student can be trained at once; the rest wait in the review queue. When the teacher's
    weights are present, a teacher job is queued for the unlabelled frames.

    Before it, six runs at heat inputs from 360 to 1110 J/mm are filled from the simulated
    plant (weldpool_core.cell.plant), one of them oscillating at 3 Hz, for the process map
    (/process).
    """
    from app.cli.service import login_hint, prepare_instance
    from app.demo import fill_demo, fill_process_runs

    settings = load_settings()
    password_file = prepare_instance(settings)  # a fresh home needs no `weldpool migrate`
    progress = lambda text: click.echo(text, err=True)  # noqa: E731
    with open_sessions(settings)() as session:
        runs = ""
        if process_frames:
            runs = fill_process_runs(session, settings, frames=process_frames, progress=progress)
        summary = fill_demo(
            session,
            settings,
            frames=frames,
            seed=seed,
            progress=progress,
        )
    click.echo(summary + runs, err=True)
    click.echo("Start it with `weldpool serve`, then:", err=True)
    click.echo(login_hint(password_file), err=True)
    sys.exit(0)
