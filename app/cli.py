"""The ``weldpool`` command line."""

from __future__ import annotations

import functools
import json
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import click
import sqlalchemy as sa
from pydantic import ValidationError

from app.config import Settings, get_settings
from app.db import create_db_engine, create_session_factory, migrate, require_current_schema
from app.errors import WeldpoolError
from app.logs import configure_logging
from app.models import Role

F = TypeVar("F", bound=Callable[..., Any])


def _fail(message: str) -> None:
    click.echo(f"weldpool: {message}", err=True)
    sys.exit(2)


def friendly_errors(func: F) -> F:
    """Turn user-facing errors into one line on stderr and exit status 2."""

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return func(*args, **kwargs)
        except WeldpoolError as exc:
            _fail(exc.message)
        except sa.exc.OperationalError as exc:
            _fail(
                f"The database is unreachable ({str(exc.orig).strip().splitlines()[0]}); "
                "check WELDPOOL_DATABASE_URL."
            )

    return wrapper  # type: ignore[return-value]


def _settings() -> Settings:
    try:
        return get_settings()
    except ValidationError as exc:
        first = exc.errors()[0]
        _fail(f"Bad setting WELDPOOL_{str(first['loc'][0]).upper()}: {first['msg']}.")
        raise  # unreachable


def _sessions(settings: Settings, *, migrated: bool = True) -> Any:
    engine = create_db_engine(settings.resolved_database_url)
    if migrated:
        require_current_schema(engine)
    return create_session_factory(engine)


@click.group()
@click.version_option(package_name="weldpool")
def main() -> None:
    """weldpool: learn the shape of a molten weld pool from camera frames."""
    settings = _settings()
    configure_logging(settings.log_level, settings.log_format)


@main.command("migrate")
@friendly_errors
def migrate_cmd() -> None:
    """Bring the database schema to the newest revision."""
    settings = _settings()
    settings.ensure_home()
    migrate(create_db_engine(settings.resolved_database_url))
    click.echo("database is at the newest revision", err=True)


@main.command()
@click.option("--host", default="127.0.0.1", show_default=True, help="Address to bind.")
@click.option("--port", default=8000, show_default=True, type=int)
@click.option("--no-worker", is_flag=True, help="Run no embedded worker (use `weldpool worker`).")
@friendly_errors
def serve(host: str, port: int, no_worker: bool) -> None:
    """Migrate, then serve the API and the browser UI (with an embedded worker)."""
    import uvicorn

    from app.frames.service import sweep_orphan_files
    from app.main import create_app
    from app.storage import Storage
    from app.users.service import ensure_initial_admin

    settings = _settings()
    settings.ensure_home()
    engine = create_db_engine(settings.resolved_database_url)
    migrate(engine)
    with create_session_factory(engine)() as session:
        password_file = ensure_initial_admin(session, settings.home)
        swept = sweep_orphan_files(session, Storage(settings.home))
    engine.dispose()
    if swept:
        click.echo(
            f"removed {swept} stored files that no row named (an interrupted upload)", err=True
        )
    if password_file:
        click.echo(f"created user 'admin'; its password is in {password_file}", err=True)
    app = create_app(settings, embedded_worker=not no_worker)
    click.echo(f"weldpool serving on http://{host}:{port}", err=True)
    uvicorn.run(app, host=host, port=port, log_config=None, access_log=True)


@main.command()
@click.option("--threads", default=None, type=int, help="Worker threads [WELDPOOL_WORKERS].")
@friendly_errors
def worker(threads: int | None) -> None:
    """A standalone worker on WELDPOOL_QUEUE_URL (stops on Ctrl-C or SIGTERM)."""
    from app.queue import JobQueue, run_standalone_worker

    settings = _settings()
    queue = JobQueue(settings, _sessions(settings))
    run_standalone_worker(queue, threads or settings.workers)


# --- import -----------------------------------------------------------------------------------

IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp"}
IMPORT_BATCH = 64


def _import_sources(paths: tuple[str, ...]) -> tuple[list[Any], list[Any]]:
    """Split the arguments into image files and video files (directories are listed, sorted)."""
    from pathlib import Path

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
    """Import frames (PNG, JPEG, TIFF, BMP) and videos (MP4, AVI) from files or directories."""
    from app.frames import service
    from app.storage import Storage
    from app.users.service import user_by_name

    settings = _settings()
    images, videos = _import_sources(paths)
    if not images and not videos:
        raise WeldpoolError("No frames or videos found in the given paths.")
    storage = Storage(settings.home)
    stored = duplicates = 0
    rejected: list[str] = []
    with _sessions(settings)() as session:
        user = user_by_name(session, username) if username else None
        sequence = service.sequence_by_name(session, sequence_name, user)
        if images:
            with click.progressbar(length=len(images), label="frames", file=sys.stderr) as bar:
                for start in range(0, len(images), IMPORT_BATCH):
                    chunk = images[start : start + IMPORT_BATCH]
                    files = [service.IncomingFile(p.name, p.read_bytes()) for p in chunk]
                    result = service.ingest_frames(
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
        for video_path in videos:
            with open(video_path, "rb") as handle:
                video = service.store_video(
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
                counts = service.extract_video_frames(
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


# --- users and tokens -------------------------------------------------------------------------


@main.group()
def user() -> None:
    """Manage users."""


@user.command("add")
@click.argument("name")
@click.option("--role", type=click.Choice([r.value for r in Role]), required=True)
@click.option("--password-stdin", is_flag=True, help="Read the password from standard input.")
@friendly_errors
def user_add(name: str, role: str, password_stdin: bool) -> None:
    """Add a user; the password comes from a prompt or --password-stdin."""
    from app.users.service import create_user

    if password_stdin:
        password = sys.stdin.readline().rstrip("\r\n")
    else:
        password = click.prompt("Password", hide_input=True, confirmation_prompt=True)
    with _sessions(_settings())() as session:
        created = create_user(session, name, password, Role(role))
    click.echo(f"added user {created.username} ({created.role.value})", err=True)


@user.command("list")
@friendly_errors
def user_list() -> None:
    """List users."""
    from app.users.service import list_users

    with _sessions(_settings())() as session:
        for row in list_users(session):
            state = "" if row.is_active else "  (inactive)"
            click.echo(f"{row.id}\t{row.username}\t{row.role.value}{state}")


@main.command()
@click.argument("name")
@click.option("--label", default="cli", show_default=True, help="A name for the token.")
@friendly_errors
def token(name: str, label: str) -> None:
    """Print a new API token for user NAME (stdout: the token alone)."""
    from app.users.service import create_token, user_by_name

    with _sessions(_settings())() as session:
        _, text = create_token(session, user_by_name(session, name), label)
    click.echo(text)


@main.group()
def tokens() -> None:
    """List and revoke API tokens."""


@tokens.command("list")
@click.argument("name")
@friendly_errors
def tokens_list(name: str) -> None:
    """List user NAME's tokens."""
    from app.users.service import list_tokens, user_by_name

    with _sessions(_settings())() as session:
        for row in list_tokens(session, user_by_name(session, name)):
            state = f"revoked {row.revoked_at:%Y-%m-%d %H:%M}" if row.revoked_at else "active"
            click.echo(f"{row.id}\t{row.prefix}…\t{row.name}\t{state}")


@tokens.command("revoke")
@click.argument("token_id", type=int)
@friendly_errors
def tokens_revoke(token_id: int) -> None:
    """Revoke token TOKEN_ID."""
    from app.users.service import revoke_token

    with _sessions(_settings())() as session:
        revoke_token(session, token_id, actor=None)
    click.echo(f"revoked token {token_id}", err=True)


# --- teacher weights --------------------------------------------------------------------------


@main.group()
def weights() -> None:
    """Download and check the teacher's model weights."""


def _weights_refs(settings: Settings) -> list[tuple[str, str]]:
    return [(settings.dino, "WELDPOOL_DINO"), (settings.sam2, "WELDPOOL_SAM2")]


@weights.command("status")
@friendly_errors
def weights_status_cmd() -> None:
    """Report where the teacher weights are; exit 2 when any is missing."""
    from weldpool_core.teacher.weights import weights_status

    statuses = [weights_status(ref, var) for ref, var in _weights_refs(_settings())]
    click.echo(json.dumps([s.as_dict() for s in statuses], indent=2))
    missing = [s for s in statuses if not s.available]
    if missing:
        _fail(missing[0].detail)


@weights.command("fetch")
@friendly_errors
def weights_fetch() -> None:
    """Download the teacher weights into the Hugging Face cache (needs internet)."""
    from weldpool_core.teacher.weights import fetch_weights

    for ref, var in _weights_refs(_settings()):
        status = fetch_weights(ref, var)
        click.echo(f"{ref}: {status.detail} ({status.path})", err=True)


# --- heatmaps and evaluation ----------------------------------------------------------------
# Masks are PNG files (0 / 255). A file `<stem>_mask.png` (what `teacher` and `predict` write)
# counts as the mask of `<stem>`, so outputs and ground truth line up by stem. A folder holding a
# `masks/` (or `keypoints/`) subfolder is read as a DATASET folder.


def _stem(path: Path) -> str:
    return path.stem.removesuffix("_mask")


def _input_masks(inputs: tuple[str, ...]) -> list[Path]:
    """The PNG masks named on the command line, folders expanded (sorted by name)."""
    paths: list[Path] = []
    for text in inputs:
        path = Path(text)
        if path.is_dir():
            found = sorted(p for p in path.iterdir() if p.suffix.lower() == ".png")
            if not found:
                _fail(f"The folder {path} holds no PNG mask.")
            paths.extend(found)
        elif path.is_file():
            paths.append(path)
        else:
            _fail(f"{path} does not exist; give PNG mask files or folders of them.")
    stems = [_stem(p) for p in paths]
    twice = sorted({s for s in stems if stems.count(s) > 1})
    if twice:
        _fail(f"Several masks would write outputs named {twice[0]!r}; give each mask its own stem.")
    return paths


def _part(folder: Path, part: str) -> Path:
    """``folder/part`` when ``folder`` is a DATASET folder, else ``folder`` itself."""
    if not folder.is_dir():
        _fail(f"{folder} is not a folder.")
    return folder / part if (folder / part).is_dir() else folder


@main.command("heatmap")
@click.argument("masks", nargs=-1, required=True)
@click.option("--out", "out_dir", required=True, type=click.Path(file_okay=False, path_type=Path))
@click.option("--k", default=4, show_default=True, type=int, help="Keypoints per mask.")
@friendly_errors
def heatmap_cmd(masks: tuple[str, ...], out_dir: Path, k: int) -> None:
    """Algorithm 1 on binary PNG masks (files or folders).

    Writes per mask <stem>_heatmap.npy (H×W×2 float32: heatmap, mask) and <stem>.json
    ({"keypoints": [[x, y], …], "rules": […]}); a mask named <stem>_mask.png gives <stem>.
    """
    import numpy as np

    from weldpool_core.errors import InvalidInputError
    from weldpool_core.heatmap import HeatmapParams, heatmap_from_mask
    from weldpool_core.io import read_mask

    params = HeatmapParams(k=k)
    paths = _input_masks(masks)
    out_dir.mkdir(parents=True, exist_ok=True)
    for path in paths:
        try:
            result = heatmap_from_mask(read_mask(path), params)
        except InvalidInputError as exc:
            raise InvalidInputError(f"{path}: {exc.message}") from None
        stem = _stem(path)
        np.save(out_dir / f"{stem}_heatmap.npy", result.heatmap)
        height, width = result.heatmap.shape[:2]
        record = {
            "keypoints": result.keypoints.tolist(),
            "rules": list(result.rules),
            "width": width,
            "height": height,
            "mask": str(path),
        }
        (out_dir / f"{stem}.json").write_text(json.dumps(record, indent=2) + "\n")
    click.echo(f"wrote {len(paths)} heatmap(s) to {out_dir}", err=True)


@main.group("eval")
def eval_group() -> None:
    """Score predictions against ground truth; JSON on stdout."""


@eval_group.command("segmentation")
@click.option("--pred", "pred_dir", required=True, type=click.Path(path_type=Path))
@click.option("--gt", "gt_dir", required=True, type=click.Path(path_type=Path))
@friendly_errors
def eval_segmentation(pred_dir: Path, gt_dir: Path) -> None:
    """IoU per frame, mIoU and quartiles (fractions in [0, 1]).

    Ground truth: <stem>.png in --gt (or its masks/). Prediction: <stem>_mask.png or <stem>.png
    in --pred (or its masks/). A missing prediction scores as an empty mask and is listed.
    """
    import numpy as np

    from weldpool_core.errors import InvalidInputError
    from weldpool_core.io import read_mask
    from weldpool_core.metrics import iou, segmentation_scores

    truth_dir, predicted_dir = _part(gt_dir, "masks"), _part(pred_dir, "masks")
    truths = {_stem(p): p for p in sorted(truth_dir.glob("*.png"))}
    if not truths:
        _fail(f"{truth_dir} holds no ground-truth mask (<stem>.png).")
    per_image: dict[str, float] = {}
    missing: list[str] = []
    for stem, truth_path in truths.items():
        candidates = [predicted_dir / f"{stem}_mask.png", predicted_dir / f"{stem}.png"]
        found = next((c for c in candidates if c.is_file()), None)
        try:
            truth = read_mask(truth_path)
            predicted = read_mask(found) if found else np.zeros_like(truth)
            per_image[stem] = iou(predicted, truth)
        except InvalidInputError as exc:
            raise InvalidInputError(f"{stem}: {exc.message}") from None
        if found is None:
            missing.append(stem)
    if len(missing) == len(truths):
        _fail(f"{predicted_dir} holds no prediction for the masks in {truth_dir} "
              "(expected <stem>_mask.png or <stem>.png).")  # fmt: skip
    report = segmentation_scores(per_image).as_dict() | {"missing": missing}
    click.echo(json.dumps(report, indent=2))


def _keypoint_file(path: Path) -> list[Any]:
    from weldpool_core.errors import InvalidInputError

    try:
        keypoints = json.loads(path.read_text())["keypoints"]
        if not isinstance(keypoints, list):
            raise TypeError
    except (OSError, ValueError, KeyError, TypeError):
        raise InvalidInputError(
            f'{path} is not a keypoints file; expected {{"keypoints": [[x, y], …]}}.'
        ) from None
    return keypoints


@eval_group.command("keypoints")
@click.option("--pred", "pred_dir", required=True, type=click.Path(path_type=Path))
@click.option("--gt", "gt_dir", required=True, type=click.Path(path_type=Path))
@click.option(
    "--matching",
    type=click.Choice(["hungarian", "order"]),
    default="hungarian",
    show_default=True,
    help="Pair keypoints by least distance, or by position.",
)
@friendly_errors
def eval_keypoints(pred_dir: Path, gt_dir: Path, matching: str) -> None:
    """mED, mED_k and std in pixels, and the distances per frame.

    Ground truth: <stem>.json in --gt (or its keypoints/); prediction: <stem>.json in --pred. A
    missing prediction counts as empty: its keypoints are missed, and it is listed.
    """
    from weldpool_core.metrics import keypoint_scores

    truth_dir, predicted_dir = _part(gt_dir, "keypoints"), _part(pred_dir, "keypoints")
    truths = {p.stem: p for p in sorted(truth_dir.glob("*.json"))}
    if not truths:
        _fail(f"{truth_dir} holds no ground-truth keypoints (<stem>.json).")
    pairs: dict[str, tuple[list[Any], list[Any]]] = {}
    missing: list[str] = []
    for stem, truth_path in truths.items():
        predicted_path = predicted_dir / f"{stem}.json"
        if not predicted_path.is_file():
            missing.append(stem)
        predicted = _keypoint_file(predicted_path) if predicted_path.is_file() else []
        pairs[stem] = (predicted, _keypoint_file(truth_path))
    if len(missing) == len(truths):
        _fail(f"{predicted_dir} holds no prediction for the keypoints in {truth_dir} "
              "(expected <stem>.json).")  # fmt: skip
    scores = keypoint_scores(pairs, matching="order" if matching == "order" else "hungarian")
    click.echo(json.dumps(scores.as_dict() | {"missing": missing}, indent=2))
