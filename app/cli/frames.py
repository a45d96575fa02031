"""Bulk import of frames and videos from the command line."""

from __future__ import annotations

import contextlib
import dataclasses
import sys
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from app.cli.base import IMAGE_SUFFIXES, friendly_errors, load_settings, main, open_sessions
from app.core.errors import WeldpoolError

if TYPE_CHECKING:
    from app.imports.schemas import ImportOptions

IMPORT_BATCH = 64


def _import_sources(paths: tuple[str, ...]) -> tuple[list[Any], list[Any]]:
    """Split the arguments into image files and video files (directories are listed, sorted)."""

    from weldpool_core.video import sniff_container

    images, videos = [], []
    for argument in paths:
        path = Path(argument)
        if not path.exists():
            raise WeldpoolError(f"{argument} does not exist.")
        candidates = sorted(p for p in path.iterdir() if p.is_file()) if path.is_dir() else [path]
        for candidate in candidates:
            with open(candidate, "rb") as handle:
                is_video = sniff_container(handle.read(16)) is not None
            if is_video:
                videos.append(candidate)
            elif candidate.suffix.lower() in IMAGE_SUFFIXES or not path.is_dir():
                images.append(candidate)
    return images, videos


@contextlib.contextmanager
def _local(paths: tuple[str, ...], settings: Any) -> Iterator[tuple[str, ...]]:
    """The arguments with ``s3://bucket/prefix`` ones copied to a temporary folder first
    (streamed to disk, with WELDPOOL_S3_ENDPOINT_URL and the AWS_* credentials)."""
    if not any(p.startswith("s3://") for p in paths):
        yield paths
        return
    from app.storage import LocalStorage
    from app.storage.s3 import download_prefix, parse_url

    scratch = LocalStorage(settings.home).scratch()  # this machine's
    with tempfile.TemporaryDirectory(prefix="weldpool-bucket-", dir=scratch) as tmp:
        local = []
        for index, path in enumerate(paths):
            if path.startswith("s3://"):
                try:
                    parse_url(path)
                except ValueError as exc:
                    raise WeldpoolError(str(exc).replace("WELDPOOL_STORAGE_URL", path)) from None
                click.echo(f"reading {path}", err=True)
                folder = Path(tmp) / str(index)
                folder.mkdir()
                waits = settings.storage_waits(jobs=True)
                path = str(download_prefix(path, folder, settings.s3_endpoint_url, waits=waits))
            local.append(path)
        yield tuple(local)


def prepare_fresh_home(settings: Any) -> None:
    """A home with no database yet is made ready as `weldpool demo` makes it (migrated, with
    `admin` as the first user), so an import is the first command a new instance may run; a
    database at an older revision still asks for `weldpool migrate`."""
    from app.cli.service import login_hint, prepare_instance
    from app.core.db import create_db_engine, schema_revision

    settings.ensure_home()
    engine = create_db_engine(settings.resolved_database_url)
    try:
        current, _ = schema_revision(engine)
    finally:
        engine.dispose()
    if current is None:
        password_file = prepare_instance(settings)
        if password_file is not None:
            click.echo(f"a fresh home: {login_hint(password_file)}", err=True)


def _bar_progress(bar: Any, total: int) -> Callable[[float, str], None]:
    """A progress callback (fraction, message) that advances a click progress bar."""
    done = 0

    def advance(fraction: float, _message: str) -> None:
        nonlocal done
        now = round(fraction * total)
        bar.update(now - done)
        done = now

    return advance


@main.command("import")
@click.argument("paths", nargs=-1, required=True, type=click.Path())
@click.option(
    "--sequence",
    "sequence_name",
    required=True,
    help="Weld run to import into (created when missing).",
)
@click.option(
    "--every-nth",
    default=1,
    show_default=True,
    type=click.IntRange(min=1),
    help="For videos: keep every n-th frame.",
)
@click.option("--user", "username", default=None, help="Record the frames as this user's.")
@friendly_errors
def import_cmd(
    paths: tuple[str, ...], sequence_name: str, every_nth: int, username: str | None
) -> None:
    """Import frames (PNG, JPEG, TIFF, BMP) and videos (MP4, AVI) from files, directories, or
    a bucket (s3://bucket/prefix: every object under it)."""
    settings = load_settings()
    prepare_fresh_home(settings)
    with _local(paths, settings) as local:
        _import_frames(settings, local, sequence_name, every_nth, username)


def _import_frames(
    settings: Any, paths: tuple[str, ...], sequence_name: str, every_nth: int, username: str | None
) -> None:
    from app.frames import ingest, sequences, videos
    from app.storage import open_storage
    from app.users.service import user_by_name

    images, video_paths = _import_sources(paths)
    if not images and not video_paths:
        raise WeldpoolError("No frames or videos found in the given paths.")
    storage = open_storage(settings)
    stored = duplicates = 0
    rejected: list[str] = []
    with open_sessions(settings)() as session:
        user = user_by_name(session, username) if username else None
        sequence = sequences.sequence_by_name(session, sequence_name, user)
        if images:
            with click.progressbar(length=len(images), label="frames", file=sys.stderr) as bar:
                for start in range(0, len(images), IMPORT_BATCH):
                    chunk = images[start : start + IMPORT_BATCH]
                    files = [ingest.IncomingFile(p.name, p.read_bytes()) for p in chunk]
                    result = ingest.ingest_frames(
                        session,
                        storage,
                        files,
                        sequence_id=sequence.id,
                        user=user,
                        max_pixels=settings.max_image_pixels,
                    )
                    stored += len(result.stored)
                    duplicates += len(result.duplicates)
                    rejected += [f"{r.name}: {r.reason}" for r in result.rejected]
                    bar.update(len(chunk))
        for video_path in video_paths:
            with open(video_path, "rb") as handle:
                video = videos.store_video(
                    session,
                    storage,
                    handle,
                    name=video_path.name,
                    every_nth=every_nth,
                    sequence_id=sequence.id,
                    user=user,
                )
            expected = -(-video.frame_count // every_nth)
            with click.progressbar(length=expected, label=video_path.name, file=sys.stderr) as bar:
                counts = videos.extract_video_frames(
                    session, storage, video, user=user, progress=_bar_progress(bar, expected)
                )
            stored += counts["frames"]
            duplicates += counts["duplicates"]
    for line in rejected:
        click.echo(f"refused {line}", err=True)
    click.echo(
        f"sequence {sequence_name!r}: {stored} frames stored, {duplicates} duplicates, "
        f"{len(rejected)} refused",
        err=True,
    )
    if rejected and not stored and not duplicates:
        sys.exit(2)


@main.command("import-labels")
@click.argument("path")
@click.option(
    "--format",
    "fmt",
    required=True,
    help="coco, yolo, masks, labelme or cvat (weldpool_core.annotations.READERS).",
)
@click.option(
    "--sequence",
    "sequence_name",
    default=None,
    help="Weld run for the new frames (created when missing); default: the runs the file "
    "names, else a new one named after PATH.",
)
@click.option("--overwrite", is_flag=True, help="Add a revision to frames that have a label.")
@click.option("--category", default=None, help="The pool's category name in the file.")
@click.option(
    "--keypoints",
    "keypoint_role",
    type=click.Choice(["validation", "label"]),
    default="validation",
    show_default=True,
    help="What the file's hand-placed pool keypoints become (validation: the frame does not "
    "train).",
)
@click.option(
    "--class-map",
    default=None,
    help="The file's class names as ours, 'theirs=ours,…' (regions of classes the label "
    "configuration has become objects; the others are counted).",
)
@click.option("--user", "username", default=None, help="Import as this user (default: an admin).")
@friendly_errors
def import_labels_cmd(
    path: str,
    fmt: str,
    sequence_name: str | None,
    overwrite: bool,
    category: str | None,
    keypoint_role: str,
    class_map: str | None,
    username: str | None,
) -> None:
    """Import labels made elsewhere: a folder, a zip, or an annotation file beside its images,
    here or in a bucket (s3://bucket/prefix)."""
    from app.imports.schemas import ImportOptions, checked_class_map, checked_format

    settings = load_settings()
    checked_format(fmt)
    options = ImportOptions(
        format=fmt,
        overwrite=overwrite,
        category=category,
        max_pixels=settings.max_image_pixels,
        keypoints=keypoint_role,
        review_stage=settings.review_stage,
        class_map=checked_class_map(class_map),
    )
    prepare_fresh_home(settings)
    with _local((path,), settings) as (local,):
        if not Path(local).exists():
            raise WeldpoolError(f"{path} does not exist.")
        _import_labels(settings, local, options, sequence_name, username)


def _import_labels(
    settings: Any,
    path: str,
    options: ImportOptions,
    sequence_name: str | None,
    username: str | None,
) -> None:
    from app.frames import sequences
    from app.imports.service import import_labels
    from app.storage import open_storage
    from app.users.service import importing_user
    from weldpool_core.annotations import open_source

    with open_sessions(settings)() as session:
        user = importing_user(session, username)
        sequence = (
            sequences.sequence_by_name(session, sequence_name, user) if sequence_name else None
        )
        options = dataclasses.replace(options, sequence_id=sequence.id if sequence else None)
        source = open_source(path)
        try:
            with click.progressbar(length=100, label="labels", file=sys.stderr) as bar:
                report = import_labels(
                    session, open_storage(settings), source, options, user, _bar_progress(bar, 100)
                )
        finally:
            source.close()
    for kind, items in (("skipped", report.skipped), ("refused", report.refused)):
        for item in items:
            click.echo(f"{kind} {item.item}: {item.reason}", err=True)
    click.echo(
        f"{report.labels} labels and {report.keypoints} keypoint sets imported, "
        f"{report.frames} new frames; {len(report.skipped)} skipped, {len(report.refused)} refused",
        err=True,
    )
    if not report.labels and not report.keypoints and report.refused:
        sys.exit(2)
