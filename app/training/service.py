"""Model versions of the student: listing, promotion, and the training set from reviewed labels."""

from __future__ import annotations

from collections.abc import Collection, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import sqlalchemy as sa
from sqlalchemy.orm import Session

from app.core.db import updated_one, utcnow
from app.core.errors import ConflictError, InvalidInputError, MissingFile, NotFoundError
from app.core.frame_rows import frame_exists
from app.core.models import (
    Frame,
    Job,
    JobStatus,
    Label,
    LabelRevision,
    LabelStatus,
    ModelVersion,
    Proposal,
    ReviewState,
    Split,
    ValidationKeypoints,
    Video,
)
from app.frames.listing import UNREVIEWED, unreviewed_frame_ids
from app.jobs.service import create_job
from app.storage import Storage
from app.storage.pixels import frame_rgb, load_mask
from app.system.doctor import frame_file_missing

if TYPE_CHECKING:
    import numpy as np
    from numpy.typing import NDArray
else:
    from weldpool_core.lazy import np

TRAINABLE = (LabelStatus.accepted, LabelStatus.corrected)
TRAINABLE_LABEL = sa.and_(
    Label.status.in_(TRAINABLE),
    sa.or_(Label.review.is_(None), Label.review == ReviewState.approved),
)
"""A label the student learns from: accepted or corrected, and approved when the review stage
asked for it (awaiting or returned ones wait)."""


def trainable(label: Label | None) -> bool:
    """``TRAINABLE_LABEL`` of one loaded label."""
    return (
        label is not None
        and label.status in TRAINABLE
        and label.review in (None, ReviewState.approved)
    )


TRAIN_KIND = "train_student"
SEQUENTIAL_KIND = "train_sequential"
QUANTIZE_KIND = "quantize_student"
STUDENT_RUN_KIND = "student"
PROMOTED_RUN = "after_promotion"
"""The parameter that marks the run a promotion queued (``queue_promoted_run``)."""
CALIBRATION_FRAMES = 64
"""Frames an int8 student is calibrated and checked on (spread over the project's frames)."""
UNLABELLED_WINDOWS = 96
"""Unlabelled windows over all videos (at least 8 a video), half for the sequential cell's
steadiness term and half to measure it on; a window's 8 frames are kept at the student's input
size (64 KB each at 256²), so this bounds the job's memory as videos are added (~50 MB)."""


def list_models(session: Session) -> list[ModelVersion]:
    return list(session.scalars(sa.select(ModelVersion).order_by(ModelVersion.id.desc())))


def get_model(session: Session, model_id: int) -> ModelVersion:
    """A model version by id, or NotFoundError in one sentence: the one lookup routes and jobs
    use (a job whose version was deleted fails with the same sentence)."""
    model = session.get(ModelVersion, model_id)
    if model is None:
        raise NotFoundError(f"There is no model version {model_id}.")
    return model


def promoted_model(session: Session) -> ModelVersion | None:
    return session.scalar(sa.select(ModelVersion).where(ModelVersion.is_promoted.is_(True)))


def promote(session: Session, model: ModelVersion) -> ModelVersion:
    """Make ``model`` the student that proposes for new frames (one promoted at a time)."""
    session.execute(sa.update(ModelVersion).values(is_promoted=False))
    model.is_promoted, model.promoted_at = True, utcnow()
    session.commit()
    session.refresh(model)
    return model


def next_name(session: Session) -> str:
    count = session.scalar(sa.select(sa.func.count()).select_from(ModelVersion)) or 0
    return f"student-v{count + 1}"


def free_name(session: Session, models_dir: Path) -> str:
    """The next ``student-vN`` whose folder is free (a crash may leave one behind)."""
    name = next_name(session)
    number = int(name.removeprefix("student-v"))
    while (models_dir / name).exists() or session.scalar(
        sa.select(ModelVersion.id).where(ModelVersion.name == name)
    ):
        number += 1
        name = f"student-v{number}"
    return name


def training_frame_ids(session: Session) -> list[int]:
    """Frames with a trainable label (``TRAINABLE_LABEL``), outside the validation split."""
    return list(
        session.scalars(
            sa.select(Frame.id)
            .join(Label, Label.frame_id == Frame.id)
            .where(TRAINABLE_LABEL, Frame.split != Split.validation)
            .order_by(Frame.id)
        )
    )


def validation_frame_ids(session: Session) -> list[int]:
    """Validation frames that have a reviewed mask or manual keypoints."""
    labelled = sa.select(Label.frame_id).where(TRAINABLE_LABEL)
    manual = sa.select(ValidationKeypoints.frame_id)
    return list(
        session.scalars(
            sa.select(Frame.id)
            .where(Frame.split == Split.validation, Frame.id.in_(labelled.union(manual)))
            .order_by(Frame.id)
        )
    )


def existing_frame_ids(session: Session, frame_ids: list[int]) -> list[int]:
    """Those of ``frame_ids`` whose frames are still there."""
    found: set[int] = set()
    for start in range(0, len(frame_ids), 500):
        chunk = frame_ids[start : start + 500]
        found.update(session.scalars(sa.select(Frame.id).where(Frame.id.in_(chunk))))
    return [f for f in frame_ids if f in found]


FETCH_AHEAD = 16
"""Frames whose files (image, label mask) a training set's reading asks the store for ahead."""


def _stored_paths(session: Session, frame_ids: list[int], with_images: bool) -> list[str]:
    """The stored files a training set reads of these frames: their label masks, and their
    images when ``with_images``."""
    if not frame_ids:
        return []
    masks = sa.select(Label.mask_path).where(
        Label.frame_id.in_(frame_ids), Label.mask_path.is_not(None)
    )
    paths = [p for p in session.scalars(masks) if p]
    if with_images:
        paths += session.scalars(sa.select(Frame.path).where(Frame.id.in_(frame_ids)))
    return paths


def labelled_samples(
    session: Session,
    storage: Storage,
    frame_ids: list[int],
    with_images: bool = True,
    skipped: list[tuple[int, str]] | None = None,
) -> Iterator[tuple[int, NDArray[np.uint8] | None, NDArray[np.bool_] | None, Any]]:
    """(frame id, RGB image or None, reviewed mask or None, keypoints or None) for each frame.

    Keypoints: the manual validation keypoints when there are some, else the label's.
    Frames deleted since their ids were read are left out; so are frames whose image or mask
    the store lost when ``skipped`` is given (each listed there with what restores its file),
    else such a frame's MissingFile is raised.
    """
    for index, frame_id in enumerate(frame_ids):
        if index % FETCH_AHEAD == 0:  # the next frames' files come while these are read
            start = index + FETCH_AHEAD if index else 0
            ahead = frame_ids[start : index + 2 * FETCH_AHEAD]
            storage.fetch_ahead(_stored_paths(session, ahead, with_images))
        frame = session.get(Frame, frame_id)
        if frame is None:
            continue
        label = session.scalar(sa.select(Label).where(Label.frame_id == frame_id))
        manual = session.scalar(
            sa.select(ValidationKeypoints).where(ValidationKeypoints.frame_id == frame_id)
        )
        mask = None
        try:
            if label is not None and trainable(label) and label.mask_path:
                mask = load_mask(storage, label.mask_path)
            image = frame_rgb(storage, frame) if with_images else None
            if skipped is not None and not with_images:
                storage.existing(frame.path)  # a frame left out is one whose image is lost too
        except MissingFile as missing:
            if not frame_exists(session, frame_id):
                continue  # its files went with the frame, deleted meanwhile
            kind = "image" if missing.path == frame.path else "label mask"
            lost = frame_file_missing(missing, frame_id, kind)
            if skipped is None:
                raise lost from None
            skipped.append((frame_id, lost.message))
            continue
        keypoints = manual.keypoints if manual else (label.keypoints if label else None)
        yield frame_id, image, mask, keypoints


def teacher_confidence(scores: dict[str, Any]) -> float | None:
    """How sure the teacher is of a proposal: SAM2's predicted IoU times its prompt stability
    (the present ones; None when neither is)."""
    parts = [scores.get("sam2_iou"), scores.get("prompt_stability")]
    present = [float(p) for p in parts if p is not None]
    return float(np.prod(present)) if present else None


def pseudo_label_proposals(session: Session, min_confidence: float) -> list[tuple[Proposal, float]]:
    """The teacher's newest proposal on each frame nobody has labelled (outside the validation
    split) whose confidence (``teacher_confidence``) is at least ``min_confidence``, with that
    confidence. Only the teacher's: a student's unverified output is never a training target."""
    newest = (
        sa.select(sa.func.max(Proposal.id))
        .join(Frame, Frame.id == Proposal.frame_id)
        .where(
            Proposal.source == "teacher",
            Frame.split != Split.validation,
            Proposal.frame_id.not_in(sa.select(Label.frame_id)),
        )
        .group_by(Proposal.frame_id)
    )
    chosen = []
    for proposal in session.scalars(
        sa.select(Proposal).where(Proposal.id.in_(newest)).order_by(Proposal.frame_id)
    ):
        confidence = teacher_confidence(proposal.scores)
        if confidence is not None and confidence >= min_confidence:
            chosen.append((proposal, confidence))
    return chosen


def queue_promoted_run(session: Session, queue: Any, model: ModelVersion, user: Any) -> Job | None:
    """The promoted student's run over the unreviewed frames (proposals and uncertainty for the
    queue), queued at most once: a run that an earlier promotion queued and no worker has
    started yet is handed to ``model`` and today's unreviewed frames instead of queuing another
    (a worker reads a job's parameters when it claims it), and a run of ``model`` already
    running is the run (promoting the promoted version again). None when no frame awaits
    review."""
    frames = len(unreviewed_frame_ids(session))
    if not frames:
        return None
    params = {
        "scope": UNREVIEWED,  # read when it starts: the frames still to review then
        "frames": frames,
        "model_version_id": model.id,
        PROMOTED_RUN: True,
    }
    waiting = session.scalars(
        sa.select(Job)
        .where(
            Job.kind == STUDENT_RUN_KIND,
            Job.status.in_([JobStatus.queued, JobStatus.running]),
        )
        .order_by(Job.id)
    )
    for job in list(waiting):
        if not (job.params or {}).get(PROMOTED_RUN):
            continue  # a run a user asked for, on frames of their choice
        if job.status == JobStatus.running:
            if job.params.get("model_version_id") == model.id:
                return job  # this version's run is running: not a second one beside it
            continue
        handed = updated_one(
            session,
            sa.update(Job)
            .where(Job.id == job.id, Job.status == JobStatus.queued)
            .values(params=params),
        )
        session.commit()
        if handed:
            session.refresh(job)
            return job
    return create_job(session, queue, STUDENT_RUN_KIND, params, user)


def labels_since_last_training(session: Session) -> int:
    """Accepted or corrected label changes made since the newest training job was created."""
    last = session.scalar(sa.select(sa.func.max(Job.created_at)).where(Job.kind == TRAIN_KIND))
    query = (
        sa.select(sa.func.count())
        .select_from(LabelRevision)
        .where(LabelRevision.status.in_(TRAINABLE))
    )
    if last is not None:
        query = query.where(LabelRevision.created_at > last)
    return int(session.scalar(query) or 0)


def maybe_retrain(session: Session, queue: Any, every: int, user: Any) -> Job | None:
    """Start a training job after ``every`` new reviewed labels (0: never), unless one is
    queued or running — the database guarantees there is never a second one."""

    if every <= 0 or labels_since_last_training(session) < every:
        return None
    if not training_frame_ids(session):
        return None
    try:
        return create_job(session, queue, TRAIN_KIND, {"automatic": True}, user)
    except ConflictError:
        return None


HELD_OUT_FRACTION = 0.2
MIN_TO_HOLD_OUT = 3


def held_out_ids(session: Session, frame_ids: list[int]) -> list[int]:
    """Training frames kept out of training to measure the version when the validation split is
    empty: a fifth of them (at least one, from ``MIN_TO_HOLD_OUT`` frames on), chosen by content
    hash so the same frames stay out as labels are added."""
    if len(frame_ids) < MIN_TO_HOLD_OUT:
        return []
    count = max(1, round(HELD_OUT_FRACTION * len(frame_ids)))
    rows = session.execute(sa.select(Frame.id, Frame.sha256).where(Frame.id.in_(frame_ids)))
    ranked = sorted(rows, key=lambda row: row.sha256)
    return sorted(row.id for row in ranked[:count])


@dataclass(frozen=True)
class TrainingPlan:
    """What a training job started now would learn from and be measured on."""

    labels: int
    validation_frames: int
    held_out: int
    needed: int
    warning: str | None


def training_plan(session: Session) -> TrainingPlan:
    """The labels a training would take, the frames its version would be measured on (the
    validation split's, else labels held out by ``held_out_ids``), and a warning when there
    are too few for the promotion gate to measure it: it could then only be promoted by force."""
    train = training_frame_ids(session)
    validation = len(validation_frame_ids(session))
    held_out = 0 if validation else len(held_out_ids(session, train))
    needed = 1 if validation else MIN_TO_HOLD_OUT
    warning = None
    if not train:
        warning = (
            "There are no accepted or corrected labels outside the validation split to train on."
        )
    elif not validation and not held_out:
        warning = (
            f"Only {_labels(len(train))} to train on and no frame in the validation split: the "
            f"promotion gate measures a version on labels held out from its training, which "
            f"takes at least {MIN_TO_HOLD_OUT} labels (or one validation frame), so this version "
            "could not be measured and could only be promoted by force; label more frames first."
        )
    return TrainingPlan(len(train) - held_out, validation, held_out, needed, warning)


def _labels(count: int) -> str:
    return f"{count} label" + "s" * (count != 1)


def model_folder(storage: Storage, model: ModelVersion) -> Path:
    """A version's folder of weights, complete on this machine (fetched from the object store
    when it has not seen it), or a 409 when the instance has none."""
    folder = storage.folder(model.checkpoint_path) if model.checkpoint_path else None
    if folder is None:
        raise ConflictError(f"{model.name} has no weights on this server.")
    return folder


def require_weights(storage: Storage, model: ModelVersion) -> None:
    """A 409 when a version has no weights, looked up without fetching them."""
    if not (model.checkpoint_path and storage.has_folder(model.checkpoint_path)):
        raise ConflictError(f"{model.name} has no weights on this server.")


def has_video_labels(session: Session) -> bool:
    """Whether a frame of an imported video outside the validation split has a reviewed label."""
    query = (
        sa.select(Frame.id)
        .join(Label, Label.frame_id == Frame.id)
        .where(
            TRAINABLE_LABEL,
            Frame.video_id.is_not(None),
            Frame.split != Split.validation,
        )
        .limit(1)
    )
    return session.scalar(query) is not None


def active_job(session: Session, kind: str) -> Job | None:
    """The queued or running job of ``kind`` (one at a time: ``ONE_AT_A_TIME``), if any."""

    return session.scalar(
        sa.select(Job).where(
            Job.kind == kind, Job.status.in_((JobStatus.queued, JobStatus.running))
        )
    )


def calibration_frame_ids(session: Session, count: int = CALIBRATION_FRAMES) -> list[int]:
    """Up to ``count`` frames spread evenly over the project's frames (by id): the cameras and
    conditions an int8 student will see, reviewed or not."""
    from weldpool_core.video import spread_evenly

    return spread_evenly(list(session.scalars(sa.select(Frame.id).order_by(Frame.id))), count)


@dataclass(frozen=True)
class VideoClips:
    """The reviewed frames of imported videos, one clip per video, for the sequential cell.

    ``train``: the training split's labels and half of each video's unlabelled windows (none
    that holds a validation frame); ``check``: the validation split's labels and the other half
    of the windows, interleaved with the first (disjoint where the video is long enough): what
    the cell is measured on and never trained on.
    """

    train: list[Any]
    check: list[Any]


def video_clips(
    session: Session,
    storage: Storage,
    config: Any,
    exclude: Collection[int] = (),
    student: Any = None,
) -> VideoClips:
    """``VideoClips`` of every video with a reviewed mask (``config``: a SequentialConfig).
    With ``student`` (the version's StudentConfig), window frames are kept at its input size.

    Each video is decoded once from its stored file, so the cell sees the camera's own frame
    rate even where only every n-th frame was imported. ``exclude``: frames the version was
    trained on, never measured on (one moved to the validation split since). A video whose file
    is gone is a one-sentence error.
    """
    from dataclasses import replace

    from weldpool_core.student.sequential import unlabelled_ends, video_clip
    from weldpool_core.student.train import as_training_frame
    from weldpool_core.video import probe_video

    rows = session.execute(
        sa.select(Frame.id, Frame.video_id, Frame.frame_index, Frame.split)
        .join(Label, Label.frame_id == Frame.id)
        .where(TRAINABLE_LABEL, Frame.video_id.is_not(None))
        .order_by(Frame.video_id, Frame.frame_index)
    ).all()
    by_video: dict[int, list[Any]] = {}
    for row in rows:
        by_video.setdefault(int(row.video_id), []).append(row)
    clips = VideoClips([], [])
    share = max(8, UNLABELLED_WINDOWS // max(1, len(by_video)))
    for video_id, labelled in by_video.items():
        video = session.get_one(Video, video_id)
        path = storage.absolute(video.path)
        if not path.is_file():
            raise InvalidInputError(
                f"The stored file of video {video.original_name} is missing; import it again."
            )
        samples = labelled_samples(session, storage, [r.id for r in labelled])
        frames = {
            int(row.frame_index): as_training_frame((image, mask, keypoints), frame_id)
            for row, (frame_id, image, mask, keypoints) in zip(labelled, samples, strict=True)
            if image is not None and mask is not None
        }
        if not frames:
            continue
        validation = {int(r.frame_index) for r in labelled if r.split == Split.validation}
        measured = {
            int(r.frame_index)
            for r in labelled
            if r.split == Split.validation and r.id not in exclude
        }
        ends = unlabelled_ends(
            probe_video(path).frame_count, replace(config, unlabelled_windows=share)
        )
        learned = [e for e in ends[0::2] if not any(e - config.window < v <= e for v in validation)]
        clip = video_clip(
            path, frames, config, unlabelled=learned + list(ends[1::2]), student=student
        )
        readable = set(clip.unlabelled)
        clips.train.append(
            replace(
                clip,
                labels={i: f for i, f in frames.items() if i not in validation},
                unlabelled=tuple(e for e in learned if e in readable),
            )
        )
        clips.check.append(
            replace(
                clip,
                labels={i: f for i, f in frames.items() if i in measured},
                unlabelled=tuple(e for e in ends[1::2] if e in readable),
            )
        )
    return clips
