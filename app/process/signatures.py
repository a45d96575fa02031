"""A weld run's stored signature: computed from its timeline by ``weldpool_core.signature`` and
kept in ``run_signatures`` (with its unstable frames in ``unstable_frames``).

Which frames count: the timeline's (a reviewed label, else the proposal the policy shows), and
of proposals only those of a source the policy trusts — the one it chose, or the teacher it falls
back on; a frame shown some other source's proposal (an unmeasured student's, the newest of an
unscored source) is left out, as is a frame rejected in review (it has no pool).

When it is computed again: a transaction that changes the run's labels, proposals or frames
marks the row stale (``app.core.models._signatures_go_stale``), and the next read of it — the run's
timeline page, the process map, the frames list filtered on unstable frames — computes it once
and stores it (``fresh_signatures``). Read-once rather than a job: one run is one timeline read
(its mask shapes are cached per process), the stale rows are only the runs someone changed,
and a read never shows a signature older than the labels it stands on; a job would add a kind
to the queue and a window in which the map shows old figures as current.
"""

from __future__ import annotations

import math
from typing import Any

import sqlalchemy as sa
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from app.core.db import utcnow
from app.core.errors import NotFoundError
from app.core.models import RunSignature, Sequence, UnstableFrame
from app.proposals import policy
from app.storage import Storage
from app.timeline.service import sequence_geometry
from weldpool_core.signature import Signature, run_signature

UNITS = {"mm": ("width_mm", "length_mm", "area_mm2"), "px": ("width_px", "length_px", "area_px")}


def trusted(source: str | None, chosen: str) -> bool:
    """Whether a timeline row's source counts (module doc)."""
    return source in ("label", chosen, policy.TEACHER)


def _nan(value: Any) -> float:
    return math.nan if value is None else float(value)


def timeline_signature(timeline: dict[str, Any], chosen: str) -> tuple[Signature, list[dict]]:
    """The signature of a timeline (``app.timeline.service.sequence_geometry``) and the rows it
    was computed from, in run order."""
    rows = [r for r in timeline["frames"] if trusted(r["source"], chosen)]
    unit = "mm" if timeline["mm_per_px"] else "px"
    width, length, area = UNITS[unit]
    times = [r["timestamp_s"] for r in rows]
    signature = run_signature(
        [_nan(r[width]) for r in rows],
        [_nan(r[length]) for r in rows],
        [_nan(r[area]) for r in rows],
        None if any(t is None for t in times) else times,
        unit=unit,
    )
    return signature, rows


def _detail(signature: Signature, rows: list[dict]) -> dict[str, Any]:
    """The stored detail: the signature with each stretch's frames and each frame's rolling CV."""
    detail = signature.as_dict()
    for stretch in detail["stretches"]:
        inside = rows[stretch["start"] : stretch["end"] + 1]
        stretch["frame_ids"] = [r["frame_id"] for r in inside]
        stretch["start_frame_index"] = inside[0]["frame_index"]
        stretch["end_frame_index"] = inside[-1]["frame_index"]
        # its place among the run's counted frames (1-based), for frames without an index
        stretch["start_position"], stretch["end_position"] = (
            stretch["start"] + 1,
            stretch["end"] + 1,
        )
    detail["rolling_cv"] = [
        {"frame_id": r["frame_id"], "cv": cv}
        for r, cv in zip(rows, signature.rolling_cv, strict=True)
    ]
    detail["frame_ids"] = [r["frame_id"] for r in rows]
    return detail


def _store(session: Session, sequence_id: int, chosen: str, timeline: dict[str, Any]) -> None:
    signature, rows = timeline_signature(timeline, chosen)
    detail = _detail(signature, rows)
    unstable = {
        frame_id: cv
        for stretch in detail["stretches"]
        for frame_id, cv in zip(
            stretch["frame_ids"],
            signature.rolling_cv[stretch["start"] : stretch["end"] + 1],
            strict=True,
        )
    }
    values = {
        "stale": False,
        "policy_source": chosen,
        "unit": signature.unit,
        "frames": signature.frames,
        "measured": signature.measured,
        "width_cv": signature.width_cv,
        "oscillation_hz": signature.oscillation.hz if signature.oscillation else None,
        "oscillation_strength": signature.oscillation.strength if signature.oscillation else None,
        "unstable_frames": len(unstable),
        "first_unstable_frame_id": next(iter(unstable), None),
        "detail": detail,
        "computed_at": utcnow(),
    }
    for name in ("width", "length", "area"):
        figure = getattr(signature, name)
        values |= {name: figure.median, f"{name}_q1": figure.q1, f"{name}_q3": figure.q3}
    row = session.scalar(sa.select(RunSignature).where(RunSignature.sequence_id == sequence_id))
    if row is None:
        row = RunSignature(sequence_id=sequence_id)
        session.add(row)
    for key, value in values.items():
        setattr(row, key, value)
    session.execute(sa.delete(UnstableFrame).where(UnstableFrame.sequence_id == sequence_id))
    session.add_all(
        UnstableFrame(frame_id=f, sequence_id=sequence_id, rolling_cv=cv)
        for f, cv in unstable.items()
    )


def fresh_signatures(
    session: Session, storage: Storage, sequence_ids: list[int] | None = None
) -> int:
    """Compute and store the signatures of the runs (all when None) that have none, a stale
    one, or one made under another policy source; commits; how many were computed."""
    chosen = policy.current(session, storage).chosen
    runs = (
        sa.select(Sequence.id)
        .outerjoin(RunSignature)
        .where(
            sa.or_(
                RunSignature.id.is_(None),
                RunSignature.stale,
                RunSignature.policy_source != chosen,
            )
        )
    )
    if sequence_ids is not None:
        runs = runs.where(Sequence.id.in_(sequence_ids))
    todo = list(session.scalars(runs.order_by(Sequence.id)))
    for sequence_id in todo:
        _store(session, sequence_id, chosen, sequence_geometry(session, storage, sequence_id))
        try:
            session.commit()
        except IntegrityError:  # a concurrent read stored it first (or the run went): theirs
            session.rollback()
    return len(todo)


def run_signature_of(session: Session, storage: Storage, sequence_id: int) -> RunSignature:
    """A run's stored signature, computed first where it is missing or stale."""
    fresh_signatures(session, storage, [sequence_id])
    row = session.scalar(sa.select(RunSignature).where(RunSignature.sequence_id == sequence_id))
    if row is None:
        raise NotFoundError(f"There is no weld run {sequence_id}.")
    return row


def signature_payload(row: RunSignature) -> dict[str, Any]:
    """The stored signature as the API shows it."""
    detail = {k: v for k, v in row.detail.items() if k != "frame_ids"}
    return {
        "sequence_id": row.sequence_id,
        "unit": row.unit,
        "unit_note": None
        if row.unit == "mm"
        else "The run has no scale: lengths are in px, areas in px².",
        "policy_source": row.policy_source,
        "computed_at": row.computed_at.isoformat() if row.computed_at else None,
        **detail,
    }
