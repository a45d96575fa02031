"""/api/v1/student and /api/v1/models: training jobs, model versions, promotion."""

from __future__ import annotations

from dataclasses import asdict

from fastapi import APIRouter, status

from app.core.bounds import IdPath
from app.core.deps import QueueDep, SessionDep, SettingsDep, StorageDep
from app.core.errors import ConflictError, InvalidInputError
from app.core.security import CurrentUser, ReviewerUser
from app.frames.listing import run_scope
from app.jobs.schemas import JobCreated
from app.jobs.service import create_job
from app.training import gate, service
from app.training.schemas import (
    ModelVersionOut,
    SequentialIn,
    StudentRunIn,
    TrainCreated,
    TrainIn,
    TrainingPlanOut,
)
from weldpool_core.student.quantize import MIN_FRAMES

router = APIRouter(tags=["training"])


@router.get("/student/training-plan", response_model=TrainingPlanOut)
def training_plan(session: SessionDep, _user: CurrentUser) -> TrainingPlanOut:
    """What a training started now would learn from and be measured on, with a warning when
    the promotion gate could not measure the version (too few labels)."""
    return TrainingPlanOut(**asdict(service.training_plan(session)))


@router.post(
    "/student/train",
    response_model=TrainCreated,
    status_code=status.HTTP_202_ACCEPTED,
    responses={
        400: {"description": "No reviewed label to train on."},
        409: {"description": "A training job is already queued or running."},
    },
)
def train(body: TrainIn, session: SessionDep, queue: QueueDep, user: ReviewerUser) -> TrainCreated:
    """Train a new student version on the accepted and corrected labels, in a worker job; the
    answer carries the training plan (`warning` when the version could not be measured)."""
    plan = service.training_plan(session)
    if not plan.labels + plan.held_out:
        raise InvalidInputError(plan.warning or "There is nothing to train on.")
    job = create_job(session, queue, service.TRAIN_KIND, body.model_dump(), user)
    return TrainCreated(job_id=job.id, **asdict(plan))


@router.post("/student/runs", response_model=JobCreated, status_code=status.HTTP_202_ACCEPTED)
def student_run(
    body: StudentRunIn, session: SessionDep, queue: QueueDep, user: CurrentUser
) -> JobCreated:
    """The promoted student proposes masks and scores uncertainty for frames, in a worker job."""
    model = service.promoted_model(session)
    if model is None:
        raise InvalidInputError("No student is promoted yet; train one and promote it.")
    scope, listed = run_scope(session, body.frame_ids, body.sequence_id)
    params = {"model_version_id": model.id} | scope
    job = create_job(session, queue, "student", params, user, frame_ids=listed)
    return JobCreated(job_id=job.id)


@router.get("/models", response_model=list[ModelVersionOut])
def list_models(session: SessionDep, _user: CurrentUser) -> list[ModelVersionOut]:
    """Student versions, newest first, with their metrics and training curves."""
    return [ModelVersionOut.model_validate(m) for m in service.list_models(session)]


@router.get("/models/{model_id}", response_model=ModelVersionOut)
def get_model(model_id: IdPath, session: SessionDep, _user: CurrentUser) -> ModelVersionOut:
    return ModelVersionOut.model_validate(service.get_model(session, model_id))


@router.post(
    "/models/{model_id}/sequential",
    response_model=JobCreated,
    status_code=status.HTTP_202_ACCEPTED,
    responses={
        409: {
            "description": "A sequential cell is already training, or the version has no "
            "weights on this server."
        }
    },
)
def train_sequential(
    model_id: IdPath,
    body: SequentialIn,
    session: SessionDep,
    storage: StorageDep,
    queue: QueueDep,
    user: ReviewerUser,
) -> JobCreated:
    """Train this version's sequential cell (steadier keypoints in live views) on the reviewed
    frames of imported videos, in a worker job; the job measures it against the per-frame
    student and the version records the measurement (`sequential`)."""
    model = service.get_model(session, model_id)
    service.require_weights(storage, model)
    if not service.has_video_labels(session):
        raise InvalidInputError(
            "No reviewed frame of the training split comes from an imported video; label frames "
            "of a video to train the sequential cell."
        )
    running = service.active_job(session, service.SEQUENTIAL_KIND)
    if running is not None:
        raise ConflictError(
            f"A sequential cell is already training (job #{running.id}); wait for it to finish."
        )
    params = body.model_dump() | {"model_version_id": model.id}
    job = create_job(session, queue, service.SEQUENTIAL_KIND, params, user)
    return JobCreated(job_id=job.id)


@router.post(
    "/models/{model_id}/int8",
    response_model=JobCreated,
    status_code=status.HTTP_202_ACCEPTED,
    responses={
        409: {
            "description": "An int8 student is already being made, or the version has no "
            "weights on this server."
        }
    },
)
def make_int8(
    model_id: IdPath,
    session: SessionDep,
    storage: StorageDep,
    queue: QueueDep,
    user: ReviewerUser,
) -> JobCreated:
    """Make this version's int8 student (ONNX Runtime's static quantization: about 1.5–3×
    faster on a CPU) in a worker job, calibrated on frames spread over the project and kept
    only when its masks agree with the float student's on others; the version records the
    agreement and both speeds (`int8`), and live views can run it."""
    model = service.get_model(session, model_id)
    service.require_weights(storage, model)
    frames = service.calibration_frame_ids(session)
    if len(frames) < MIN_FRAMES:
        raise InvalidInputError(
            f"An int8 student is calibrated on frames of your camera; upload at least "
            f"{MIN_FRAMES} frames first ({len(frames)} so far)."
        )
    running = service.active_job(session, service.QUANTIZE_KIND)
    if running is not None:
        raise ConflictError(
            f"An int8 student is already being made (job #{running.id}); wait for it to finish."
        )
    job = create_job(session, queue, service.QUANTIZE_KIND, {"model_version_id": model.id}, user)
    return JobCreated(job_id=job.id)


@router.post(
    "/models/{model_id}/promote",
    response_model=ModelVersionOut,
    responses={
        409: {"description": "The promotion gate found the version worse than the teacher."}
    },
)
def promote(
    model_id: IdPath,
    session: SessionDep,
    storage: StorageDep,
    settings: SettingsDep,
    queue: QueueDep,
    user: ReviewerUser,
    force: bool = False,
) -> ModelVersionOut:
    """Make this version the student that proposes for frames and scores the queue. The gate
    measures it first, now, against the promoted version and the teacher; a version it finds
    unusable is refused (409) unless `force=true`. Queues a student run on the unreviewed frames
    (one: a run an earlier promotion queued that has not started yet runs this version instead).
    """
    model = service.get_model(session, model_id)
    verdict = gate.measure(
        session, storage, model, service.promoted_model(session), settings.device
    )
    model.gate = verdict
    session.commit()
    if not verdict["usable"] and not force:
        refused = ConflictError(
            f"{model.name} was not promoted: {verdict['reason'].removeprefix('Not promoted: ')} "
            "Promote with force=true to use it anyway; the review keeps showing the teacher's "
            "proposals while they agree better with the labels."
        )
        refused.extra = {"reason": verdict["reason"].removeprefix("Not promoted: ")}  # type: ignore[attr-defined]
        raise refused
    model = service.promote(session, model)
    service.queue_promoted_run(session, queue, model, user)
    return ModelVersionOut.model_validate(model)
