"""ORM tables: the core of weldpool's domain. Migrations in ``migrations/`` create them."""

from __future__ import annotations

import datetime as dt
import enum
from typing import TYPE_CHECKING, Any

import sqlalchemy as sa
from sqlalchemy.orm import Mapped, Session, mapped_column, relationship

from app.core.db import Base, JSONType, UTCDateTime, enum_type, has_table, utcnow
from app.core.errors import NotFoundError
from app.core.facet_table import LabelFacet as LabelFacet  # what a label holds, to filter on
from app.core.job_tables import ONE_AT_A_TIME as ONE_AT_A_TIME  # the jobs' tables, re-exported:
from app.core.job_tables import Job as Job  # every table is imported from here
from app.core.job_tables import JobChunk as JobChunk
from app.core.job_tables import JobScope as JobScope
from app.core.job_tables import JobStatus as JobStatus
from app.core.job_tables import Worker as Worker
from app.core.policy_table import DisplayPolicy as DisplayPolicy  # the stored display policy
from app.core.process_tables import RunSignature as RunSignature  # a run's stored signature
from app.core.process_tables import UnstableFrame as UnstableFrame

if TYPE_CHECKING:
    import numpy as np
else:
    from weldpool_core.lazy import np  # the web process loads NumPy once it reads a vector


class Float32Vector(sa.types.TypeDecorator[Any]):
    """A vector of floats as little-endian float32 bytes, read back as a NumPy array: a DINO
    descriptor of 384 floats is 1.5 KB and decodes in microseconds (as JSON it was ~3.4 KB and
    took the queue's first page 4 ms to parse for 50 frames)."""

    impl = sa.LargeBinary
    cache_ok = True

    def process_bind_param(self, value: Any, dialect: Any) -> bytes | None:
        if value is None:
            return None
        return np.asarray(value, "<f4").tobytes()

    def process_result_value(self, value: bytes | None, dialect: Any) -> Any:
        if value is None:
            return None
        return np.frombuffer(value, "<f4")

    def compare_values(self, x: Any, y: Any) -> bool:  # arrays: not ``==``, which is elementwise
        vectors = (list, tuple, np.ndarray)
        if isinstance(x, vectors) and isinstance(y, vectors):
            return bool(np.array_equal(np.asarray(x, "<f4"), np.asarray(y, "<f4")))
        return x is y  # None, or the ORM's "not loaded"


class Role(enum.StrEnum):
    """What a user may do: annotators label; reviewers also accept, reject and train; admins
    also manage users."""

    annotator = "annotator"
    reviewer = "reviewer"
    admin = "admin"

    @property
    def rank(self) -> int:
        return _ROLE_RANK[self]


_ROLE_RANK = {Role.annotator: 1, Role.reviewer: 2, Role.admin: 3}


class Split(enum.StrEnum):
    """Which set a frame belongs to; validation frames never train the student."""

    train = "train"
    validation = "validation"
    test = "test"


class FrameStatus(enum.StrEnum):
    """Where a frame stands in the review loop."""

    new = "new"
    proposed = "proposed"
    accepted = "accepted"
    corrected = "corrected"
    rejected = "rejected"


class LabelStatus(enum.StrEnum):
    """A reviewer's verdict on a frame."""

    accepted = "accepted"
    corrected = "corrected"
    rejected = "rejected"


class ReviewState(enum.StrEnum):
    """Where an annotator's label stands in the review stage (``WELDPOOL_REVIEW_STAGE``);
    a label without one (the stage off, or saved before it was on) counts as approved."""

    awaiting = "awaiting"
    approved = "approved"
    returned = "returned"


class User(Base):
    """Who may use weldpool. A name is one user in any case (``uq_users_lower_username``;
    migration 0019 makes it only where no two names an older database holds differ by case
    alone, and the service refuses such a name either way)."""

    __tablename__ = "users"
    __table_args__ = (sa.Index("uq_users_lower_username", sa.text("lower(username)"), unique=True),)

    id: Mapped[int] = mapped_column(primary_key=True)
    username: Mapped[str] = mapped_column(sa.String(64), unique=True)
    password_hash: Mapped[str] = mapped_column(sa.String(255))
    role: Mapped[Role] = mapped_column(enum_type(Role, "role"))
    is_active: Mapped[bool] = mapped_column(default=True)
    created_at: Mapped[dt.datetime] = mapped_column(UTCDateTime, default=utcnow)
    last_login_at: Mapped[dt.datetime | None] = mapped_column(UTCDateTime)


class ApiToken(Base):
    """A bearer token; only its SHA-256 is stored, the token itself is shown once."""

    __tablename__ = "api_tokens"

    id: Mapped[int] = mapped_column(primary_key=True)
    user_id: Mapped[int] = mapped_column(sa.ForeignKey("users.id", ondelete="CASCADE"), index=True)
    name: Mapped[str] = mapped_column(sa.String(64), default="")
    token_hash: Mapped[str] = mapped_column(sa.String(64), unique=True)
    prefix: Mapped[str] = mapped_column(sa.String(16))
    created_at: Mapped[dt.datetime] = mapped_column(UTCDateTime, default=utcnow)
    last_used_at: Mapped[dt.datetime | None] = mapped_column(UTCDateTime)
    revoked_at: Mapped[dt.datetime | None] = mapped_column(UTCDateTime)

    user: Mapped[User] = relationship(lazy="joined")


class WebSession(Base):
    """A browser login; the cookie holds a random id whose SHA-256 is stored here."""

    __tablename__ = "web_sessions"

    id: Mapped[int] = mapped_column(primary_key=True)
    user_id: Mapped[int] = mapped_column(sa.ForeignKey("users.id", ondelete="CASCADE"), index=True)
    session_hash: Mapped[str] = mapped_column(sa.String(64), unique=True)
    csrf_token: Mapped[str] = mapped_column(sa.String(64))
    created_at: Mapped[dt.datetime] = mapped_column(UTCDateTime, default=utcnow)
    expires_at: Mapped[dt.datetime] = mapped_column(UTCDateTime)

    user: Mapped[User] = relationship(lazy="joined")


class Sequence(Base):
    """A weld run, with the process parameters of the paper's Table I."""

    __tablename__ = "sequences"

    id: Mapped[int] = mapped_column(primary_key=True)
    name: Mapped[str] = mapped_column(sa.String(200), unique=True)
    wire_feed_m_min: Mapped[float | None] = mapped_column(sa.Float)
    voltage_v: Mapped[float | None] = mapped_column(sa.Float)
    current_a: Mapped[float | None] = mapped_column(sa.Float)
    arc_length_correction_pct: Mapped[float | None] = mapped_column(sa.Float)
    robot_speed_cm_min: Mapped[float | None] = mapped_column(sa.Float)
    synergic_law: Mapped[str | None] = mapped_column(sa.String(200))
    joint_type: Mapped[str | None] = mapped_column(sa.String(64))
    mm_per_px: Mapped[float | None] = mapped_column(sa.Float)
    """The camera's scale at the pool (mm per pixel), for geometry in millimetres."""
    notes: Mapped[str] = mapped_column(sa.Text, default="")
    created_by_id: Mapped[int | None] = mapped_column(
        sa.ForeignKey("users.id", ondelete="SET NULL")
    )
    created_at: Mapped[dt.datetime] = mapped_column(UTCDateTime, default=utcnow)


class Video(Base):
    """An uploaded weld video; a job extracts every n-th frame of it into its sequence."""

    __tablename__ = "videos"

    id: Mapped[int] = mapped_column(primary_key=True)
    sequence_id: Mapped[int] = mapped_column(
        sa.ForeignKey("sequences.id", ondelete="CASCADE"), index=True
    )
    sha256: Mapped[str] = mapped_column(sa.String(64))
    path: Mapped[str] = mapped_column(sa.String(500))
    original_name: Mapped[str] = mapped_column(sa.String(255), default="")
    container: Mapped[str] = mapped_column(sa.String(16))
    size_bytes: Mapped[int] = mapped_column(sa.BigInteger)
    width: Mapped[int]
    height: Mapped[int]
    fps: Mapped[float] = mapped_column(sa.Float)
    frame_count: Mapped[int]
    every_nth: Mapped[int] = mapped_column(default=1)
    job_id: Mapped[int | None] = mapped_column(sa.ForeignKey("jobs.id", ondelete="SET NULL"))
    uploaded_by_id: Mapped[int | None] = mapped_column(
        sa.ForeignKey("users.id", ondelete="SET NULL")
    )
    created_at: Mapped[dt.datetime] = mapped_column(UTCDateTime, default=utcnow)


UNREVIEWED = (FrameStatus.new, FrameStatus.proposed)
"""Frames still to review: what the queue shows by default (``status=unreviewed``)."""
UNREVIEWED_SQL = f"status IN ({', '.join(repr(status.value) for status in UNREVIEWED)})"
"""Frames still to review, as SQL with its values written out: the queue's partial indexes are
defined by it, and a query must say it the same way for SQLite to use them (a bound parameter
cannot prove that a row is in a partial index)."""


class Frame(Base):
    """One stored camera frame; the file lives under WELDPOOL_HOME, named by its content hash.

    A sequence holds a given content once: (sequence_id, sha256) is unique, and so is the hash
    among frames without a sequence.
    """

    __tablename__ = "frames"
    __table_args__ = (
        sa.Index("uq_frames_sequence_sha", "sequence_id", "sha256", unique=True),
        sa.Index(
            "uq_frames_unsequenced_sha",
            "sha256",
            unique=True,
            sqlite_where=sa.text("sequence_id IS NULL"),
            postgresql_where=sa.text("sequence_id IS NULL"),
        ),
        sa.Index("ix_frames_sequence_index", "sequence_id", "frame_index", "id"),
        # One index per list order, so that a page reads its rows in order instead of sorting
        # the run: a run's frames by id, and the review queue (frames still to review, most
        # uncertain first) of a run and of everything.
        sa.Index("ix_frames_sequence_id", "sequence_id", "id"),
        sa.Index(
            "ix_frames_queue_sequence",
            "sequence_id",
            sa.text("coalesce(uncertainty, -1.0) DESC"),
            "id",
            sqlite_where=sa.text(UNREVIEWED_SQL),
            postgresql_where=sa.text(UNREVIEWED_SQL),
        ),
        sa.Index(
            "ix_frames_queue",
            sa.text("coalesce(uncertainty, -1.0) DESC"),
            "id",
            sqlite_where=sa.text(UNREVIEWED_SQL),
            postgresql_where=sa.text(UNREVIEWED_SQL),
        ),
        # The uncertainty order without a status filter (the home page's default list).
        sa.Index(
            "ix_frames_sequence_uncertainty",
            "sequence_id",
            sa.text("coalesce(uncertainty, -1.0) DESC"),
            "id",
        ),
        sa.Index("ix_frames_uncertainty_order", sa.text("coalesce(uncertainty, -1.0) DESC"), "id"),
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    sequence_id: Mapped[int | None] = mapped_column(
        sa.ForeignKey("sequences.id", ondelete="CASCADE")
    )
    sha256: Mapped[str] = mapped_column(sa.String(64), index=True)
    path: Mapped[str] = mapped_column(sa.String(500))
    original_name: Mapped[str] = mapped_column(sa.String(255), default="")
    media_type: Mapped[str] = mapped_column(sa.String(64))
    size_bytes: Mapped[int] = mapped_column(sa.BigInteger)
    width: Mapped[int]
    height: Mapped[int]
    channels: Mapped[int] = mapped_column(default=1)
    bit_depth: Mapped[int] = mapped_column(default=8)
    video_id: Mapped[int | None] = mapped_column(
        sa.ForeignKey("videos.id", ondelete="SET NULL"), index=True
    )
    frame_index: Mapped[int | None]
    timestamp_s: Mapped[float | None] = mapped_column(sa.Float)
    split: Mapped[Split] = mapped_column(enum_type(Split, "split"), default=Split.train, index=True)
    status: Mapped[FrameStatus] = mapped_column(
        enum_type(FrameStatus, "frame_status"), default=FrameStatus.new, index=True
    )
    uncertainty: Mapped[float | None] = mapped_column(sa.Float, index=True)
    uncertainty_components: Mapped[dict[str, Any] | None] = mapped_column(JSONType)
    uncertainty_reason: Mapped[str | None] = mapped_column(sa.String(32))
    descriptor: Mapped[Any] = mapped_column(
        "descriptor_f32", Float32Vector, nullable=True, deferred=True
    )
    """The frame's DINO descriptor (384 floats, a read-only float32 array; a list may be
    assigned): loaded only where it is asked for (the queue's diversity pick), never with list
    rows."""
    teacher_error: Mapped[str | None] = mapped_column(sa.String(500))
    """Why the teacher's last run failed on this frame; cleared by its next proposal."""
    uploaded_by_id: Mapped[int | None] = mapped_column(
        sa.ForeignKey("users.id", ondelete="SET NULL")
    )
    created_at: Mapped[dt.datetime] = mapped_column(UTCDateTime, default=utcnow)
    assignee_id: Mapped[int | None] = mapped_column(
        sa.ForeignKey("users.id", ondelete="SET NULL"), index=True
    )
    """The person the frame is handed to (``POST /frames/assign``); None: anyone's."""
    assigned_at: Mapped[dt.datetime | None] = mapped_column(UTCDateTime)

    assignee: Mapped[User | None] = relationship(foreign_keys=[assignee_id], lazy="selectin")


class ProposalClaim(Base):
    """A run proposing a frame with one model right now (``app.proposals.record.claim``): two
    runs of the same teacher over the same frames propose each frame once. Removed when the
    proposal is recorded; one left by a run that stopped is taken over."""

    __tablename__ = "proposal_claims"

    frame_id: Mapped[int] = mapped_column(
        sa.ForeignKey("frames.id", ondelete="CASCADE"), primary_key=True, autoincrement=False
    )
    model_id: Mapped[str] = mapped_column(sa.String(255), primary_key=True)
    job_id: Mapped[int] = mapped_column(sa.ForeignKey("jobs.id", ondelete="CASCADE"))


class Proposal(Base):
    """A teacher's or student's proposed mask, heatmap and keypoints for one frame. Every
    proposal is kept; ``app.review.policy`` picks the one a reviewer sees."""

    __tablename__ = "proposals"
    __table_args__ = (sa.Index("ix_proposals_frame_source", "frame_id", "source"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    frame_id: Mapped[int] = mapped_column(
        sa.ForeignKey("frames.id", ondelete="CASCADE"), index=True
    )
    source: Mapped[str] = mapped_column(sa.String(16))  # "teacher", "student" or "propagated"
    model_id: Mapped[str] = mapped_column(sa.String(255))
    model_version_id: Mapped[int | None] = mapped_column(
        sa.ForeignKey("model_versions.id", ondelete="SET NULL")
    )
    job_id: Mapped[int | None] = mapped_column(sa.ForeignKey("jobs.id", ondelete="SET NULL"))
    mask_path: Mapped[str] = mapped_column(sa.String(500))
    heatmap_path: Mapped[str | None] = mapped_column(sa.String(500))
    keypoints: Mapped[list[Any]] = mapped_column(JSONType, default=list)
    prompts: Mapped[dict[str, Any]] = mapped_column(JSONType, default=dict)
    scores: Mapped[dict[str, Any]] = mapped_column(JSONType, default=dict)
    timings: Mapped[dict[str, Any]] = mapped_column(JSONType, default=dict)
    created_at: Mapped[dt.datetime] = mapped_column(UTCDateTime, default=utcnow)


class Label(Base):
    """The current reviewed label of a frame; ``revision`` guards against lost updates."""

    __tablename__ = "labels"

    id: Mapped[int] = mapped_column(primary_key=True)
    frame_id: Mapped[int] = mapped_column(
        sa.ForeignKey("frames.id", ondelete="CASCADE"), unique=True
    )
    revision: Mapped[int] = mapped_column(default=1)
    status: Mapped[LabelStatus] = mapped_column(enum_type(LabelStatus, "label_status"))
    mask_path: Mapped[str | None] = mapped_column(sa.String(500))
    keypoints: Mapped[list[Any] | None] = mapped_column(JSONType)
    proposal_id: Mapped[int | None] = mapped_column(
        sa.ForeignKey("proposals.id", ondelete="SET NULL")
    )
    mask_changed: Mapped[bool | None]  # did the reviewer change the proposal's mask?
    # The mask in COCO's terms, computed when the label is saved (exports read them instead of
    # decoding every mask): compressed RLE {"size", "counts"}, area in pixels, [x, y, w, h].
    mask_rle: Mapped[dict[str, Any] | None] = mapped_column(JSONType)
    mask_area: Mapped[int | None]
    mask_bbox: Mapped[list[int] | None] = mapped_column(JSONType)
    # Its regions' outer outlines as the YOLO export writes them (``outline.region_outlines``):
    # [[[x, y], …], …] in frame pixels.
    mask_outlines: Mapped[list[Any] | None] = mapped_column(JSONType)
    # Where a label made elsewhere came from ({"kind": "imported", "format", "file"}); NULL
    # for one drawn here.
    source: Mapped[dict[str, Any] | None] = mapped_column(JSONType)
    updated_by_id: Mapped[int | None] = mapped_column(
        sa.ForeignKey("users.id", ondelete="SET NULL")
    )
    updated_at: Mapped[dt.datetime] = mapped_column(UTCDateTime, default=utcnow)
    # The review stage (off: all NULL): awaiting a reviewer, approved, or returned with a
    # comment; who decided last (``updated_by`` of that revision) is in the history.
    review: Mapped[ReviewState | None] = mapped_column(enum_type(ReviewState, "review_state"))
    review_comment: Mapped[str | None] = mapped_column(sa.String(1000))
    # The other configured classes' objects ([{"class", …}], ``app.labelconfig``) and the
    # frame's tags and attributes ({"tags": […], "attributes": {…}}); NULL: the pool alone.
    objects: Mapped[list[Any] | None] = mapped_column(JSONType)
    frame_tags: Mapped[dict[str, Any] | None] = mapped_column(JSONType)


class LabelRevision(Base):
    """Every change to a label, kept: who, when, what."""

    __tablename__ = "label_revisions"
    __table_args__ = (sa.UniqueConstraint("frame_id", "revision"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    frame_id: Mapped[int] = mapped_column(
        sa.ForeignKey("frames.id", ondelete="CASCADE"), index=True
    )
    revision: Mapped[int]
    status: Mapped[LabelStatus] = mapped_column(enum_type(LabelStatus, "label_status"))
    mask_path: Mapped[str | None] = mapped_column(sa.String(500))
    keypoints: Mapped[list[Any] | None] = mapped_column(JSONType)
    proposal_id: Mapped[int | None] = mapped_column(
        sa.ForeignKey("proposals.id", ondelete="SET NULL")
    )
    mask_changed: Mapped[bool | None]
    source: Mapped[dict[str, Any] | None] = mapped_column(JSONType)  # as Label.source
    review: Mapped[ReviewState | None] = mapped_column(enum_type(ReviewState, "review_state"))
    review_comment: Mapped[str | None] = mapped_column(sa.String(1000))
    user_id: Mapped[int | None] = mapped_column(sa.ForeignKey("users.id", ondelete="SET NULL"))
    created_at: Mapped[dt.datetime] = mapped_column(UTCDateTime, default=utcnow)
    objects: Mapped[list[Any] | None] = mapped_column(JSONType)  # as Label.objects
    frame_tags: Mapped[dict[str, Any] | None] = mapped_column(JSONType)  # as Label.frame_tags


class LabelConfig(Base):
    """One version of the instance's label configuration (``app.labelconfig``): rows are only
    added; the highest ``version`` is in force. Two admins saving on one version: the second
    insert meets the first's key (409)."""

    __tablename__ = "label_configs"

    version: Mapped[int] = mapped_column(primary_key=True, autoincrement=False)
    config: Mapped[dict[str, Any]] = mapped_column(JSONType)
    user_id: Mapped[int | None] = mapped_column(sa.ForeignKey("users.id", ondelete="SET NULL"))
    created_at: Mapped[dt.datetime] = mapped_column(UTCDateTime, default=utcnow)


class OverlapLabel(Base):
    """One annotator's own label of a frame given to several (``app.review.agreement``): kept
    apart from the frame's label, never trained on, until a reviewer approves one of them or
    merges them into the frame's label; kept after that, for the agreement figures. A row
    without a mask is a frame given to that annotator and not labelled yet."""

    __tablename__ = "overlap_labels"
    __table_args__ = (sa.UniqueConstraint("frame_id", "user_id"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    frame_id: Mapped[int] = mapped_column(
        sa.ForeignKey("frames.id", ondelete="CASCADE"), index=True
    )
    user_id: Mapped[int] = mapped_column(sa.ForeignKey("users.id", ondelete="CASCADE"), index=True)
    mask_path: Mapped[str | None] = mapped_column(sa.String(500))
    keypoints: Mapped[list[Any] | None] = mapped_column(JSONType)
    # Her objects of the other classes and her frame tags and attributes, as ``Label`` holds
    # them (NULL: the pool alone).
    objects: Mapped[list[Any] | None] = mapped_column(JSONType)
    frame_tags: Mapped[dict[str, Any] | None] = mapped_column(JSONType)
    created_at: Mapped[dt.datetime] = mapped_column(UTCDateTime, default=utcnow)
    updated_at: Mapped[dt.datetime | None] = mapped_column(UTCDateTime)


class ValidationKeypoints(Base):
    """Keypoints placed by hand; their frame is in the validation split."""

    __tablename__ = "validation_keypoints"

    id: Mapped[int] = mapped_column(primary_key=True)
    frame_id: Mapped[int] = mapped_column(
        sa.ForeignKey("frames.id", ondelete="CASCADE"), unique=True
    )
    keypoints: Mapped[list[Any]] = mapped_column(JSONType)
    user_id: Mapped[int | None] = mapped_column(sa.ForeignKey("users.id", ondelete="SET NULL"))
    updated_at: Mapped[dt.datetime] = mapped_column(UTCDateTime, default=utcnow)
    revision: Mapped[int] = mapped_column(default=1, server_default=sa.text("1"))
    """1 for the first keypoints, one more for each save after (a stale ``base_revision``: 409)."""


class ModelVersion(Base):
    """A trained student: its checkpoint, metrics and training curve."""

    __tablename__ = "model_versions"

    id: Mapped[int] = mapped_column(primary_key=True)
    name: Mapped[str] = mapped_column(sa.String(100), unique=True)
    checkpoint_path: Mapped[str | None] = mapped_column(sa.String(500))
    config: Mapped[dict[str, Any]] = mapped_column(JSONType, default=dict)
    metrics: Mapped[dict[str, Any]] = mapped_column(JSONType, default=dict)
    curve: Mapped[list[Any]] = mapped_column(JSONType, default=list)
    train_label_count: Mapped[int] = mapped_column(default=0)
    train_frame_ids: Mapped[list[int] | None] = mapped_column(JSONType, default=list)
    held_out_frame_ids: Mapped[list[int] | None] = mapped_column(JSONType, default=list)
    gate: Mapped[dict[str, Any] | None] = mapped_column(JSONType)  # app.training.gate's verdict
    sequential: Mapped[dict[str, Any] | None] = mapped_column(JSONType)  # its sequential cell
    int8: Mapped[dict[str, Any] | None] = mapped_column(JSONType)  # its int8 student
    is_promoted: Mapped[bool] = mapped_column(default=False, index=True)
    job_id: Mapped[int | None] = mapped_column(sa.ForeignKey("jobs.id", ondelete="SET NULL"))
    created_at: Mapped[dt.datetime] = mapped_column(UTCDateTime, default=utcnow)
    promoted_at: Mapped[dt.datetime | None] = mapped_column(UTCDateTime)


class DoomedFile(Base):
    """A stored file whose last naming row may have gone (a deletion, a replaced proposal),
    written in the same transaction: the collector looks at these files, not at the whole
    store (``app.core.housekeeping``)."""

    __tablename__ = "doomed_files"

    path: Mapped[str] = mapped_column(sa.String(500), primary_key=True)
    since: Mapped[dt.datetime] = mapped_column(UTCDateTime, default=utcnow)


STORED_PATH_COLUMNS = (
    Frame.path,
    Video.path,
    Proposal.mask_path,
    Proposal.heatmap_path,
    Label.mask_path,
    LabelRevision.mask_path,
    OverlapLabel.mask_path,
)
"""Every column that names a stored file under WELDPOOL_HOME (the store is content-addressed,
so one file may be named by several rows): what start-up sweeping and deletions consult."""


def _ids_never_reused() -> None:
    """SQLite hands the highest id out again after that row is deleted unless a table says
    AUTOINCREMENT (PostgreSQL's sequences never do): every table with an integer id says it, so
    a page still open on a deleted frame, run or job can never reach another's (migration 0018
    rebuilds the tables of an older database). A key the service picks itself
    (``autoincrement=False``, as ``LabelConfig.version``) is never handed out: none."""
    for table in Base.metadata.tables.values():
        key = list(table.primary_key.columns)
        if len(key) == 1 and isinstance(key[0].type, sa.Integer) and key[0].autoincrement:
            table.dialect_kwargs["sqlite_autoincrement"] = True


_ids_never_reused()


def get_frame(session: Session, frame_id: int) -> Frame:
    """A frame by id, or NotFoundError in one sentence: the one lookup every domain uses."""
    frame = session.get(Frame, frame_id)
    if frame is None:
        raise NotFoundError(f"There is no frame {frame_id}.")
    return frame


def _history(row: Any, name: str) -> Any:
    """An attribute's pending changes, unloaded ones not loaded (``inspect().attrs`` builds all)."""
    return sa.orm.attributes.get_history(row, name, sa.orm.base.PASSIVE_NO_INITIALIZE)


def _changed_runs(session: Any) -> tuple[set[int], set[int]]:
    """The runs and the frames whose pending changes move a signature: labels, their revisions
    and proposals added, changed or deleted; frames added, deleted, moved or re-timed; a run's
    scale changed."""
    frames: set[int] = set()
    runs: set[int] = set()
    for row in (*session.new, *session.dirty, *session.deleted):
        if isinstance(row, (Label, LabelRevision, Proposal)) and row.frame_id is not None:
            frames.add(row.frame_id)
        elif isinstance(row, Sequence) and _history(row, "mm_per_px").has_changes():
            runs.add(row.id)
        elif isinstance(row, Frame):
            names = ("sequence_id", "frame_index", "timestamp_s")
            moved = any(_history(row, name).has_changes() for name in names)
            if row in session.new or row in session.deleted or moved:
                runs.update(
                    run
                    for run in (row.sequence_id, *_history(row, "sequence_id").deleted)
                    if run is not None
                )
    return runs, frames


@sa.event.listens_for(Session, "before_flush")
def _signatures_go_stale(session: Any, _context: Any, _instances: Any) -> None:
    """Mark the signatures of the runs a flush changes stale, in the same transaction (bulk
    label updates and proposal deletions always come with a new revision or proposal row,
    which this sees; a bulk frame deletion is ``_frames_deleted``'s)."""
    runs, frames = _changed_runs(session)
    if not (runs or frames) or not has_table(session, RunSignature.__tablename__):
        return
    where: sa.ColumnElement[bool] = RunSignature.sequence_id.in_(runs)
    if frames:
        owners = sa.select(Frame.sequence_id).where(Frame.id.in_(frames))
        where = sa.or_(where, RunSignature.sequence_id.in_(owners))
    with session.no_autoflush:
        session.execute(
            sa.update(RunSignature).where(where, ~RunSignature.stale).values(stale=True)
        )


@sa.event.listens_for(Session, "do_orm_execute")
def _frames_deleted(state: Any) -> None:
    """A bulk frame deletion (``app.frames.deletion``) may touch any run: every signature goes
    stale (deletions are rare; each run is computed again once, when read)."""
    if not state.is_delete or state.bind_mapper is None or state.bind_mapper.class_ is not Frame:
        return
    if has_table(state.session, RunSignature.__tablename__):
        state.session.execute(sa.update(RunSignature).where(~RunSignature.stale).values(stale=True))
