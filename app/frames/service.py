"""Sequences, frame ingest and videos: every file is checked, decoded once, stored by content
hash and recorded atomically (files first, then one commit; a failed commit removes the files).
"""

from __future__ import annotations

import hashlib
import os
import re
import threading
from collections.abc import Callable, Iterable
from collections.abc import Sequence as Seq
from concurrent.futures import Future, ThreadPoolExecutor, wait
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, BinaryIO, Literal

import sqlalchemy as sa
from sqlalchemy.orm import Session, undefer

from app.bounds import MAX_MM_PER_PX
from app.db import commit_or_conflict
from app.errors import ConflictError, InvalidInputError, NotFoundError
from app.models import (
    STORED_PATH_COLUMNS,
    UNREVIEWED_SQL,
    Frame,
    FrameStatus,
    Label,
    LabelRevision,
    Proposal,
    Sequence,
    Split,
    User,
    ValidationKeypoints,
    Video,
)
from app.proposals.policy import pick
from app.proposals.queue import diverse_head
from app.storage import StagedFile, Storage, StoredFile
from weldpool_core.geometry import scale_from_points
from weldpool_core.io import (
    EXTENSIONS,
    MEDIA_TYPES,
    ImageInfo,
    check_image,
    encode_png,
    read_image,
)
from weldpool_core.video import probe_video, sniff_container

_BAD_NAME = re.compile(r"[/\\\x00-\x1f]")
_POOL = ThreadPoolExecutor(max_workers=max(2, os.cpu_count() or 2), thread_name_prefix="ingest")
_DISK = ThreadPoolExecutor(max_workers=8, thread_name_prefix="ingest-disk")
"""Writes and fsyncs wait on the disk, not a core: their own threads keep the checks going
and let the disk queue several flushes at once."""


# --- sequences ---------------------------------------------------------------------------------


def create_sequence(session: Session, values: dict[str, Any], user: User | None) -> Sequence:
    """A new weld run; names are unique."""
    if session.scalar(sa.select(Sequence.id).where(Sequence.name == values["name"])):
        raise ConflictError(f"There is already a sequence named {values['name']!r}.")
    sequence = Sequence(**values, created_by_id=user.id if user else None)
    session.add(sequence)
    commit_or_conflict(session, f"There is already a sequence named {values['name']!r}.")
    return sequence


def get_sequence(session: Session, sequence_id: int) -> Sequence:
    sequence = session.get(Sequence, sequence_id)
    if sequence is None:
        raise NotFoundError(f"There is no sequence {sequence_id}.")
    return sequence


def sequence_by_name(session: Session, name: str, user: User | None) -> Sequence:
    """The sequence called ``name``, created when missing (command-line import)."""
    sequence = session.scalar(sa.select(Sequence).where(Sequence.name == name))
    return sequence or create_sequence(session, {"name": name}, user)


def unique_sequence_name(session: Session, base: str) -> str:
    """``base``, or ``base (2)``, ``base (3)``… whichever is free."""
    taken = set(session.scalars(sa.select(Sequence.name).where(Sequence.name.like(f"{base}%"))))
    name, number = base, 1
    while name in taken:
        number += 1
        name = f"{base} ({number})"
    return name


def update_sequence(session: Session, sequence: Sequence, values: dict[str, Any]) -> Sequence:
    """Change a run's fields; ``scale_points`` (``{"points": [[x, y], [x, y]],
    "distance_mm": d}``) sets ``mm_per_px`` from two points a known distance apart."""
    values = dict(values)
    if (scale := values.pop("scale_points", None)) is not None:
        first, second = scale["points"]
        mm_per_px = scale_from_points(tuple(first), tuple(second), scale["distance_mm"])
        if mm_per_px > MAX_MM_PER_PX:
            raise InvalidInputError(
                f"That is {mm_per_px:.3g} mm per pixel, more than {MAX_MM_PER_PX:g} mm per "
                "pixel; check the distance (millimetres) and the two points."
            )
        values["mm_per_px"] = mm_per_px
    renamed = "name" in values and values["name"] != sequence.name
    if renamed and session.scalar(sa.select(Sequence.id).where(Sequence.name == values["name"])):
        raise ConflictError(f"There is already a sequence named {values['name']!r}.")
    for key, value in values.items():
        setattr(sequence, key, value)
    commit_or_conflict(session, f"There is already a sequence named {values.get('name')!r}.")
    return sequence


def frame_counts(session: Session, sequence_ids: Iterable[int]) -> dict[int, int]:
    rows = session.execute(
        sa.select(Frame.sequence_id, sa.func.count())
        .where(Frame.sequence_id.in_(list(sequence_ids)))
        .group_by(Frame.sequence_id)
    )
    return {sequence_id: count for sequence_id, count in rows if sequence_id is not None}


def list_sequences(session: Session) -> list[Sequence]:
    return list(session.scalars(sa.select(Sequence).order_by(Sequence.id.desc())))


# --- frame ingest ------------------------------------------------------------------------------


@dataclass(frozen=True)
class IncomingFile:
    """An uploaded or imported file: the client's name (metadata only) and its bytes."""

    name: str
    data: bytes


@dataclass(frozen=True)
class CheckedFrame:
    """A frame that passed the checks, ready to be stored."""

    name: str
    data: bytes
    sha256: str
    info: ImageInfo
    frame_index: int | None = None
    timestamp_s: float | None = None
    staged: StagedFile | None = None  # already written and flushed (``Storage.stage``)


@dataclass(frozen=True)
class Rejection:
    name: str
    reason: str


@dataclass(frozen=True)
class DuplicateFrame:
    name: str
    sha256: str
    frame_id: int


@dataclass
class IngestResult:
    """What became of each file of a batch."""

    stored: list[Frame] = field(default_factory=list)
    duplicates: list[DuplicateFrame] = field(default_factory=list)
    rejected: list[Rejection] = field(default_factory=list)


def name_problem(name: str) -> str | None:
    """Why a client-given file name is refused (it is metadata, never a path), or None."""
    if not name:
        return "The file has no name."
    if len(name) > 255:
        return "The file name is longer than 255 characters."
    if _BAD_NAME.search(name) or name in (".", "..") or name.startswith(".."):
        return "The file name must not contain path parts ('/', '\\\\', '..') or control codes."
    return None


def check_frame_file(
    incoming: IncomingFile, max_pixels: int, digest: str | None = None
) -> CheckedFrame | Rejection:
    """Name, content and decodability of one file (``check_image``: a plain PNG inflated in
    full and verified, any other file decoded), exactly once."""
    problem = name_problem(incoming.name)
    if problem:
        return Rejection(incoming.name, problem)
    try:
        info = check_image(incoming.data, max_pixels=max_pixels)
    except InvalidInputError as exc:
        return Rejection(incoming.name, exc.message)
    digest = digest or hashlib.sha256(incoming.data).hexdigest()
    return CheckedFrame(incoming.name, incoming.data, digest, info)


_Check = tuple[str, CheckedFrame | Rejection | None, Future[StagedFile] | None]
"""What one file's check gives: its digest; its verdict, or None for a copy of a content
another file of the request is checked for; the staging of a good one."""


class FrameChecks:
    """The checks of one request's files, each started in the pool the moment it arrives.

    A file is hashed; the first of each content is checked (``check_frame_file``) and, when
    good, staged on disk at once (``Storage.stage``, in the disk threads) while later files
    are still arriving or being checked; its copies share its verdict, each still with its own
    name checked. ``results`` waits for all of them; ``discard`` undoes the staging.
    """

    def __init__(self, storage: Storage, max_pixels: int) -> None:
        self._storage, self._max_pixels = storage, max_pixels
        self._files: list[IncomingFile] = []
        self._futures: list[Future[_Check] | None] = []  # None: refused by its name
        self._started: set[str] = set()
        self._lock = threading.Lock()

    def add(self, incoming: IncomingFile) -> None:
        """Start checking one file (returns at once)."""
        self._files.append(incoming)
        named = name_problem(incoming.name) is None
        self._futures.append(_POOL.submit(self._check, incoming) if named else None)

    def __len__(self) -> int:
        return len(self._files)

    def _check(self, incoming: IncomingFile) -> _Check:
        digest = hashlib.sha256(incoming.data).hexdigest()
        with self._lock:
            if digest in self._started:
                return digest, None, None
            self._started.add(digest)
        verdict = check_frame_file(incoming, self._max_pixels, digest)
        if isinstance(verdict, Rejection):
            return digest, verdict, None
        extension = verdict.info.extension
        return digest, verdict, _DISK.submit(self._storage.stage, incoming.data, digest, extension)

    def _settle(self) -> tuple[list[_Check], list[BaseException]]:
        """Wait for every check and staging; what they gave, and what they raised."""
        futures = [f for f in self._futures if f is not None]
        wait(futures)
        checks = [f.result() for f in futures if f.exception() is None]
        stages = [stage for _, _, stage in checks if stage is not None]
        wait(stages)
        pending: list[Future[Any]] = [*futures, *stages]
        errors = [e for f in pending if (e := f.exception()) is not None]
        return checks, errors

    def discard(self) -> None:
        """Wait for the checks, then remove every file they staged (the request failed)."""
        checks, _ = self._settle()
        stages = [stage for _, _, stage in checks if stage is not None]
        self._storage.unstage(s.result() for s in stages if s.exception() is None)

    def results(self) -> list[CheckedFrame | Rejection]:
        """Every file's verdict, in the order they arrived; the first good file of each content
        carries its staged file. If anything failed, nothing staged is left and it is raised."""
        checks, errors = self._settle()
        if errors:
            self.discard()
            raise errors[0]
        verdicts: dict[str, CheckedFrame | Rejection] = {}
        for digest, verdict, stage in checks:
            if isinstance(verdict, CheckedFrame) and stage is not None:
                verdict = replace(verdict, staged=stage.result())
            if verdict is not None:
                verdicts[digest] = verdict
        checked: list[CheckedFrame | Rejection] = []
        placed: set[str] = set()
        for incoming, future in zip(self._files, self._futures, strict=True):
            if future is None:
                checked.append(Rejection(incoming.name, name_problem(incoming.name) or ""))
                continue
            digest = future.result()[0]
            verdict = verdicts[digest]
            if isinstance(verdict, Rejection):
                checked.append(Rejection(incoming.name, verdict.reason))
            elif digest in placed:
                checked.append(CheckedFrame(incoming.name, incoming.data, digest, verdict.info))
            else:
                placed.add(digest)
                checked.append(replace(verdict, name=incoming.name))
        return checked


def _existing(session: Session, sequence_id: int | None, hashes: Seq[str]) -> dict[str, int]:
    found: dict[str, int] = {}
    for start in range(0, len(hashes), 500):
        chunk = list(hashes[start : start + 500])
        query = sa.select(Frame.sha256, Frame.id).where(Frame.sha256.in_(chunk))
        query = query.where(
            Frame.sequence_id == sequence_id
            if sequence_id is not None
            else Frame.sequence_id.is_(None)
        )
        found.update({sha: frame_id for sha, frame_id in session.execute(query)})
    return found


def _paths_in_use(session: Session, paths: list[str]) -> set[str]:
    in_use: set[str] = set()
    for start in range(0, len(paths), 500):
        chunk = paths[start : start + 500]
        in_use.update(session.scalars(sa.select(Frame.path).where(Frame.path.in_(chunk))))
    return in_use


def record_frames(
    session: Session,
    storage: Storage,
    frames: Seq[CheckedFrame],
    *,
    sequence_id: int | None,
    user: User | None,
    video_id: int | None = None,
) -> IngestResult:
    """Store and record checked frames in one transaction; same content in the same sequence
    is reported as a duplicate. Safe against a concurrent upload of the same content.

    Frames staged while they were checked are installed as they are; the others are staged
    here. Staged files that are not installed (duplicates) are removed."""
    # A content found already stored while the request arrived is looked for again now: the
    # last frame using its file may have been deleted meanwhile (stage_many writes it then).
    staged = {f.sha256: f.staged for f in frames if f.staged is not None and f.staged.temporary}
    try:
        return _record_staged(session, storage, frames, staged, sequence_id, user, video_id)
    finally:
        storage.unstage(staged.values())


def _record_staged(
    session: Session,
    storage: Storage,
    frames: Seq[CheckedFrame],
    staged: dict[str, StagedFile],
    sequence_id: int | None,
    user: User | None,
    video_id: int | None,
) -> IngestResult:
    for attempt in (1, 2):
        result = IngestResult()
        existing = _existing(session, sequence_id, [f.sha256 for f in frames])
        new: dict[str, CheckedFrame] = {}
        for frame in frames:
            if frame.sha256 in existing:
                result.duplicates.append(
                    DuplicateFrame(frame.name, frame.sha256, existing[frame.sha256])
                )
            elif frame.sha256 in new:
                result.duplicates.append(DuplicateFrame(frame.name, frame.sha256, -1))
            else:
                new[frame.sha256] = frame
        written: list[StoredFile] = []
        try:
            unstaged = [f for f in new.values() if f.sha256 not in staged]
            items = [(f.data, f.sha256, f.info.extension) for f in unstaged]
            staged.update(
                zip(
                    [f.sha256 for f in unstaged],
                    storage.stage_many(items, executor=_DISK),
                    strict=True,
                )
            )
            written = storage.install_many([staged.pop(f.sha256) for f in new.values()], _DISK)
            rows = [
                _frame_row(frame, stored.path, sequence_id, user, video_id)
                for frame, stored in zip(new.values(), written, strict=True)
            ]
            session.add_all(rows)
            session.commit()
        except sa.exc.IntegrityError:
            session.rollback()
            storage.discard(written, _paths_in_use(session, [w.path for w in written]))
            if attempt == 2:
                raise
            continue  # another upload stored some of this content meanwhile: look again
        except BaseException:
            session.rollback()
            storage.discard(written, _paths_in_use(session, [w.path for w in written]))
            raise
        by_hash = {row.sha256: row.id for row in rows}
        result.duplicates = [
            d if d.frame_id != -1 else DuplicateFrame(d.name, d.sha256, by_hash[d.sha256])
            for d in result.duplicates
        ]
        result.stored = rows
        return result
    raise AssertionError("unreachable")


def _frame_row(
    frame: CheckedFrame,
    path: str,
    sequence_id: int | None,
    user: User | None,
    video_id: int | None,
) -> Frame:
    info = frame.info
    return Frame(
        sequence_id=sequence_id,
        sha256=frame.sha256,
        path=path,
        original_name=frame.name,
        media_type=info.media_type,
        size_bytes=len(frame.data),
        width=info.width,
        height=info.height,
        channels=info.channels,
        bit_depth=info.bit_depth,
        video_id=video_id,
        frame_index=frame.frame_index,
        timestamp_s=frame.timestamp_s,
        split=Split.train,
        status=FrameStatus.new,
        uploaded_by_id=user.id if user else None,
    )


def ingest_frames(
    session: Session,
    storage: Storage,
    files: Seq[IncomingFile],
    *,
    sequence_id: int | None,
    user: User | None,
    max_pixels: int,
) -> IngestResult:
    """Check every file (in parallel, each distinct content checked once), then store and
    record the good ones atomically."""
    checks = FrameChecks(storage, max_pixels)
    for incoming in files:
        checks.add(incoming)
    return record_checked(session, storage, checks, sequence_id=sequence_id, user=user)


def record_checked(
    session: Session,
    storage: Storage,
    checks: FrameChecks,
    *,
    sequence_id: int | None,
    user: User | None,
) -> IngestResult:
    """Store and record the good files of ``checks`` atomically, once all are checked; the
    refused ones are listed with their reasons. Nothing staged is left behind on failure."""
    try:
        if sequence_id is not None:
            get_sequence(session, sequence_id)
        checked = checks.results()
    except BaseException:
        checks.discard()
        raise
    good = [c for c in checked if isinstance(c, CheckedFrame)]
    result = record_frames(session, storage, good, sequence_id=sequence_id, user=user)
    result.rejected = [c for c in checked if isinstance(c, Rejection)]
    return result


# --- reading frames ----------------------------------------------------------------------------


_ORDERINGS: dict[str, tuple[Any, ...]] = {
    "id": (Frame.id,),
    "-id": (Frame.id.desc(),),
    "frame_index": (Frame.sequence_id, Frame.frame_index, Frame.id),
    # Scores lie in [0, 1]: −1 puts frames without one last, on both databases, in the form
    # the queue's indexes hold (ix_frames_queue, ix_frames_queue_sequence).
    "uncertainty": (
        sa.func.coalesce(Frame.uncertainty, sa.literal_column("-1.0")).desc(),
        Frame.id,
    ),
}


def list_query(
    *,
    sequence_id: int | None = None,
    status: FrameStatus | Literal["unreviewed"] | None = None,
    split: Split | None = None,
    order: str = "id",
) -> tuple[sa.Select[Any], sa.Select[Any]]:
    """The ordered query of a frame list and the query of its count (which reads no row)."""
    conditions: list[Any] = []
    if sequence_id is not None:
        conditions.append(Frame.sequence_id == sequence_id)
    if status == "unreviewed":
        conditions.append(sa.text(f"frames.{UNREVIEWED_SQL}"))
    elif status is not None:
        conditions.append(Frame.status == status)
    if split is not None:
        conditions.append(Frame.split == split)
    count = sa.select(sa.func.count()).select_from(Frame).where(*conditions)
    return sa.select(Frame).where(*conditions).order_by(*_ORDERINGS[order]), count


# Keyset pagination: a page after a cursor reads only its own rows through the order's index,
# where an offset walks every row it skips. The cursor names the order and the sort key of the
# page's last row: ``<order>~<key>~<key>…`` (``null`` for a NULL), or ``uncertainty~head~<n>``
# for a position inside the queue's diversity head (which is reordered on every request).
_KEY_COLUMNS: dict[str, tuple[tuple[Any, bool, bool], ...]] = {
    # (column or expression, descending, can be NULL)
    "id": ((Frame.id, False, False),),
    "-id": ((Frame.id, True, False),),
    "frame_index": (
        (Frame.sequence_id, False, True),
        (Frame.frame_index, False, True),
        (Frame.id, False, False),
    ),
    "uncertainty": ((_ORDERINGS["uncertainty"][0].element, True, False), (Frame.id, False, False)),
}
_HEAD = "head"
_CURSOR_PROBLEM = (
    "`after` is not a cursor of this list's order; pass the `next_after` of the previous page."
)


def _key(frame: Frame, order: str) -> list[Any]:
    if order in ("id", "-id"):
        return [frame.id]
    if order == "frame_index":
        return [frame.sequence_id, frame.frame_index, frame.id]
    return [-1.0 if frame.uncertainty is None else float(frame.uncertainty), frame.id]


def _cursor(order: str, values: Seq[Any]) -> str:
    return "~".join([order, *("null" if v is None else repr(v) for v in values)])


def cursor_after(frame: Frame, order: str) -> str:
    """The cursor of the page that follows ``frame`` in ``order``."""
    return _cursor(order, _key(frame, order))


def parse_cursor(after: str, order: str) -> list[Any] | int:
    """The sort key a cursor holds (or, for the queue's head, a position); a one-sentence 400
    (``InvalidInputError``) when it is not a cursor of this order."""
    parts = after.split("~")
    columns = _KEY_COLUMNS[order]
    try:
        if parts[0] != order:
            raise ValueError
        if order == "uncertainty" and len(parts) == 3 and parts[1] == _HEAD:
            return int(parts[2])
        if len(parts) != len(columns) + 1:
            raise ValueError
        floats = order == "uncertainty"
        values: list[Any] = []
        for i, text in enumerate(parts[1:]):
            if text == "null":
                values.append(None)
            else:
                values.append(float(text) if floats and i == 0 else int(text))
        if values[-1] is None:
            raise ValueError
        return values
    except ValueError:
        raise InvalidInputError(_CURSOR_PROBLEM) from None


def after_condition(
    order: str, values: list[Any], nulls_first: bool, sequence_id: int | None = None
) -> Any:
    """Rows strictly after ``values`` in ``order``: a lexicographic comparison that places
    NULLs where the database sorts them (first ascending on SQLite, last on PostgreSQL).
    ``sequence_id``: the list is one run's, which lets a frame-index page start its index
    range at the cursor's frame index."""

    def equal(column: Any, value: Any) -> Any:
        return column.is_(None) if value is None else column == value

    def beyond(column: Any, value: Any, descending: bool, nullable: bool) -> Any:
        if value is None:
            return column.is_not(None) if nulls_first else sa.false()
        ahead = column < value if descending else column > value
        return ahead if nulls_first or not nullable else sa.or_(ahead, column.is_(None))

    columns = _KEY_COLUMNS[order]
    clauses = []
    for i, (column, descending, nullable) in enumerate(columns):
        same = [equal(c, v) for (c, _, _), v in zip(columns[:i], values[:i], strict=True)]
        clauses.append(sa.and_(*same, beyond(column, values[i], descending, nullable)))
    condition = sa.or_(*clauses)
    first, descending, nullable = columns[0]
    if not nullable and len(columns) > 1:  # a range the index can start from; the OR filters
        condition = sa.and_(first <= values[0] if descending else first >= values[0], condition)
    one_run = sequence_id is not None and values[0] == sequence_id
    if order == "frame_index" and one_run and values[1] is not None:
        start = Frame.frame_index >= values[1]
        condition = sa.and_(
            start if nulls_first else start | Frame.frame_index.is_(None), condition
        )
    return condition


@dataclass
class FramePageResult:
    """A page of a frame list: its rows, the list's total and the cursor of the next page."""

    rows: list[Frame]
    total: int
    next_after: str | None


def list_frames(
    session: Session,
    *,
    sequence_id: int | None = None,
    status: FrameStatus | Literal["unreviewed"] | None = None,
    split: Split | None = None,
    order: str = "id",
    limit: int = 50,
    offset: int = 0,
    after: str | None = None,
    diversity: float = 0.0,
    diversity_pool: int = 50,
) -> FramePageResult:
    """Frames filtered and paginated by ``offset`` or by the cursor ``after`` (keyset: no row
    before the page is read); ``order=uncertainty`` is the review queue (most unsure first,
    frames without a score last), whose first ``diversity_pool`` frames are reordered for
    diversity (``diversity`` > 0) so that near-identical frames do not follow each other."""
    if after is not None and offset:
        raise InvalidInputError("Use either `offset` or `after`, not both.")
    ordered, count = list_query(sequence_id=sequence_id, status=status, split=split, order=order)
    total = session.scalar(count) or 0
    position = offset
    key: list[Any] | None = None
    if after is not None:
        parsed = parse_cursor(after, order)
        if isinstance(parsed, int):
            position = parsed
        else:
            key = parsed
    diverse = order == "uncertainty" and diversity > 0
    if diverse and key is None and position < diversity_pool:
        pool = ordered.options(undefer(Frame.descriptor)).limit(diversity_pool)
        head = diverse_head(list(session.scalars(pool)), diversity)
        page = head[position : position + limit]
        tail: list[Frame] = []
        if len(page) < limit and len(head) == diversity_pool:
            tail = list(session.scalars(ordered.offset(diversity_pool).limit(limit - len(page))))
        end = position + len(page)
        if end < len(head):
            return FramePageResult(page, total, f"uncertainty~{_HEAD}~{end}")
        rows = page + tail
        if len(head) < diversity_pool or len(rows) < limit:  # the list ends on this page
            return FramePageResult(rows, total, None)
        last = tail[-1] if tail else max(head, key=_sort_position)
        return FramePageResult(rows, total, cursor_after(last, order))
    if key is not None:
        nulls_first = session.get_bind().dialect.name == "sqlite"
        ordered = ordered.where(after_condition(order, key, nulls_first, sequence_id))
        rows = list(session.scalars(ordered.limit(limit)))
    else:
        rows = list(session.scalars(ordered.limit(limit).offset(position)))
    more = len(rows) == limit
    return FramePageResult(rows, total, cursor_after(rows[-1], order) if more else None)


def _sort_position(frame: Frame) -> tuple[float, int]:
    """The queue's sort key as a tuple that grows along the list."""
    score, frame_id = _key(frame, "uncertainty")
    return -score, frame_id


def ordering_note(order: str, diversity: float, diversity_pool: int) -> str | None:
    """How a list is ordered, in words, where the order is not evident from the scores shown."""
    if order != "uncertainty":
        return None
    if diversity > 0:
        return (
            f"Most uncertain first; among the top {diversity_pool}, frames that look alike are "
            "spread apart (no near-copies in a row), so a score can be lower than the next one's."
        )
    return "Most uncertain first; frames without a score last."


def get_frame(session: Session, frame_id: int) -> Frame:
    frame = session.get(Frame, frame_id)
    if frame is None:
        raise NotFoundError(f"There is no frame {frame_id}.")
    return frame


def frame_state(session: Session, storage: Storage, frame: Frame) -> dict[str, Any]:
    """The frame's label, the proposal the policy shows and whether it has manual keypoints."""
    label = session.scalar(sa.select(Label).where(Label.frame_id == frame.id))
    proposal = pick(session, storage, frame.id)
    manual = session.scalar(
        sa.select(ValidationKeypoints.id).where(ValidationKeypoints.frame_id == frame.id)
    )
    return {
        "label": label
        and {"status": label.status, "revision": label.revision, "updated_at": label.updated_at},
        "proposal": proposal
        and {
            "id": proposal.id,
            "source": proposal.source,
            "model_id": proposal.model_id,
            "created_at": proposal.created_at,
        },
        "has_validation_keypoints": manual is not None,
        "uncertainty_components": frame.uncertainty_components,
    }


def display_image(storage: Storage, frame: Frame, variant: str) -> Path:
    """An 8-bit PNG of the frame for browsers (``display``: full size; ``thumb``: 256 px),
    made once from the original by the one reader and cached under ``cache/``."""
    import cv2

    from weldpool_core.io import to_rgb8

    relative = f"cache/{variant}/{frame.sha256[:2]}/{frame.sha256}.png"
    if (target := storage.absolute(relative)).exists():
        return target
    rgb = to_rgb8(read_image(storage.absolute(frame.path)))
    pixels: Any = rgb[:, :, 0] if frame.channels == 1 else rgb
    if variant == "thumb":
        scale = 256 / max(frame.width, frame.height)
        if scale < 1:
            size = (max(1, round(frame.width * scale)), max(1, round(frame.height * scale)))
            pixels = cv2.resize(pixels, size, interpolation=cv2.INTER_AREA)
    return storage.write(relative, encode_png(pixels))


# --- videos ------------------------------------------------------------------------------------


def store_video(
    session: Session,
    storage: Storage,
    source: BinaryIO,
    *,
    name: str,
    every_nth: int,
    sequence_id: int | None,
    user: User | None,
) -> Video:
    """Store a video file and record it, after checking that it decodes; the frames are
    extracted separately (a job in the service, in-process on the command line)."""
    problem = name_problem(name)
    if problem:
        raise InvalidInputError(problem)
    if every_nth < 1:
        raise InvalidInputError("every_nth must be 1 or more.")
    sequence = get_sequence(session, sequence_id) if sequence_id is not None else None
    head = source.read(16)
    if not head:
        raise InvalidInputError("The file is empty.")
    container = sniff_container(head)
    if container is None:
        raise InvalidInputError("The file is not a video; upload an MP4 or AVI video.")
    source.seek(0)
    stored, sha256, size = storage.put_stream(source, f".{container}", area="videos")
    try:
        info = probe_video(storage.absolute(stored.path))
        if sequence is None:
            base = Path(name).stem or "video"
            sequence = create_sequence(session, {"name": unique_sequence_name(session, base)}, user)
        video = Video(
            sequence_id=sequence.id,
            sha256=sha256,
            path=stored.path,
            original_name=name,
            container=container,
            size_bytes=size,
            width=info.width,
            height=info.height,
            fps=info.fps,
            frame_count=info.frame_count,
            every_nth=every_nth,
            uploaded_by_id=user.id if user else None,
        )
        session.add(video)
        session.commit()
    except BaseException:
        session.rollback()
        in_use = set(session.scalars(sa.select(Video.path).where(Video.path == stored.path)))
        storage.discard([stored], in_use)
        raise
    return video


def encode_video_frame(index: int, timestamp_s: float, pixels: Any, name: str) -> CheckedFrame:
    """A decoded video frame as a lossless PNG ready to be recorded."""
    data = encode_png(pixels)
    height, width = pixels.shape[:2]
    info = ImageInfo(
        format="PNG",
        media_type=MEDIA_TYPES["PNG"],
        extension=EXTENSIONS["PNG"],
        width=width,
        height=height,
        channels=1 if pixels.ndim == 2 else pixels.shape[2],
        bit_depth=8,
    )
    return CheckedFrame(name, data, hashlib.sha256(data).hexdigest(), info, index, timestamp_s)


def extract_video_frames(
    session: Session,
    storage: Storage,
    video: Video,
    *,
    user: User | None,
    progress: Callable[[float, str], None],
    batch_size: int = 32,
) -> dict[str, int]:
    """Every n-th frame of ``video`` into its sequence, recorded batch by batch with progress.

    Re-running it is harmless: frames already stored are reported as duplicates.
    """
    from weldpool_core.video import iter_video_frames

    stem = Path(video.original_name).stem or f"video{video.id}"
    expected = max(1, -(-video.frame_count // video.every_nth))
    stored = duplicates = done = 0
    batch: list[Any] = []

    def flush() -> None:
        nonlocal stored, duplicates, done
        checked = list(
            _POOL.map(
                lambda f: encode_video_frame(
                    f.index, f.timestamp_s, f.pixels, f"{stem}_f{f.index:06d}.png"
                ),
                batch,
            )
        )
        result = record_frames(
            session, storage, checked, sequence_id=video.sequence_id, user=user, video_id=video.id
        )
        stored += len(result.stored)
        duplicates += len(result.duplicates)
        done += len(batch)
        batch.clear()
        progress(min(done / expected, 0.999), f"{done} of about {expected} frames")

    for frame in iter_video_frames(storage.absolute(video.path), video.every_nth):
        batch.append(frame)
        if len(batch) == batch_size:
            flush()
    if batch:
        flush()
    return {
        "video_id": video.id,
        "frames": stored,
        "duplicates": duplicates,
        "sequence_id": video.sequence_id,
    }


# --- deleting ----------------------------------------------------------------------------------

REVIEWED = (FrameStatus.accepted, FrameStatus.corrected, FrameStatus.rejected)


@dataclass
class Deletion:
    """What a deletion removed."""

    frames: int = 0
    reviewed: int = 0
    files: int = 0


def _files_of(session: Session, frame_ids: list[int], video_ids: list[int]) -> set[str]:
    paths: set[str] = set()
    for start in range(0, len(frame_ids), 500):
        chunk = frame_ids[start : start + 500]
        for column, owner in (
            (Frame.path, Frame.id),
            (Proposal.mask_path, Proposal.frame_id),
            (Proposal.heatmap_path, Proposal.frame_id),
            (Label.mask_path, Label.frame_id),
            (LabelRevision.mask_path, LabelRevision.frame_id),
        ):
            paths.update(p for p in session.scalars(sa.select(column).where(owner.in_(chunk))) if p)
    if video_ids:
        paths.update(session.scalars(sa.select(Video.path).where(Video.id.in_(video_ids))))
    return paths


def _still_used(session: Session, paths: set[str]) -> set[str]:
    used: set[str] = set()
    candidates = list(paths)
    for column in STORED_PATH_COLUMNS:
        for start in range(0, len(candidates), 500):
            chunk = candidates[start : start + 500]
            used.update(p for p in session.scalars(sa.select(column).where(column.in_(chunk))) if p)
    return used


def delete_frames(
    session: Session,
    storage: Storage,
    frame_ids: list[int],
    *,
    force: bool,
    sequence: Sequence | None = None,
) -> Deletion:
    """Delete frames (or a whole sequence with its frames and videos) in one transaction.

    Proposals, labels with their history and validation keypoints go with their frame. Frames
    a person reviewed (accepted, corrected, rejected, or with validation keypoints) are only
    deleted with ``force``; otherwise ConflictError says how many would be lost. After the
    commit the collector removes each file no remaining row names (content is shared by hash)
    unless an upload in flight claimed it; what it leaves, and what a crash in between leaves,
    the collector sweeps later.
    """
    frame_ids = sorted(set(frame_ids))
    found: set[int] = set()
    for start in range(0, len(frame_ids), 500):
        chunk = frame_ids[start : start + 500]
        found.update(session.scalars(sa.select(Frame.id).where(Frame.id.in_(chunk))))
    if missing := [i for i in frame_ids if i not in found]:
        raise NotFoundError(f"There is no frame {missing[0]}; nothing was deleted.")
    reviewed = 0
    for start in range(0, len(frame_ids), 500):
        chunk = frame_ids[start : start + 500]
        reviewed += (
            session.scalar(
                sa.select(sa.func.count())
                .select_from(Frame)
                .where(
                    Frame.id.in_(chunk),
                    Frame.status.in_(REVIEWED)
                    | Frame.id.in_(
                        sa.select(ValidationKeypoints.frame_id).where(
                            ValidationKeypoints.frame_id.in_(chunk)
                        )
                    ),
                )
            )
            or 0
        )
    if reviewed and not force:
        what = f"sequence {sequence.name!r}" if sequence else "the selection"
        raise ConflictError(
            f"{reviewed} frame{'s' * (reviewed != 1)} of {what} "
            f"{'have' if reviewed != 1 else 'has'} reviewed labels or validation keypoints "
            "that would be lost; delete with force=true to remove them too."
        )
    video_ids = (
        list(session.scalars(sa.select(Video.id).where(Video.sequence_id == sequence.id)))
        if sequence
        else []
    )
    paths = _files_of(session, frame_ids, video_ids)
    for start in range(0, len(frame_ids), 500):
        session.execute(sa.delete(Frame).where(Frame.id.in_(frame_ids[start : start + 500])))
    if sequence is not None:
        session.execute(sa.delete(Video).where(Video.sequence_id == sequence.id))
        session.execute(sa.delete(Sequence).where(Sequence.id == sequence.id))
    session.commit()
    removed = storage.collect(paths, _still_used(session, paths))
    return Deletion(frames=len(frame_ids), reviewed=reviewed, files=len(removed))


def delete_sequence(
    session: Session, storage: Storage, sequence: Sequence, *, force: bool
) -> Deletion:
    """A weld run with its frames and videos (see ``delete_frames`` for the guard)."""
    frame_ids = list(session.scalars(sa.select(Frame.id).where(Frame.sequence_id == sequence.id)))
    return delete_frames(session, storage, frame_ids, force=force, sequence=sequence)


def frames_for_run(
    session: Session, frame_ids: list[int] | None, sequence_id: int | None
) -> list[int]:
    """The frames a teacher run covers: the given ids (all must exist) or a whole sequence."""
    if frame_ids:
        found = set(session.scalars(sa.select(Frame.id).where(Frame.id.in_(frame_ids))))
        missing = sorted(set(frame_ids) - found)
        if missing:
            raise NotFoundError(f"There is no frame {missing[0]}.")
        return list(dict.fromkeys(frame_ids))
    if sequence_id is not None:
        ids = list(
            session.scalars(
                sa.select(Frame.id).where(Frame.sequence_id == sequence_id).order_by(Frame.id)
            )
        )
        if not ids:
            raise InvalidInputError(f"Sequence {sequence_id} has no frames.")
        return ids
    raise InvalidInputError("Give frame_ids or a sequence_id.")
