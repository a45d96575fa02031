"""Labels made elsewhere, brought in: each reader's labels (``weldpool_core.annotations``)
matched to frames and written as reviewed labels.

A label's image is the file the annotation names in the import (stored like an upload, or the
frame already here with the same content) or, when the import has no such file, the frame
already here with that name (in the run given, else anywhere when only one frame has it).
Labels are written in batches of ``BATCH``: the batch's new frames are stored and committed
first (as an upload is), then its labels, validation keypoints and history in one transaction,
with their mask files written before it and removed if it fails. An imported label is
``corrected`` by the importing user, with ``source`` ``{"kind": "imported", "format", "file"}``
in its history; a frame that already has a label keeps it (listed as skipped) unless the
import asks to ``overwrite``, which adds a revision.
"""

from __future__ import annotations

import hashlib
import os
import posixpath
import shutil
import uuid
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

import sqlalchemy as sa
from pydantic import ValidationError
from sqlalchemy.orm import Session

from app.db import utcnow
from app.errors import ConflictError, InvalidInputError
from app.frames import ingest, sequences
from app.frames.ingest import DISK_POOL, INGEST_POOL
from app.frames.schemas import SequenceIn
from app.models import Frame, Label, LabelStatus, Sequence, User, ValidationKeypoints
from app.proposals.files import FrameDeleted, lock_frame, masks_in_use
from app.review.service import (
    check_keypoints,
    mask_columns,
    mask_keypoints,
    set_validation_keypoints,
    write_label,
)
from app.storage import CHUNK, Storage, StoredFile
from weldpool_core.annotations import READERS, ImportedLabel, Parsed, Refusal, Source
from weldpool_core.annotations.shapes import DAMAGED, inside_frame
from weldpool_core.io import encode_mask_png

IMPORTS_DIR = "imports"
"""Where an uploaded import waits for its job (removed when the job ends; a day at most)."""
BATCH = 64
RUN_NAME = 190
"""Longest run name an import makes (runs hold 200 characters; ``name (2)`` needs room)."""
MAX_LISTED = 1000
"""Most skipped or refused items a job's result lists one by one (the rest are counted)."""
Progress = Callable[[float, str], None]


def upload_name(name: str) -> str:
    """Where the file an import job reads is stored (``name`` is the job's, never a
    client's)."""
    return f"{IMPORTS_DIR}/{Path(name).name}"


def keep_upload(storage: Storage, source: BinaryIO, suffix: str) -> str:
    """Copy an uploaded file (a spooled part) under ``imports/``, flushed and published to
    every machine (a worker elsewhere reads it); its name."""
    folder = storage.home / IMPORTS_DIR
    folder.mkdir(parents=True, exist_ok=True)
    name = f"{uuid.uuid4().hex}{suffix}"
    target = folder / name
    try:
        with open(target, "wb") as handle:
            shutil.copyfileobj(source, handle, CHUNK)
            handle.flush()
            os.fsync(handle.fileno())
        storage.publish(upload_name(name))
    except BaseException:
        target.unlink(missing_ok=True)
        raise
    return name


KEYPOINT_ROLES = ("validation", "label")
"""What a file's hand-placed pool keypoints become: validation keypoints (the frame joins the
validation split and does not train), or the label's own keypoints (it trains on them)."""


@dataclass(frozen=True)
class ImportOptions:
    format: str
    sequence_id: int | None = None
    overwrite: bool = False
    category: str | None = None
    max_pixels: int = 25_000_000
    keypoints: str = "validation"  # KEYPOINT_ROLES


@dataclass
class ImportReport:
    """What an import did: frames stored, labels and validation keypoints written, and every
    item it skipped or refused, with why."""

    frames: int = 0
    labels: int = 0
    keypoints: int = 0
    skipped: list[Refusal] = field(default_factory=list)
    refused: list[Refusal] = field(default_factory=list)

    def as_result(self) -> dict[str, Any]:
        def listed(items: list[Refusal]) -> list[dict[str, str]]:
            return [{"item": r.item, "reason": r.reason} for r in items[:MAX_LISTED]]

        return {
            "frames": self.frames,
            "labels": self.labels,
            "keypoints": self.keypoints,
            "skipped": listed(self.skipped),
            "skipped_count": len(self.skipped),
            "refused": listed(self.refused),
            "refused_count": len(self.refused),
        }


def checked_format(name: str) -> str:
    """``name`` when it is a label format, else a one-sentence error."""
    if name not in READERS:
        raise InvalidInputError(
            f"There is no label format {name!r}; use one of {', '.join(READERS)}."
        )
    return name


def import_labels(
    session: Session,
    storage: Storage,
    source: Source,
    options: ImportOptions,
    user: User,
    progress: Progress | None = None,
) -> ImportReport:
    """Read ``source`` in ``options.format`` and import its labels batch by batch."""
    reader = READERS[checked_format(options.format)]
    if options.sequence_id is not None:
        sequences.get_sequence(session, options.sequence_id)
    try:
        parsed = reader(source, options.category)
    except InvalidInputError as exc:
        if not source.refused:
            raise
        parsed = Parsed([], [Refusal(source.name, exc.message)])  # nothing left to read
    report = ImportReport(refused=[*source.refused, *parsed.refused])
    runs = _Runs(session, source.name, options.sequence_id, user, report)
    total = len(parsed.labels)
    for start in range(0, total, BATCH):
        batch = parsed.labels[start : start + BATCH]
        _Batch(session, storage, source, options, user, report).run(batch, runs)
        if progress is not None:
            done = min(start + BATCH, total)
            progress(done / total, f"{done} of {total} labels read")
    return report


class _Runs:
    """The run each label's new frame goes to: the one asked for; else the run the label
    names (a weldpool export's, created with its process parameters when missing); else one
    new run named after the import, made when first needed."""

    def __init__(
        self,
        session: Session,
        name: str,
        sequence_id: int | None,
        user: User,
        report: ImportReport,
    ) -> None:
        self._session, self._user, self._report = session, user, report
        self._name = posixpath.splitext(posixpath.basename(name))[0][:RUN_NAME] or "import"
        self._fixed = sequence_id
        self._by_name: dict[str, int] = {}
        self._default: int | None = None

    @property
    def fixed(self) -> int | None:
        return self._fixed

    def for_label(self, label: ImportedLabel) -> int:
        if self._fixed is not None:
            return self._fixed
        if label.sequence:
            if label.sequence not in self._by_name:
                self._by_name[label.sequence] = self._named(label.sequence, label.process)
            return self._by_name[label.sequence]
        if self._default is None:
            self._default = self._new_run()
        return self._default

    def _new_run(self) -> int:
        """A new run named after the import (``name (2)``… when taken, also meanwhile)."""
        for _ in range(5):
            name = sequences.unique_sequence_name(self._session, self._name)
            try:
                return sequences.create_sequence(self._session, {"name": name}, self._user).id
            except ConflictError:  # another import took the name meanwhile
                self._session.rollback()
        raise ConflictError("Other imports kept taking the new run's name; import again.")

    def _named(self, name: str, process: dict[str, Any] | None) -> int:
        name = name[:RUN_NAME]
        found = self._session.scalar(sa.select(Sequence).where(Sequence.name == name))
        if found is not None:
            return found.id
        values: dict[str, Any] = {"name": name}
        parameters = {k: v for k, v in (process or {}).items() if k != "name"}
        try:
            values = SequenceIn.model_validate(values | parameters).model_dump(exclude_unset=True)
        except ValidationError:
            self._report.refused.append(
                Refusal(name, "Its process parameters are not valid; the run is made without.")
            )
        try:
            return sequences.create_sequence(self._session, values, self._user).id
        except ConflictError:  # made meanwhile by another import
            self._session.rollback()
            return self._session.scalars(sa.select(Sequence.id).where(Sequence.name == name)).one()


@dataclass
class _Target:
    label: ImportedLabel
    frame_id: int | None = None
    incoming: ingest.IncomingFile | None = None
    sha256: str | None = None
    sequence_id: int | None = None


class _Batch:
    """One batch: its frames found or stored, then its labels written in one transaction."""

    def __init__(
        self,
        session: Session,
        storage: Storage,
        source: Source,
        options: ImportOptions,
        user: User,
        report: ImportReport,
    ) -> None:
        self.session, self.storage, self.source = session, storage, source
        self.options, self.user, self.report = options, user, report
        self.has_manual: set[int] = set()

    def refuse(self, label: ImportedLabel, reason: str) -> None:
        self.report.refused.append(Refusal(label.item, reason))

    def run(self, labels: list[ImportedLabel], runs: _Runs) -> None:
        if self.options.keypoints == "label":
            for label in labels:  # the file's hand-placed keypoints are the label's own
                if label.validation_keypoints and not label.keypoints and label.shapes:
                    label.keypoints, label.validation_keypoints = label.validation_keypoints, None
        targets = [t for t in (self._target(label, runs) for label in labels) if t is not None]
        self._store_frames(targets)
        placed = [t for t in targets if t.frame_id is not None]
        listed = len(self.report.skipped), len(self.report.refused)
        for attempt in (1, 2):
            try:
                self._write_labels(placed)
                return
            except (ConflictError, sa.exc.IntegrityError):
                if attempt == 2:
                    raise ConflictError(
                        "Other writers kept labelling these frames; import again."
                    ) from None
                # another writer labelled one of these frames meanwhile: look again
                del self.report.skipped[listed[0] :], self.report.refused[listed[1] :]

    # --- frames --------------------------------------------------------------------------

    def _target(self, label: ImportedLabel, runs: _Runs) -> _Target | None:
        data = label.image_data
        if data is None:
            path = self.source.find(label.image, label.beside)
            try:
                data = self.source.read(path) if path is not None else None
            except InvalidInputError as exc:  # a damaged zip entry: this item, not the import
                self.refuse(label, f"The image cannot be read: {exc.message}")
                return None
        if data is not None:
            name = label.original_name or posixpath.basename(label.image) or "frame"
            digest = hashlib.sha256(data).hexdigest()
            target = _Target(label, incoming=ingest.IncomingFile(name, data), sha256=digest)
            target.frame_id = self._stored_with(digest, runs.fixed)
            if target.frame_id is None:
                target.sequence_id = runs.for_label(label)
            return target
        frame_id, problem = self._stored_named(label, runs.fixed)
        if problem:
            self.refuse(label, problem)
            return None
        return _Target(label, frame_id=frame_id)

    def _stored_with(self, digest: str, sequence_id: int | None) -> int | None:
        query = sa.select(Frame.id).where(Frame.sha256 == digest).order_by(Frame.id).limit(1)
        if sequence_id is not None:
            query = query.where(Frame.sequence_id == sequence_id)
        return self.session.scalar(query)

    def _stored_named(
        self, label: ImportedLabel, sequence_id: int | None
    ) -> tuple[int | None, str]:
        names = {label.original_name, posixpath.basename(label.image)} - {None, ""}
        query = sa.select(Frame.id).where(Frame.original_name.in_(names)).limit(2)
        if sequence_id is not None:
            query = query.where(Frame.sequence_id == sequence_id)
        found = list(self.session.scalars(query))
        if not found:
            where = f" in sequence {sequence_id}" if sequence_id is not None else ""
            return None, (
                f"The image {label.image!r} is neither in the import nor stored here{where}."
            )
        if len(found) > 1:
            return None, (
                f"More than one stored frame is named {label.image!r}; import into one sequence."
            )
        return found[0], ""

    def _store_frames(self, targets: list[_Target]) -> None:
        by_run: dict[int, list[_Target]] = {}
        for target in targets:
            if target.frame_id is None and target.sequence_id is not None:
                by_run.setdefault(target.sequence_id, []).append(target)
        for sequence_id, group in by_run.items():
            files = [t.incoming for t in group if t.incoming is not None]
            result = ingest.ingest_frames(
                self.session,
                self.storage,
                files,
                sequence_id=sequence_id,
                user=self.user,
                max_pixels=self.options.max_pixels,
            )
            self.report.frames += len(result.stored)
            ids = {f.sha256: f.id for f in result.stored}
            ids.update({d.sha256: d.frame_id for d in result.duplicates})
            reasons = {r.name: r.reason for r in result.rejected}
            for target in group:
                target.frame_id = ids.get(target.sha256 or "")
                if target.frame_id is None and target.incoming is not None:
                    reason = reasons.get(target.incoming.name, "The image could not be stored.")
                    self.refuse(target.label, f"The image is refused: {reason}")

    # --- labels --------------------------------------------------------------------------

    def _write_labels(self, targets: list[_Target]) -> None:
        session = self.session
        ids = sorted({t.frame_id for t in targets if t.frame_id is not None})
        frames = {f.id: f for f in session.scalars(sa.select(Frame).where(Frame.id.in_(ids)))}
        labels = {
            label.frame_id: label
            for label in session.scalars(sa.select(Label).where(Label.frame_id.in_(ids)))
        }
        self.has_manual = set(  # a reviewer's validation keypoints stay unless overwritten
            session.scalars(
                sa.select(ValidationKeypoints.frame_id).where(ValidationKeypoints.frame_id.in_(ids))
            )
        )
        written: list[StoredFile] = []
        try:
            for frame_id in ids:
                try:
                    lock_frame(session, frame_id)  # a deletion waits for this batch (PostgreSQL)
                except FrameDeleted:
                    frames.pop(frame_id, None)
            work = self._placed(targets, frames, labels)
            sizes = [(frame.height, frame.width) for _, frame, _ in work]  # read here, not there
            contents = list(
                INGEST_POOL.map(lambda job, size: _content(job[0].label, size, job[2]), work, sizes)
            )
            written = self._store_masks(contents)
            counts = [0, 0]
            for (target, frame, _), content in zip(work, contents, strict=True):
                self._write_one(target.label, frame, labels.get(frame.id), content, counts)
            session.commit()
        except BaseException:
            session.rollback()
            paths = [f.path for f in written]
            self.storage.discard(written, in_use=masks_in_use(session, paths))
            raise
        self.report.labels += counts[0]
        self.report.keypoints += counts[1]

    def _placed(
        self, targets: list[_Target], frames: dict[int, Frame], labels: dict[int, Label]
    ) -> list[tuple[_Target, Frame, bool]]:
        """Each target with its frame and whether its label is to be written (else it is
        skipped: the frame has one and the import does not overwrite)."""
        placed, seen = [], set()
        for target in targets:
            frame = frames.get(target.frame_id or -1)
            if frame is None:
                self.refuse(target.label, "Its frame was deleted while it was imported.")
            elif frame.id in seen:
                self.refuse(target.label, "Another item of the import labels this frame.")
            else:
                seen.add(frame.id)
                current = labels.get(frame.id)
                wants = bool(target.label.shapes) and (current is None or self.options.overwrite)
                if target.label.shapes and not wants and current is not None:
                    self.report.skipped.append(
                        Refusal(
                            target.label.item,
                            f"Frame {frame.id} already has a label (revision "
                            f"{current.revision}); import with overwrite to add a revision.",
                        )
                    )
                placed.append((target, frame, wants))
        return placed

    def _store_masks(self, contents: list[_Content]) -> list[StoredFile]:
        """Every new mask PNG staged in the disk threads, then installed (flushed)."""
        new = [c for c in contents if c.mask_png is not None]
        items = [(c.mask_png or b"", c.sha256, ".png") for c in new]
        staged = self.storage.stage_many(items, area="artefacts", executor=DISK_POOL)
        written = self.storage.install_many(staged, DISK_POOL)
        for content, stored in zip(new, written, strict=True):
            content.mask_path = stored.path
        return [w for w in written if w.created]

    def _write_one(
        self,
        item: ImportedLabel,
        frame: Frame,
        current: Label | None,
        content: _Content,
        counts: list[int],
    ) -> None:
        """The label and validation keypoints of one frame (not committed)."""
        try:
            if content.problem:
                raise InvalidInputError(content.problem)
            size = (frame.height, frame.width)
            keypoints = check_keypoints(frame, inside_frame(content.keypoints or [], *size))
            manual = (
                check_keypoints(frame, inside_frame(content.manual, *size))
                if content.manual
                else None
            )
        except InvalidInputError as exc:
            self.refuse(item, exc.message)
            return
        if content.mask_path is not None:
            values = content.columns | {
                "mask_path": content.mask_path,
                "status": LabelStatus.corrected,
                "keypoints": keypoints,
                "proposal_id": None,
                "mask_changed": None,
                "source": {"kind": "imported", "format": self.options.format, "file": item.item},
                "updated_by_id": self.user.id,
                "updated_at": utcnow(),
            }
            base = current.revision if current is not None else 0
            write_label(self.session, frame, current, base, values, flush=False)
            counts[0] += 1
        if manual is not None and (frame.id not in self.has_manual or self.options.overwrite):
            set_validation_keypoints(self.session, frame, self.user, manual)
            counts[1] += 1


@dataclass
class _Content:
    """One label's content, computed in the ingest pool, off the session: its mask's PNG (to
    store), stored columns and keypoints, or why it is refused."""

    mask_png: bytes | None = None
    sha256: str = ""
    columns: dict[str, Any] = field(default_factory=dict)
    keypoints: list[list[float]] | None = None
    manual: list[list[float]] | None = None
    problem: str | None = None
    mask_path: str | None = None  # set once the PNG is stored


def _content(item: ImportedLabel, size: tuple[int, int], wants_label: bool) -> _Content:
    """Rasterise, check, encode and measure one label on a frame of ``size`` (height, width);
    thread-safe. The label's keypoints are Algorithm 1's on the mask unless it has its own."""
    height, width = size
    content = _Content(manual=item.validation_keypoints)
    try:
        item.checked_points(height, width)
        if not wants_label:
            return content
        mask, rle = item.rasterised(height, width)
        if mask is None:
            return content
        content.keypoints = item.keypoints or mask_keypoints(mask)
        content.columns = mask_columns(mask, rle=rle)
        content.mask_png = encode_mask_png(mask)
        content.sha256 = hashlib.sha256(content.mask_png).hexdigest()
    except InvalidInputError as exc:
        content.problem = exc.message
    except DAMAGED:
        content.problem = "The annotation holds values of the wrong type or size."
    return content
