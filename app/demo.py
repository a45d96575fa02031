"""`weldpool demo`: a synthetic weld run in a fresh instance, so a new user sees the whole loop.

The labels it adds come from the generator's ground truth and are recorded as the `demo`
user's (status accepted), clearly apart from anyone's real review.
"""

from __future__ import annotations

import math
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
from app.storage import Storage, open_storage
from app.users.service import create_user
from weldpool_core.cell.plant import PlantCamera, PlantParams
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


PROCESS_RUNS = (
    # (voltage V, current A, travel speed cm/min): heat inputs from about 420 to 860 J/mm
    (20.0, 150.0, 50.0),
    (21.0, 165.0, 45.0),
    (22.5, 180.0, 40.0),
    (23.5, 195.0, 37.0),
    (24.5, 210.0, 34.0),
    (25.5, 225.0, 31.0),
)
"""The process-map runs' parameters; the fourth one oscillates (``OSCILLATING``)."""
OSCILLATING = 3
PROCESS_FPS = 15.0
OSCILLATION_HZ = 3.0


def _process_widths(plant: PlantParams, run: int, frames: int) -> list[float]:
    """One run's pool width per frame: the plant's steady width for the run's power and speed,
    reached with its lag from 70 % of it (the run-in after the arc starts: the same share on every
    run, so the law between runs holds); on the oscillating run a 3 Hz humping of ±15 % over the
    middle third."""
    volts, amps, speed = PROCESS_RUNS[run]
    steady = plant.steady_width(volts * amps, speed / 6.0)
    widths = [
        steady * (1.0 - 0.3 * math.exp(-i / PROCESS_FPS / plant.tau_s)) for i in range(frames)
    ]
    if run == OSCILLATING:
        for i in range(frames // 3, 2 * frames // 3):
            widths[i] *= 1.0 + 0.15 * math.sin(2 * math.pi * OSCILLATION_HZ * i / PROCESS_FPS)
    return widths


def fill_process_runs(
    session: Session, settings: Settings, *, frames: int, progress: Callable[[str], None]
) -> str:
    """Weld runs at different heat inputs for the process map, each labelled from the plant's
    pool (``weldpool_core.cell.plant``: width from Rosenthal's √(heat input), with its lag), one of
    them oscillating; returns a one-sentence summary."""
    user = _demo_user(session)
    storage = open_storage(settings)
    nominal = PROCESS_RUNS[2]
    plant = PlantParams(power_w=nominal[0] * nominal[1], speed_mm_s=nominal[2] / 6.0)
    camera = PlantCamera(plant, seed=5)
    for run, (volts, amps, speed) in enumerate(PROCESS_RUNS):
        progress(f"drawing process run {run + 1} of {len(PROCESS_RUNS)}")
        name = unique_sequence_name(
            session, f"process run {run + 1}: {volts:g} V, {amps:g} A, {speed:g} cm/min"
        )
        values = {"name": name, **DEMO_RUN, "voltage_v": volts, "current_a": amps}
        values |= {"robot_speed_cm_min": speed, "mm_per_px": camera.mm_per_px}
        sequence = create_sequence(session, values, user)
        drawn = [
            camera.render(width, i / PROCESS_FPS)
            for i, width in enumerate(_process_widths(plant, run, frames))
        ]
        files = [
            IncomingFile(f"run{run + 1}_{i:04d}.png", cv2.imencode(".png", f.image)[1].tobytes())
            for i, f in enumerate(drawn)
        ]
        stored = ingest_frames(
            session, storage, files, sequence_id=sequence.id, user=user,
            max_pixels=settings.max_image_pixels,
        ).stored  # fmt: skip
        for i, (frame, truth) in enumerate(zip(stored, drawn, strict=True)):
            frame.frame_index, frame.timestamp_s = i, i / PROCESS_FPS
            save_label(
                session, storage, frame, user, status=LabelStatus.accepted, base_revision=0,
                mask_png=encode_mask_png(truth.mask),
                keypoints=[[float(x), float(y)] for x, y in truth.keypoints],
            )  # fmt: skip
    return (
        f" {len(PROCESS_RUNS)} process runs at heat inputs from "
        f"{min(v * a / (s / 6) for v, a, s in PROCESS_RUNS):.0f} to "
        f"{max(v * a / (s / 6) for v, a, s in PROCESS_RUNS):.0f} J/mm for the process map "
        f"(/process), run {OSCILLATING + 1} oscillating at {OSCILLATION_HZ:g} Hz."
    )


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
    storage = open_storage(settings)
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
