"""Reading frames: the paginated list and the review queue's order, one frame's state and its
display image, and the frames a run covers."""

from __future__ import annotations

import math
from collections.abc import Sequence as Seq
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import sqlalchemy as sa
from sqlalchemy.orm import Session, undefer

from app.core.bounds import MAX_ID
from app.core.errors import InvalidInputError, NotFoundError
from app.core.models import (
    UNREVIEWED_SQL,
    Frame,
    FrameStatus,
    Label,
    ReviewState,
    Split,
    UnstableFrame,
    ValidationKeypoints,
)
from app.frames.sequences import get_sequence
from app.jobs.service import listed_frames
from app.proposals.policy import pick
from app.proposals.queue import diverse_head
from app.storage import Storage
from app.system.doctor import frame_file
from app.users.work import work_of, work_order
from weldpool_core.io import encode_png, read_image

if TYPE_CHECKING:
    import cv2
else:
    from weldpool_core.lazy import cv2

ORDERINGS: dict[str, tuple[Any, ...]] = {
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
    assignee: int | Literal["none"] | None = None,
    review: ReviewState | None = None,
    work_for: int | None = None,
    unstable: bool = False,
    facets: Seq[Any] = (),
) -> tuple[sa.Select[Any], sa.Select[Any]]:
    """The ordered query of a frame list and the query of its count (which reads no row);
    ``assignee``: the frames handed to that user, or (``none``) to nobody; ``review``: the
    frames whose label is in that state of the review stage (approved: NULL too);
    ``work_for``: that user's work (``app.users.work``), what was sent back to them first;
    ``unstable``: only frames inside their run's unstable stretches (``app.process``);
    ``facets``: conditions on what the label holds (``app.labelconfig.facets``)."""
    conditions: list[Any] = [*facets]
    first: tuple[Any, ...] = ()
    if work_for is not None:
        conditions.append(work_of(work_for))
        first = (work_order(),)
    if unstable:
        conditions.append(Frame.id.in_(sa.select(UnstableFrame.frame_id)))
    if review is not None:
        state = Label.review == review
        if review == ReviewState.approved:
            state = sa.or_(state, Label.review.is_(None))
        conditions.append(Frame.id.in_(sa.select(Label.frame_id).where(state)))
    if assignee == "none":
        conditions.append(Frame.assignee_id.is_(None))
    elif assignee is not None:
        conditions.append(Frame.assignee_id == assignee)
    if sequence_id is not None:
        conditions.append(Frame.sequence_id == sequence_id)
    if status == "unreviewed":
        conditions.append(sa.text(f"frames.{UNREVIEWED_SQL}"))
    elif status is not None:
        conditions.append(Frame.status == status)
    if split is not None:
        conditions.append(Frame.split == split)
    count = sa.select(sa.func.count()).select_from(Frame).where(*conditions)
    ordered = sa.select(Frame).where(*conditions).order_by(*first, *ORDERINGS[order])
    plain = review is None and assignee is None and split is None and not facets
    page_index, count_index = _sqlite_indexes(order, status, sequence_id is not None, plain)
    if page_index:
        ordered = ordered.with_hint(Frame, f"INDEXED BY {page_index}", "sqlite")
    if count_index:
        count = count.with_hint(Frame, f"INDEXED BY {count_index}", "sqlite")
    return ordered, count


def _sqlite_indexes(
    order: str, status: FrameStatus | Literal["unreviewed"] | None, one_run: bool, plain: bool
) -> tuple[str | None, str | None]:
    """The index a page and the count of a run's list or the queue read on SQLite, named: its
    planner has no statistics, and among indexes it costs alike (each that starts with
    ``sequence_id``) it takes the first in ``sqlite_master``, whose order differs between homes
    — the queue's count then read every row of the run instead of the partial index alone.
    ``plain``: no filter but the run and the status (others leave the choice to the planner)."""
    if not plain:
        return None, None
    if status == "unreviewed":  # the partial index holds exactly these rows: nothing else read
        queue = "ix_frames_queue_sequence" if one_run else "ix_frames_queue"
        return (queue if order == "uncertainty" else None), queue
    if status is None:
        by_score = "ix_frames_sequence_uncertainty" if one_run else "ix_frames_uncertainty_order"
        return (by_score if order == "uncertainty" else None), (
            "ix_frames_sequence_id" if one_run else None
        )
    return None, None


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
    "uncertainty": ((ORDERINGS["uncertainty"][0].element, True, False), (Frame.id, False, False)),
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
            return _bounded(int(parts[2]), low=0)
        if len(parts) != len(columns) + 1:
            raise ValueError
        floats = order == "uncertainty"
        values: list[Any] = []
        for (_, _, nullable), text in zip(columns, parts[1:], strict=True):
            if text == "null" and nullable:
                values.append(None)
            elif floats and not values:
                values.append(_finite(float(text)))
            else:
                values.append(_bounded(int(text), low=-MAX_ID))
        return values
    except ValueError:
        raise InvalidInputError(_CURSOR_PROBLEM) from None


def _bounded(value: int, low: int) -> int:
    """``value`` where it lies in ``[low, MAX_ID]`` (no key or position of a list lies beyond:
    a larger one would overflow the database's integers)."""
    if not low <= value <= MAX_ID:
        raise ValueError
    return value


def _finite(value: float) -> float:
    if not math.isfinite(value):
        raise ValueError
    return value


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
    assignee: int | Literal["none"] | None = None,
    review: ReviewState | None = None,
    work_for: int | None = None,
    unstable: bool = False,
    facets: Seq[Any] = (),
) -> FramePageResult:
    """Frames filtered and paginated by ``offset`` or by the cursor ``after`` (keyset: no row
    before the page is read); ``order=uncertainty`` is the review queue (most unsure first,
    frames without a score last), whose first ``diversity_pool`` frames are reordered for
    diversity (``diversity`` > 0) so that near-identical frames do not follow each other.
    A person's work list (``work_for``) pages by offset alone (its order leads with a case)."""
    if after is not None and offset:
        raise InvalidInputError("Use either `offset` or `after`, not both.")
    if work_for is not None and after is not None:
        raise InvalidInputError("A work list pages by `offset`; it has no cursor.")
    ordered, count = list_query(
        sequence_id=sequence_id,
        status=status,
        split=split,
        order=order,
        assignee=assignee,
        review=review,
        work_for=work_for,
        unstable=unstable,
        facets=facets,
    )
    total = session.scalar(count) or 0
    if work_for is not None:
        rows = list(session.scalars(ordered.limit(limit).offset(offset)))
        return FramePageResult(rows, total, None)
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


def ordering_note(
    order: str, diversity: float, diversity_pool: int, work: bool = False
) -> str | None:
    """How a list is ordered, in words, where the order is not evident from the scores shown."""
    if work:
        return "What was sent back to you first, then the frames handed to you still to review."
    if order != "uncertainty":
        return None
    if diversity > 0:
        return (
            f"Most uncertain first; among the top {diversity_pool}, frames that look alike are "
            "spread apart (no near-copies in a row), so a score can be lower than the next one's."
        )
    return "Most uncertain first; frames without a score last."


def review_states(session: Session, frame_ids: list[int]) -> dict[int, dict[str, Any]]:
    """Per frame with a label in the review stage: its state and the reviewer's comment."""
    rows = session.execute(
        sa.select(Label.frame_id, Label.review, Label.review_comment).where(
            Label.frame_id.in_(frame_ids), Label.review.is_not(None)
        )
    )
    return {f: {"review": r, "review_comment": c} for f, r, c in rows}


def frame_state(session: Session, storage: Storage, frame: Frame) -> dict[str, Any]:
    """The frame's label, the proposal the policy shows and whether it has manual keypoints."""
    label = session.scalar(sa.select(Label).where(Label.frame_id == frame.id))
    proposal = pick(session, storage, frame.id)
    manual = session.scalar(
        sa.select(ValidationKeypoints.id).where(ValidationKeypoints.frame_id == frame.id)
    )
    return {
        "label": label
        and {
            "status": label.status,
            "revision": label.revision,
            "updated_at": label.updated_at,
            "review": label.review,
        },
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
    from weldpool_core.io import to_rgb8

    relative = f"cache/{variant}/{frame.sha256[:2]}/{frame.sha256}.png"
    if (target := storage.absolute(relative)).exists():
        return target
    rgb = to_rgb8(read_image(frame_file(storage, frame.path, frame.id)))
    pixels: Any = rgb[:, :, 0] if frame.channels == 1 else rgb
    if variant == "thumb":
        scale = 256 / max(frame.width, frame.height)
        if scale < 1:
            size = (max(1, round(frame.width * scale)), max(1, round(frame.height * scale)))
            pixels = cv2.resize(pixels, size, interpolation=cv2.INTER_AREA)
    return storage.write(relative, encode_png(pixels))


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
        get_sequence(session, sequence_id)
        ids = list(
            session.scalars(
                sa.select(Frame.id).where(Frame.sequence_id == sequence_id).order_by(Frame.id)
            )
        )
        if not ids:
            raise InvalidInputError(f"Sequence {sequence_id} has no frames.")
        return ids
    raise InvalidInputError("Give frame_ids or a sequence_id.")


def run_scope(
    session: Session, frame_ids: list[int] | None, sequence_id: int | None
) -> tuple[dict[str, Any], list[int] | None]:
    """A run's scope as a job stores it: a weld run as its id and frame count (its parameters),
    or the frames a person listed (checked; ``create_job`` keeps them in the job's scope row)."""
    ids = frames_for_run(session, frame_ids, sequence_id)
    if sequence_id is not None and not frame_ids:
        return {"sequence_id": sequence_id, "frames": len(ids)}, None
    return {}, ids


def run_frames(session: Session, sequence_id: int) -> list[Frame]:
    """The run's frames in the order SAM2 walks them (its video's order, then by id)."""
    return list(
        session.scalars(
            sa.select(Frame)
            .where(Frame.sequence_id == sequence_id)
            .order_by(Frame.frame_index.is_(None), Frame.frame_index, Frame.id)
        )
    )


UNREVIEWED = "unreviewed"
"""A run's scope: the frames still to review when it starts (the promoted student's run)."""


def unreviewed_frame_ids(session: Session) -> list[int]:
    """Frames without an accepted, corrected or rejected label (the review queue)."""
    reviewed = sa.select(Label.frame_id)
    return list(
        session.scalars(sa.select(Frame.id).where(Frame.id.not_in(reviewed)).order_by(Frame.id))
    )


def scope_frames(session: Session, job_id: int, params: dict[str, Any]) -> list[int]:
    """The frames a run works on, read when it starts: those a person listed, the frames still
    to review, or every frame of its weld run, in id order."""
    if (listed := listed_frames(session, job_id, params)) is not None:
        return listed
    if params.get("scope") == UNREVIEWED:
        return unreviewed_frame_ids(session)
    if "sequence_id" in params:
        return list(
            session.scalars(
                sa.select(Frame.id)
                .where(Frame.sequence_id == int(params["sequence_id"]))
                .order_by(Frame.id)
            )
        )
    raise InvalidInputError("This run names no frames.")


def also_in(session: Session, frames: list[Frame]) -> list[tuple[int, int, int | None, str | None]]:
    """For each of ``frames`` whose content another frame holds (in another run, or in none):
    (frame id, the first such other frame's id, its run's id and name). One query."""
    from app.core.models import Sequence

    if not frames:
        return []
    by_sha = {f.sha256: f.id for f in frames}
    rows = session.execute(
        sa.select(Frame.sha256, Frame.id, Frame.sequence_id, Sequence.name)
        .outerjoin(Sequence, Sequence.id == Frame.sequence_id)
        .where(Frame.sha256.in_(list(by_sha)), Frame.id.not_in(list(by_sha.values())))
        .order_by(Frame.id)
    ).all()
    found: dict[str, tuple[int, int, int | None, str | None]] = {}
    for sha, other, sequence_id, name in rows:
        found.setdefault(sha, (by_sha[sha], other, sequence_id, name))
    return sorted(found.values())
