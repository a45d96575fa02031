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
import posixpath
from collections.abc import Callable
from dataclasses import dataclass

import sqlalchemy as sa
from sqlalchemy.orm import Session

from app.core.db import utcnow
from app.core.errors import ConflictError, InvalidInputError, PermissionDeniedError
from app.core.frame_rows import lock_frames
from app.core.models import Frame, Label, LabelStatus, User, ValidationKeypoints
from app.frames import ingest, sequences
from app.frames.ingest import DISK_POOL, INGEST_POOL
from app.imports.classes import frame_tags, sort_classes
from app.imports.pool import BATCH, Check, Contents, computed
from app.imports.runs import Runs
from app.imports.schemas import ImportOptions, ImportReport, checked_format
from app.jobs.registry import counted
from app.labelconfig import service as labelconfig
from app.proposals.files import masks_in_use
from app.review.service import (
    check_keypoints,
    saved_review,
    set_validation_keypoints,
    write_label,
)
from app.storage import Storage, StoredFile
from weldpool_core.annotations import READERS, ImportedLabel, Parsed, Refusal, Source
from weldpool_core.annotations.content import LabelContent
from weldpool_core.annotations.shapes import inside_frame

PROCESS_MIN = 256
"""Labels in an import from which their work (rasterise, encode, Algorithm 1) runs in processes,
one per core, instead of the ingest threads, whose Python parts share one GIL: starting the
processes costs about a second, which a few hundred labels repay."""
Progress = Callable[[float, str], None]


def import_labels(
    session: Session,
    storage: Storage,
    source: Source,
    options: ImportOptions,
    user: User,
    progress: Progress | None = None,
    check: Check | None = None,
) -> ImportReport:
    """Read ``source`` in ``options.format`` and import its labels batch by batch; ``check``
    (a job's cancel) is asked while each batch's labels are computed.

    Raises:
        PermissionDeniedError: ``user`` was deactivated during the import (the batches
            written before stay).
    """
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
    sort_classes(parsed, labelconfig.current(session), options.class_map, report)
    report.skip_classes(source.name)
    runs = Runs(session, source.name, options.sequence_id, user, report.refused)
    total = len(parsed.labels)
    processes = total >= PROCESS_MIN
    # A pipeline of two batches: the next one's frames are stored while this one's labels
    # are computed (in processes for a large import); each batch's labels in one transaction.
    pending: tuple[_Batch, int] | None = None
    for start in range(0, total, BATCH):
        still_active(session, user)
        batch = _Batch(session, storage, source, options, user, report, processes, check)
        try:
            batch.prepare(parsed.labels[start : start + BATCH], runs)
        finally:
            if pending is not None:
                _finish(*pending, total, progress)
        pending = batch, min(start + BATCH, total)
    if pending is not None:
        _finish(*pending, total, progress)
    return report


def still_active(session: Session, user: User) -> None:
    """Refuse to go on in the name of a user deactivated (or deleted) since the import began."""
    if not session.scalar(sa.select(User.is_active).where(User.id == user.id)):
        raise PermissionDeniedError(
            f"{user.username} was deactivated during the import; it stopped, and only the "
            "labels written before stay."
        )


def _names(label: ImportedLabel) -> set[str]:
    """The names a label gives its image (its original name, the file's base name)."""
    return {name for name in (label.original_name, posixpath.basename(label.image)) if name}


def _digests(images: list[bytes | InvalidInputError | None]) -> list[str]:
    """Each image's sha256 ("" where the import has none): hashlib lets go of the GIL, so the
    ingest threads hash a batch at once (labels of stored frames start no task)."""
    found = iter(
        INGEST_POOL.map(
            lambda data: hashlib.sha256(data).hexdigest(),
            [d for d in images if isinstance(d, bytes)],
        )
    )
    return [next(found) if isinstance(d, bytes) else "" for d in images]


def _finish(batch: _Batch, done: int, total: int, progress: Progress | None) -> None:
    batch.finish()
    if progress is not None:
        progress(done / total, f"{done} of {total} labels read")


WRITE_ATTEMPTS = 3
"""How often a batch's labels are read and written again when other writers changed its
frames meanwhile, before the import stops saying what it wrote."""


@dataclass
class _Target:
    label: ImportedLabel
    frame_id: int | None = None
    incoming: ingest.IncomingFile | None = None
    sha256: str | None = None
    sequence_id: int | None = None


class _Batch:
    """One batch: its frames found or stored and its labels' contents started (``prepare``),
    then its labels written in one transaction (``finish``)."""

    def __init__(
        self,
        session: Session,
        storage: Storage,
        source: Source,
        options: ImportOptions,
        user: User,
        report: ImportReport,
        processes: bool = False,
        check: Check | None = None,
    ) -> None:
        self.session, self.storage, self.source = session, storage, source
        self.options, self.user, self.report = options, user, report
        self.processes, self.check = processes, check
        self.has_manual: set[int] = set()
        self.placed: list[_Target] = []
        self.early: dict[int, tuple[int, tuple[int, int], bool]] = {}
        self.contents: Contents | None = None

    def refuse(self, label: ImportedLabel, reason: str) -> None:
        self.report.refused.append(Refusal(label.item, reason))

    def run(self, labels: list[ImportedLabel], runs: Runs) -> None:
        self.prepare(labels, runs)
        self.finish()

    def prepare(self, labels: list[ImportedLabel], runs: Runs) -> None:
        if self.options.keypoints == "label":
            for label in labels:  # the file's hand-placed keypoints are the label's own
                if label.validation_keypoints and not label.keypoints and label.shapes:
                    label.keypoints, label.validation_keypoints = label.validation_keypoints, None
        labels = [loaded for label in labels if (loaded := self._loaded(label)) is not None]
        images = [self._image(label) for label in labels]
        digests = _digests(images)
        stored = self._stored_with(digests, runs.fixed)
        named = self._stored_by_name(
            [label for label, data in zip(labels, images, strict=True) if data is None],
            runs.fixed,
        )
        targets = [
            t
            for label, data, digest in zip(labels, images, digests, strict=True)
            if (t := self._target(label, data, digest, stored, named, runs)) is not None
        ]
        self._store_frames(targets)
        self.placed = [t for t in targets if t.frame_id is not None]
        self._start_contents()

    def _start_contents(self) -> None:
        """Start computing the labels' contents on their frames' sizes, as they will be
        written unless the frames change meanwhile (``_write_labels`` looks again)."""
        ids = {t.frame_id for t in self.placed if t.frame_id is not None}
        sizes = {
            frame_id: (height, width)
            for frame_id, height, width in self.session.execute(
                sa.select(Frame.id, Frame.height, Frame.width).where(Frame.id.in_(ids))
            )
        }
        labelled = set(
            self.session.scalars(sa.select(Label.frame_id).where(Label.frame_id.in_(ids)))
        )
        jobs: list[tuple[ImportedLabel, tuple[int, int], bool]] = []
        for target in self.placed:
            if target.frame_id in sizes:
                size = sizes[target.frame_id]
                wants = bool(target.label.shapes) and (
                    target.frame_id not in labelled or self.options.overwrite
                )
                self.early[id(target)] = (len(jobs), size, wants)
                jobs.append((target.label, size, wants))
        self.contents = Contents(jobs, self.processes)

    def finish(self) -> None:
        still_active(self.session, self.user)
        listed = len(self.report.skipped), len(self.report.refused)
        for attempt in range(1, WRITE_ATTEMPTS + 1):
            try:
                self._write_labels(self.placed)
                return
            except (ConflictError, sa.exc.IntegrityError):
                self.session.rollback()
                if attempt == WRITE_ATTEMPTS:
                    raise ConflictError(self._stopped()) from None
                # another writer labelled or deleted one of these frames meanwhile: look again
                del self.report.skipped[listed[0] :], self.report.refused[listed[1] :]

    def _stopped(self) -> str:
        """Why the import stopped in a batch others kept changing, and what it left: the
        labels of the batches before (kept) and this batch's new frames (kept, unlabelled; an
        import again finds them by content and labels them)."""
        report = self.report
        return (
            f"Other writers kept labelling or deleting these frames while the import wrote them; "
            f"it stopped after writing {counted(report.labels, 'label')} and storing "
            f"{counted(report.frames, 'new frame')} (those stay); import again to label the rest."
        )

    # --- frames --------------------------------------------------------------------------

    def _loaded(self, label: ImportedLabel) -> ImportedLabel | None:
        """The label with its files read (with its batch, not before); None, refused, when
        one cannot be read."""
        try:
            return label.loaded(self.source)
        except InvalidInputError as exc:
            self.refuse(label, exc.message)
            return None

    def _image(self, label: ImportedLabel) -> bytes | InvalidInputError | None:
        """The label's image from the file: None when it is not in it, the error (already
        listed as the item's refusal) when its entry is damaged or its name ambiguous."""
        if label.image_data is not None:
            return label.image_data
        try:
            path = self.source.find(label.image, label.beside)
        except InvalidInputError as exc:  # a bare name two folders hold: not a stored frame
            self.refuse(label, exc.message)
            return exc
        try:
            return self.source.read(path) if path is not None else None
        except InvalidInputError as exc:  # a damaged zip entry: this item, not the import
            self.refuse(label, f"The image cannot be read: {exc.message}")
            return exc

    def _target(
        self,
        label: ImportedLabel,
        data: bytes | InvalidInputError | None,
        digest: str,
        stored: dict[str, int],
        named: dict[str, list[int]],
        runs: Runs,
    ) -> _Target | None:
        if isinstance(data, InvalidInputError):
            return None  # refused in ``_image``
        if data is not None:
            name = label.original_name or posixpath.basename(label.image) or "frame"
            incoming = ingest.IncomingFile(name, data, sha256=digest)
            target = _Target(label, incoming=incoming, sha256=digest)
            target.frame_id = stored.get(digest)
            if target.frame_id is None:
                target.sequence_id = runs.for_label(label)
            return target
        frame_id, problem = self._stored_named(label, named, runs.fixed)
        if problem:
            self.refuse(label, problem)
            return None
        return _Target(label, frame_id=frame_id)

    def _stored_with(self, digests: list[str], sequence_id: int | None) -> dict[str, int]:
        """The first stored frame of each content (in ``sequence_id`` when given): one query."""
        wanted = {d for d in digests if d}
        if not wanted:
            return {}
        query = (
            sa.select(Frame.sha256, sa.func.min(Frame.id))
            .where(Frame.sha256.in_(wanted))
            .group_by(Frame.sha256)
        )
        if sequence_id is not None:
            query = query.where(Frame.sequence_id == sequence_id)
        return {sha: frame_id for sha, frame_id in self.session.execute(query)}

    def _stored_by_name(
        self, labels: list[ImportedLabel], sequence_id: int | None
    ) -> dict[str, list[int]]:
        """The stored frames (up to two each: one more than a match) that bear each name the
        labels give their image (in ``sequence_id`` when given): one query."""
        names = set().union(*(_names(label) for label in labels)) if labels else set()
        if not names:
            return {}
        query = sa.select(Frame.original_name, Frame.id).where(Frame.original_name.in_(names))
        if sequence_id is not None:
            query = query.where(Frame.sequence_id == sequence_id)
        found: dict[str, list[int]] = {}
        for name, frame_id in self.session.execute(query.order_by(Frame.id)):
            if len(ids := found.setdefault(name, [])) < 2:
                ids.append(frame_id)
        return found

    def _stored_named(
        self, label: ImportedLabel, named: dict[str, list[int]], sequence_id: int | None
    ) -> tuple[int | None, str]:
        found = sorted({i for name in _names(label) for i in named.get(name, [])})
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
            present = lock_frames(session, ids)  # a deletion waits for this batch (PostgreSQL)
            for frame_id in set(ids) - present:
                frames.pop(frame_id, None)
            work = self._placed(targets, frames, labels)
            contents = self._contents(work)
            written, mask_paths = self._store_masks(contents)
            counts = [0, 0]
            for (target, frame, _), content, path in zip(work, contents, mask_paths, strict=True):
                current = labels.get(frame.id)
                self._write_one(target.label, frame, current, content, path, counts)
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

    def _contents(self, work: list[tuple[_Target, Frame, bool]]) -> list[LabelContent]:
        """Each placed label's content: the one started in ``prepare`` when its frame and
        whether it is written are as they were then, else computed now."""
        early = self.contents.results(self.check) if self.contents is not None else []
        found: list[LabelContent | None] = []
        late = []
        for target, frame, wants in work:
            started = self.early.get(id(target))
            if started is not None and started[1:] == ((frame.height, frame.width), wants):
                found.append(early[started[0]])
            else:
                found.append(None)
                late.append((target.label, (frame.height, frame.width), wants))
        made = iter(computed(late, self.check))
        return [c if c is not None else next(made) for c in found]

    def _store_masks(
        self, contents: list[LabelContent]
    ) -> tuple[list[StoredFile], list[str | None]]:
        """Every new mask PNG staged in the disk threads, then installed (flushed); the files
        this created, and each content's stored path."""
        new = [i for i, c in enumerate(contents) if c.mask_png is not None]
        items = [(contents[i].mask_png or b"", contents[i].sha256, ".png") for i in new]
        staged = self.storage.stage_many(items, area="artefacts", executor=DISK_POOL)
        written = self.storage.install_many(staged, DISK_POOL)
        paths: list[str | None] = [None] * len(contents)
        for index, stored in zip(new, written, strict=True):
            paths[index] = stored.path
        return [w for w in written if w.created], paths

    def _write_one(
        self,
        item: ImportedLabel,
        frame: Frame,
        current: Label | None,
        content: LabelContent,
        mask_path: str | None,
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
        if mask_path is not None:
            values = content.columns | {
                "mask_path": mask_path,
                "status": LabelStatus.corrected,
                "keypoints": keypoints,
                "proposal_id": None,
                "mask_changed": None,
                "source": {"kind": "imported", "format": self.options.format, "file": item.item},
                "updated_by_id": self.user.id,
                "updated_at": utcnow(),
                "review": saved_review(self.user, self.options.review_stage),
                "review_comment": None,
                "objects": content.objects or None,
                "frame_tags": frame_tags(item),
            }
            base = current.revision if current is not None else 0
            write_label(self.session, frame, current, base, values, flush=False)
            counts[0] += 1
            self.report.skipped += [Refusal(item.item, why) for why in content.left_out]
        if manual is not None and (frame.id not in self.has_manual or self.options.overwrite):
            # Without overwrite, only where there were none when read (0): keypoints a reviewer
            # saved since make a conflict, and the batch is read again (``finish``).
            since = None if self.options.overwrite else 0
            set_validation_keypoints(self.session, frame, self.user, manual, since)
            counts[1] += 1
