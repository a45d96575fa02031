"""Frame ingest: every file is checked, decoded once, stored by content hash and recorded
atomically (files first, then one commit; a failed commit removes the files)."""

from __future__ import annotations

import hashlib
import os
import re
import threading
from collections.abc import Sequence as Seq
from concurrent.futures import Future, wait
from dataclasses import dataclass, field, replace
from functools import partial
from typing import Any

import sqlalchemy as sa
from sqlalchemy.orm import Session

from app.core.budgets import shared_pool
from app.core.errors import InvalidInputError
from app.core.models import Frame, FrameStatus, Split, User
from app.frames.sequences import get_sequence
from app.storage import StagedFile, Storage, StoredFile, best_effort
from weldpool_core.io import ImageInfo, check_image, header_extension

_BAD_NAME = re.compile(r"[/\\\x00-\x1f]")
INGEST_POOL = shared_pool(max(2, os.cpu_count() or 2), "ingest")  # uploads', imports', videos'
DISK_POOL = shared_pool(8, "ingest-disk")
"""Writes and fsyncs wait on the disk, not a core: their own threads keep the checks going
and let the disk queue several flushes at once."""


@dataclass(frozen=True)
class IncomingFile:
    """An uploaded or imported file: the client's name (metadata only), its bytes, and their
    SHA-256 when the caller has hashed them already (an import, to find stored frames)."""

    name: str
    data: bytes
    sha256: str | None = None


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

    A file is hashed; the first of each content is checked (``check_frame_file``) and staged
    (``Storage.stage``, in the disk threads) while later files are still arriving or being
    checked — from the moment it is hashed when its header names an image format, so an object
    store's upload overlaps the check (withdrawn if the check refuses the file). Its copies
    share its verdict, each still with its own name checked. ``results`` waits for all of
    them; ``discard`` undoes the staging.
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
        self._futures.append(INGEST_POOL.submit(self._check, incoming) if named else None)

    def __len__(self) -> int:
        return len(self._files)

    def _check(self, incoming: IncomingFile) -> _Check:
        digest = incoming.sha256 or hashlib.sha256(incoming.data).hexdigest()
        with self._lock:
            if digest in self._started:
                return digest, None, None
            self._started.add(digest)
        guess = header_extension(incoming.data)
        early = self._stage(incoming.data, digest, guess) if guess else None
        verdict = check_frame_file(incoming, self._max_pixels, digest)
        wanted = verdict.info.extension if isinstance(verdict, CheckedFrame) else None
        if early is not None and guess != wanted:  # refused, or not what its header said
            wait([early])
            if early.exception() is None:
                self._storage.unstage([early.result()])
            early = None
        if wanted is None:
            return digest, verdict, None
        return digest, verdict, early or self._stage(incoming.data, digest, wanted)

    def _stage(self, data: bytes, digest: str, extension: str) -> Future[StagedFile]:
        """Stage a content in the disk threads."""
        return DISK_POOL.submit(self._storage.stage, data, digest, extension)

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
        best_effort("unstage", partial(storage.unstage, list(staged.values())))


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
                    storage.stage_many(items, executor=DISK_POOL),
                    strict=True,
                )
            )
            # A duplicate staged with a temporary was not in the store: its file was lost, and
            # this upload puts it back (what `weldpool doctor` advises for a lost image).
            lost = [staged.pop(sha) for sha in existing.keys() & staged.keys()]
            written = storage.install_many(
                [staged.pop(f.sha256) for f in new.values()] + lost, DISK_POOL
            )
            rows = [
                _frame_row(frame, stored.path, sequence_id, user, video_id)
                for frame, stored in zip(new.values(), written[: len(new)], strict=True)
            ]
            session.add_all(rows)
            session.commit()
        except sa.exc.IntegrityError:
            session.rollback()
            storage.discard(written, _paths_in_use(session, [w.path for w in written]))
            if sequence_id is not None:
                get_sequence(session, sequence_id)  # deleted meanwhile: its 404
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
