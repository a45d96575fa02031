"""Which proposal a reviewer sees. Every proposal a frame gets is kept (each teacher run, each
student version); the policy picks one source for the whole project, measured on reviewed frames:

- Each source — the teacher (its newest proposal per frame, whatever its model) and each student
  version — is scored by the IoU of its proposals against the reviewed masks (accepted or
  corrected). A student version is never scored on frames it trained on.
- A student version is shown instead of the teacher only when, on the frames where both have a
  proposal and a reviewed mask (at least ``MIN_FRAMES``), its mIoU beats the teacher's, and its
  promotion gate has not found it unusable. Among several such versions, the largest margin
  wins. Without that evidence the teacher's proposal is the one shown: a model never makes the
  review worse unmeasured.
- A frame without a proposal from the chosen source shows the teacher's, else its newest.

Labels that started from a source's proposal favour that source (an unchanged accept scores
IoU 1), so a student enters the review only through the promotion gate's held-out measurement
or frames reviewed from the teacher's proposal; the bias can keep a shown student in place, never
bring an unmeasured one in.
"""

from __future__ import annotations

import threading
from dataclasses import asdict, dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import sqlalchemy as sa
import structlog
from sqlalchemy.orm import Session, sessionmaker

from app.core.db import has_table, utcnow
from app.core.errors import InvalidInputError, MissingFile, NotFoundError
from app.core.models import (
    DisplayPolicy,
    Frame,
    Label,
    LabelRevision,
    LabelStatus,
    ModelVersion,
    Proposal,
)
from app.core.policy_table import ROW
from app.storage import Storage
from weldpool_core.io import read_mask
from weldpool_core.metrics import iou

log = structlog.get_logger(__name__)

TEACHER = "teacher"
MIN_FRAMES = 3
"""Reviewed frames a student needs in common with the teacher before it can be shown."""


@dataclass(frozen=True)
class SourceScore:
    """One source's agreement with the reviewed masks.

    Attributes:
        key: ``teacher`` or ``student:<version name>``.
        source: the proposals' ``source`` column.
        model_id: the student's version name (None for the teacher).
        frames: reviewed frames it was scored on.
        mIoU: its mean IoU there (None without frames).
        common_frames: frames scored for both it and the teacher.
        mIoU_common / teacher_mIoU_common: both mIoUs on those frames.
        usable: False when its promotion gate found it worse than the teacher.
    """

    key: str
    source: str
    model_id: str | None
    frames: int
    mIoU: float | None
    common_frames: int
    mIoU_common: float | None
    teacher_mIoU_common: float | None
    usable: bool

    @property
    def margin(self) -> float:
        if self.mIoU_common is None or self.teacher_mIoU_common is None:
            return float("-inf")
        return self.mIoU_common - self.teacher_mIoU_common

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class Policy:
    """The chosen source and every source's score (``GET /frames/{id}/proposals`` shows both)."""

    chosen: str
    reason: str
    sources: list[SourceScore]

    def as_dict(self) -> dict[str, Any]:
        return {
            "chosen": self.chosen,
            "reason": self.reason,
            "sources": [s.as_dict() for s in self.sources],
        }


@lru_cache(maxsize=65536)
def stored_iou(first: Path, second: Path) -> float:
    """IoU of two stored masks; paths are content-addressed, so the answer never changes."""
    return iou(read_mask(first), read_mask(second))


def source_key(proposal: Proposal) -> str:
    """``teacher`` for any teacher proposal, ``<source>:<model id>`` for the others."""
    return TEACHER if proposal.source == TEACHER else f"{proposal.source}:{proposal.model_id}"


def _mean(values: list[float]) -> float | None:
    return sum(values) / len(values) if values else None


def measure(session: Session, storage: Storage) -> Policy:
    """Score every source on the reviewed frames and pick the one to show (module doc)."""
    reviewed = sa.select(Label.frame_id, Label.mask_path).where(
        Label.status.in_([LabelStatus.accepted, LabelStatus.corrected]),
        Label.mask_path.is_not(None),
    )
    labels: dict[int, str] = dict(session.execute(reviewed).all())  # type: ignore[arg-type]
    newest = (
        sa.select(sa.func.max(Proposal.id))
        .where(Proposal.frame_id.in_(reviewed.with_only_columns(Label.frame_id)))
        .group_by(Proposal.frame_id, Proposal.source, Proposal.model_id)
    )
    proposals = session.scalars(sa.select(Proposal).where(Proposal.id.in_(newest))).all()
    versions = {v.name: v for v in session.scalars(sa.select(ModelVersion))}
    # key → frame → (proposal id, IoU); the teacher keeps its newest proposal per frame
    scores: dict[str, dict[int, tuple[int, float]]] = {}
    for proposal in proposals:
        key = source_key(proposal)
        version = versions.get(proposal.model_id) if proposal.source == "student" else None
        if version is not None and proposal.frame_id in set(version.train_frame_ids or []):
            continue
        seen = scores.setdefault(key, {}).get(proposal.frame_id)
        if seen is not None and seen[0] > proposal.id:
            continue
        try:
            value = stored_iou(
                storage.existing(proposal.mask_path), storage.existing(labels[proposal.frame_id])
            )
        except MissingFile:  # a lost mask scores nothing (`weldpool doctor` lists it)
            continue
        scores[key][proposal.frame_id] = (proposal.id, value)
    teacher = {frame: value for frame, (_, value) in scores.get(TEACHER, {}).items()}
    sources = [
        SourceScore(
            TEACHER, TEACHER, None, len(teacher), _mean(list(teacher.values())), 0, None, None, True
        )
    ]
    for key, per_frame in sorted(scores.items()):
        if key == TEACHER:
            continue
        source, _, model_id = key.partition(":")
        values = {frame: value for frame, (_, value) in per_frame.items()}
        common = sorted(set(values) & set(teacher))
        version = versions.get(model_id) if source == "student" else None
        gate = (version.gate or {}) if version is not None else {}
        sources.append(
            SourceScore(
                key,
                source,
                model_id,
                len(values),
                _mean(list(values.values())),
                len(common),
                _mean([values[f] for f in common]),
                _mean([teacher[f] for f in common]),
                gate.get("usable", True) is not False,
            )
        )
    better = [s for s in sources[1:] if s.usable and s.common_frames >= MIN_FRAMES and s.margin > 0]
    if not better:
        return Policy(TEACHER, _teacher_reason(sources), sources)
    best = max(better, key=lambda s: s.margin)
    return Policy(
        best.key,
        f"{best.model_id} agrees better with the reviewed masks than the teacher on "
        f"{best.common_frames} frames (mIoU {best.mIoU_common:.3f} vs "
        f"{best.teacher_mIoU_common:.3f}).",
        sources,
    )


def _teacher_reason(sources: list[SourceScore]) -> str:
    others = [s for s in sources[1:] if s.common_frames]
    if not others:
        return "The teacher: no other source has been measured on reviewed frames yet."
    best = max(others, key=lambda s: s.margin)
    if not best.usable:
        return f"The teacher: {best.model_id} did not pass its promotion gate."
    if best.common_frames < MIN_FRAMES:
        return (
            f"The teacher: {best.model_id} has been measured on {best.common_frames} reviewed "
            f"frames; it needs {MIN_FRAMES}."
        )
    return (
        f"The teacher: it agrees better with the reviewed masks than {best.model_id} "
        f"(mIoU {best.teacher_mIoU_common:.3f} vs {best.mIoU_common:.3f} on "
        f"{best.common_frames} frames)."
    )


STORE = "display_policy_store"
"""``Session.info`` key: the ``Storage`` a session's commit measures a stale policy with."""


def watch(factory: sessionmaker[Session], storage: Storage) -> None:
    """Sessions from ``factory`` measure the policy before committing a change to what it is
    measured from (``app.core.policy_table``) and store it, so reads find it as a row."""
    factory.configure(info={STORE: storage})


CHANGED = "display_policy_changed"
"""``Session.info`` key: this transaction changed what the policy is measured from."""
MEASURED_FROM = (Label, LabelRevision, Proposal, ModelVersion)


@sa.event.listens_for(Session, "before_flush")
def _note_change(session: Session, _context: Any, _instances: Any) -> None:
    """A flush that adds, changes or deletes what the policy is measured from."""
    if not session.info.get(CHANGED) and any(
        isinstance(instance, MEASURED_FROM)
        for instance in (*session.new, *session.dirty, *session.deleted)
    ):
        session.info[CHANGED] = True


@sa.event.listens_for(Session, "do_orm_execute")
def _note_bulk_change(state: Any) -> None:
    """A bulk update or deletion of what it is measured from, or a bulk frame deletion (which
    takes labels and proposals with it)."""
    mapper = state.bind_mapper
    if mapper is None or not (state.is_delete or state.is_update):
        return
    if issubclass(mapper.class_, MEASURED_FROM) or (state.is_delete and mapper.class_ is Frame):
        state.session.info[CHANGED] = True


@sa.event.listens_for(Session, "before_commit")
def _measure_before_commit(session: Session) -> None:
    """Measure and store the policy in the transaction that changed it, or mark it stale where
    the session does not know the store (``watch``) or the store cannot be read."""
    session.flush()  # the changes still pending count too
    if not session.info.pop(CHANGED, False) or not has_table(session, DisplayPolicy.__tablename__):
        return
    # The row's lock is this transaction's last: two such commits measure one after the other
    # (PostgreSQL), the second seeing the first's change, and no lock is awaited while held.
    session.execute(
        sa.select(DisplayPolicy.id).where(DisplayPolicy.id == ROW).with_for_update()
    ).all()
    storage = session.info.get(STORE)
    if storage is not None:
        try:
            store(session, measure(session, storage))
            return
        except sa.exc.SQLAlchemyError:
            raise
        except Exception:  # an unreadable file must not fail the commit: stale, measured on read
            log.warning("policy.measure_failed", exc_info=True)
    session.execute(sa.update(DisplayPolicy).where(DisplayPolicy.id == ROW).values(stale=True))


@sa.event.listens_for(Session, "after_rollback")
def _forget_change(session: Session) -> None:
    session.info.pop(CHANGED, None)


def store(session: Session, policy: Policy) -> None:
    """Write ``policy`` as the stored row, fresh."""
    session.execute(
        sa.update(DisplayPolicy)
        .where(DisplayPolicy.id == ROW)
        .values(
            stale=False,
            chosen=policy.chosen,
            reason=policy.reason,
            sources=[score.as_dict() for score in policy.sources],
            measured_at=utcnow(),
        )
    )


def stored(session: Session) -> Policy | None:
    """The stored policy, or None while it is stale (or on a home that has none yet)."""
    row = session.execute(
        sa.select(DisplayPolicy)
        .where(DisplayPolicy.id == ROW)
        .execution_options(populate_existing=True)
    ).scalar_one_or_none()
    if row is None or row.stale:
        return None
    return Policy(row.chosen, row.reason, [SourceScore(**score) for score in row.sources])


_cache_lock = threading.Lock()
_cache: dict[tuple[Any, ...], Policy] = {}


def current(session: Session, storage: Storage) -> Policy:
    """The stored policy; while it is stale (a change committed by a session that did not know
    the store, or a failed measure) or this transaction changed what it is measured from,
    ``measure``, kept per process until labels, proposals or
    model versions change (added ones move the newest id, deleted frames take rows away: both
    are in the stamp)."""
    found = None if session.info.get(CHANGED) else stored(session)  # own changes: measure
    if found is not None:
        return found
    stamp = (
        str(storage.home),
        *session.execute(
            sa.select(sa.func.max(LabelRevision.id), sa.func.count(LabelRevision.id))
        ).one(),
        *session.execute(sa.select(sa.func.max(Proposal.id), sa.func.count(Proposal.id))).one(),
        session.scalar(sa.select(sa.func.count(ModelVersion.id))),
        session.scalar(sa.select(sa.func.max(ModelVersion.promoted_at))),
    )
    with _cache_lock:
        policy = _cache.get(stamp)
    if policy is None:
        policy = measure(session, storage)
        with _cache_lock:
            _cache.clear()
            _cache[stamp] = policy
    return policy


def frame_proposals(session: Session, frame_id: int) -> list[Proposal]:
    """Every proposal of a frame, newest first."""
    return list(
        session.scalars(
            sa.select(Proposal).where(Proposal.frame_id == frame_id).order_by(Proposal.id.desc())
        )
    )


def pick(
    session: Session,
    storage: Storage,
    frame_id: int,
    source: str | None = None,
    proposal_id: int | None = None,
) -> Proposal | None:
    """The proposal to show for a frame: a given one, the newest of a given source key, or the
    policy's (module doc). None when the frame has no proposal."""
    proposals = frame_proposals(session, frame_id)
    if proposal_id is not None:
        for proposal in proposals:
            if proposal.id == proposal_id:
                return proposal
        raise NotFoundError(f"Frame {frame_id} has no proposal {proposal_id}.")
    if source is not None:
        for proposal in proposals:
            if source_key(proposal) == source:
                return proposal
        keys = ", ".join(dict.fromkeys(source_key(p) for p in proposals)) or "none"
        raise InvalidInputError(
            f"Frame {frame_id} has no proposal from {source!r}; its sources: {keys}."
        )
    return _choose(proposals, current(session, storage).chosen)


def _choose(proposals: list[Proposal], chosen: str) -> Proposal | None:
    """The policy's rule on one frame's proposals (newest first): the chosen source's newest,
    else the teacher's, else the newest."""
    if not proposals:
        return None
    for wanted in (chosen, TEACHER):
        for proposal in proposals:
            if source_key(proposal) == wanted:
                return proposal
    return proposals[0]


def pick_many(session: Session, storage: Storage, frame_ids: list[int]) -> dict[int, Proposal]:
    """``pick`` for many frames in one query (a weld run's timeline)."""
    by_frame: dict[int, list[Proposal]] = {}
    for start in range(0, len(frame_ids), 5000):
        rows = session.scalars(
            sa.select(Proposal)
            .where(Proposal.frame_id.in_(frame_ids[start : start + 5000]))
            .order_by(Proposal.id.desc())
        )
        for proposal in rows:
            by_frame.setdefault(proposal.frame_id, []).append(proposal)
    chosen = current(session, storage).chosen
    picked = {frame_id: _choose(items, chosen) for frame_id, items in by_frame.items()}
    return {frame_id: proposal for frame_id, proposal in picked.items() if proposal is not None}
