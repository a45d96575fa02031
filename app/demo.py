"""`weldpool demo`: a synthetic weld run in a fresh instance, so a new user sees the whole loop.

The labels it adds come from the generator's ground truth and are recorded as the `demo`
user's (status accepted), clearly apart from anyone's real review.
"""

from __future__ import annotations

import secrets
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import sqlalchemy as sa
from sqlalchemy.orm import Session, sessionmaker

from app.core.config import Settings
from app.core.models import LabelStatus, Role, User
from app.core.security import MADE_PASSWORD_BYTES
from app.frames.ingest import IncomingFile, ingest_frames
from app.frames.sequences import create_sequence, unique_sequence_name
from app.jobs.queue import JobQueue
from app.jobs.service import create_job
from app.review.service import save_label, save_validation_keypoints
from app.storage import Storage
from app.users.service import create_user
from weldpool_core.io import encode_mask_png
from weldpool_core.synth import synth_sequence
from weldpool_core.teacher.prompt_names import DEFAULT_PROMPTS
from weldpool_core.teacher.weights import weights_status

if TYPE_CHECKING:
    import cv2
else:
    from weldpool_core.lazy import cv2

DEMO_USER = "demo"


DEMO_RUN = {
    "wire_feed_m_min": 8.0,
    "voltage_v": 22.5,
    "current_a": 180.0,
    "arc_length_correction_pct": 0.0,
    "robot_speed_cm_min": 40.0,
    "joint_type": "fillet",
    "notes": "Synthetic frames from weldpool_core.synth (`weldpool demo`).",
}
"""The demo run's process parameters."""


def _demo_user(session: Session) -> User:
    found = session.scalar(sa.select(User).where(User.username == DEMO_USER))
    return found or create_user(
        session, DEMO_USER, secrets.token_urlsafe(MADE_PASSWORD_BYTES), Role.reviewer, made=True
    )


def _label_frames(
    session: Session, storage: Storage, user: User, stored: list[Any], drawn: list[Any]
) -> tuple[int, int, list[int]]:
    """Three frames in four labelled from the ground truth, one of them held out for
    validation with its mask (so the gate measures a student on merit); the fourth is left to
    the teacher. Returns the labelled and validation counts and the unlabelled frames."""
    labelled = validation = 0
    unlabelled = []
    for index, (frame, truth) in enumerate(zip(stored, drawn, strict=True)):
        keypoints = [[float(x), float(y)] for x, y in truth.keypoints]
        if index % 4 == 3:
            unlabelled.append(frame.id)
            continue
        save_label(
            session,
            storage,
            frame,
            user,
            status=LabelStatus.accepted,
            base_revision=0,
            mask_png=encode_mask_png(truth.mask),
            keypoints=keypoints,
        )
        labelled += 1
        if index % 4 == 1:
            save_validation_keypoints(session, frame, user, keypoints)
            validation += 1
    return labelled, validation, unlabelled


def _teacher_for(session: Session, settings: Settings, user: User, unlabelled: list[int]) -> str:
    """The teacher queued for the unlabelled frames where its weights are here; the summary's
    last sentence either way."""
    ready = all(
        weights_status(ref, var).available
        for ref, var in ((settings.dino, "WELDPOOL_DINO"), (settings.sam2, "WELDPOOL_SAM2"))
    )
    if ready and unlabelled:
        factory = sessionmaker(session.get_bind(), expire_on_commit=False)
        job = create_job(
            session,
            JobQueue(settings, factory),
            "teacher",
            {"frame_ids": unlabelled, "prompts": DEFAULT_PROMPTS},
            user,
        )
        return f" Teacher job {job.id} queued for the other {len(unlabelled)} frames."
    return (
        " The teacher's weights are not here: run `weldpool weights fetch` (or set "
        "WELDPOOL_DINO / WELDPOOL_SAM2), then start the teacher from the UI."
    )


def fill_demo(
    session: Session,
    settings: Settings,
    *,
    frames: int,
    seed: int,
    progress: Callable[[str], None],
) -> str:
    """Add the synthetic run; returns a one-paragraph summary of what was added."""
    user = _demo_user(session)
    name = unique_sequence_name(session, "demo weld run (synthetic)")
    sequence = create_sequence(session, {"name": name, **DEMO_RUN}, user)
    progress(f"drawing {frames} synthetic frames")
    drawn = synth_sequence(seed=seed, length=frames)
    files = [
        IncomingFile(f"demo_{i:04d}.png", cv2.imencode(".png", f.image)[1].tobytes())
        for i, f in enumerate(drawn)
    ]
    storage = Storage.of(settings)
    stored = ingest_frames(
        session,
        storage,
        files,
        sequence_id=sequence.id,
        user=user,
        max_pixels=settings.max_image_pixels,
    ).stored
    labelled, validation, unlabelled = _label_frames(session, storage, user, stored, drawn)
    summary = (
        f"demo: sequence {sequence.name!r} with {len(stored)} frames; {labelled} labelled "
        f"from ground truth, {validation} of them held out for validation (mask and keypoints)."
    )
    return summary + _teacher_for(session, settings, user, unlabelled)
