"""Background work of the training domain: training a student version, and the promoted
student's proposals and uncertainty scores."""

from __future__ import annotations

import shutil
from dataclasses import replace
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any

import sqlalchemy as sa
import structlog

from app.core.db import utcnow
from app.core.errors import MissingFile
from app.core.frame_rows import FrameDeleted, frame_exists
from app.core.models import Frame, Job, ModelVersion
from app.frames.listing import scope_frames
from app.jobs.fanout import Fanout
from app.jobs.registry import JobContext, counted, job_handler
from app.proposals.queue import latest_teacher_proposal
from app.proposals.record import STUDENT, record_proposal
from app.storage import Storage, best_effort, open_storage
from app.storage.pixels import frame_rgb, load_mask
from app.training import gate, service
from app.training.classes import with_classes
from weldpool_core.active import disagreement as teacher_disagreement
from weldpool_core.errors import InvalidInputError

if TYPE_CHECKING:
    import numpy as np
else:
    from weldpool_core.lazy import np

log = structlog.get_logger(__name__)

UNCERTAINTY_SAMPLES = 8


def _remove_stale_work(models_dir: Any, session: Any) -> None:
    """Work folders of training jobs that are over (a killed worker leaves one behind)."""
    for folder in models_dir.glob(".work-job*"):
        job_id = folder.name.removeprefix(".work-job")
        job = session.get(Job, int(job_id)) if job_id.isdigit() else None
        if job is None or job.status.finished:
            shutil.rmtree(folder, ignore_errors=True)


def _training_split(ctx: JobContext, models_dir: Path) -> tuple[list[int], list[int], list[int]]:
    """The frames to train on, the validation split's, and (without a validation split) the
    training frames held out for validation (``service.held_out_ids``)."""
    with ctx.session_factory() as session:
        _remove_stale_work(models_dir, session)
        train_ids = service.training_frame_ids(session)
        validation_ids = service.validation_frame_ids(session)
        held_out = [] if validation_ids else service.held_out_ids(session, train_ids)
    train_ids = [f for f in train_ids if f not in held_out]
    if not train_ids:
        raise InvalidInputError("There are no accepted or corrected labels to train on.")
    return train_ids, validation_ids, held_out


def _configs(ctx: JobContext) -> tuple[Any, Any]:
    """The job's training settings and student architecture."""
    from weldpool_core.student.model import StudentConfig, student_config
    from weldpool_core.student.train import TrainConfig

    config = TrainConfig(seed=int(ctx.params.get("seed") or 0), device=ctx.settings.device)
    if ctx.params.get("epochs"):
        config = replace(config, epochs=int(ctx.params["epochs"]))
    size = ctx.params.get("size")
    return config, student_config(str(size)) if size else StudentConfig()


Skipped = list[tuple[int, str]]


def _samples(
    session: Any, storage: Storage, frame_ids: list[int], skipped: Skipped
) -> list[tuple[int, Any]]:
    """``(frame id, (image, mask, keypoints))`` of the labelled frames that have both; those
    whose files the store lost are listed in ``skipped`` instead."""
    return [
        (frame_id, (image, mask, keypoints))
        for frame_id, image, mask, keypoints in service.labelled_samples(
            session, storage, frame_ids, skipped=skipped
        )
        if mask is not None and image is not None
    ]


def _anything_left(training: list[Any], skipped: Skipped) -> None:
    """A clear failure when every frame to train on was left out for its lost files."""
    if not training and skipped:
        first = skipped[0][1]
        raise InvalidInputError(
            f"Every labelled frame to train on has lost files ({len(skipped)} frames), so "
            f"nothing was trained; the first: {first}"
        )


def _record_version(
    ctx: JobContext,
    work: Path,
    result: Any,
    configs: tuple[Any, Any],
    training: list[tuple[int, Any]],
    pseudo: list[tuple[int, Any]],
    held_out: list[int],
) -> tuple[ModelVersion, Path]:
    """The trained folder renamed into ``models/<name>`` and its ModelVersion row, or neither
    (every frame it trained on was deleted meanwhile, or the commit failed)."""
    from weldpool_core.student import checkpoint

    config, student = configs
    models_dir, storage = work.parent, open_storage(ctx.settings)
    with ctx.session_factory() as session:
        if not service.existing_frame_ids(session, [frame_id for frame_id, _ in training]):
            shutil.rmtree(work, ignore_errors=True)
            raise InvalidInputError(
                "Every labelled frame it trained on was deleted during training; no version "
                "was recorded."
            )
        name = service.free_name(session, models_dir)
        final = models_dir / name
        work.rename(final)
        try:
            checkpoint.prune_state(final)  # a recorded version is never resumed
            storage.publish(f"models/{name}")  # every machine can read it once its row is in
            version = ModelVersion(
                name=name,
                checkpoint_path=f"models/{name}",
                job_id=ctx.job_id,
                config={"student": student.as_dict(), "training": config.as_dict()},
                metrics=result.metrics
                | {
                    "best_epoch": result.best_epoch,
                    "validation_frames": result.validation_frames,
                    "pretrained_encoder": result.pretrained_encoder,
                    "pseudo_labels": len(pseudo),
                },
                curve=[record.as_dict() for record in result.curve],
                train_label_count=len(training),
                train_frame_ids=[frame_id for frame_id, _ in training + pseudo],
                held_out_frame_ids=held_out,
            )
            session.add(version)
            session.commit()
        except BaseException:
            session.rollback()
            shutil.rmtree(final, ignore_errors=True)
            best_effort("unpublish", partial(storage.unpublish, f"models/{name}"))
            raise
    return version, final


@job_handler("train_student")
def train_student_version(ctx: JobContext) -> dict[str, Any]:
    """Train a student on the accepted and corrected labels; validate on the validation split
    (or, without one, on training frames held out by ``service.held_out_ids``); then the
    promotion gate measures it against the promoted version and the teacher.

    The model is written to a work folder and becomes ``models/<name>`` and a ModelVersion row
    only when training finished: a killed or cancelled job leaves no half-written version.
    """
    from weldpool_core.student.train import train_student

    storage = open_storage(ctx.settings)
    models_dir = storage.local("models")
    models_dir.mkdir(parents=True, exist_ok=True)
    work = models_dir / f".work-job{ctx.job_id}"
    train_ids, validation_ids, held_out = _training_split(ctx, models_dir)
    shutil.rmtree(work, ignore_errors=True)
    config, student = _configs(ctx)
    skipped: Skipped = []
    with ctx.session_factory() as session:
        training = _samples(session, storage, train_ids, skipped)
        _anything_left(training, skipped)
        held = _samples(session, storage, validation_ids or held_out, skipped)
        student, training, validation = with_classes(session, ctx.settings, student, training, held)
        pseudo = _pseudo_labels(ctx, session, storage, len(training))
        result = train_student(
            [sample for _, sample in training] + [frame for _, frame in pseudo],
            work,
            student,
            config,
            progress=lambda fraction, message: ctx.progress(0.95 * fraction, message),
            validation=validation or None,
        )

    # A lost, cancelled or interrupted attempt records no version.
    ctx.progress(0.96, "measuring the new version against the promoted one and the teacher")
    ctx.check_cancelled()  # progress may skip its write (and check) when the last was recent
    version, final = _record_version(
        ctx, work, result, (config, student), training, pseudo, held_out
    )
    verdict = _gate_and_promote(ctx, version.id)
    promoted = verdict["promote"] and ctx.settings.auto_promote
    ctx.summary = _summary(
        final.name, result.best_epoch, len(result.curve), version.metrics, verdict, promoted
    ) + (f"; {counted(len(skipped), 'frame')} left out, their files are lost" if skipped else "")
    return {
        "model_version_id": version.id,
        "name": final.name,
        "metrics": version.metrics,
        "promoted": promoted,
        "gate": {k: verdict[k] for k in ("usable", "promote", "reason")},
        "skipped_frames": [{"frame_id": f, "reason": reason} for f, reason in skipped],
    }


def _forget_version(ctx: JobContext, version_id: int, folder: Path) -> None:
    """Remove a version the job recorded but could not measure: its row and its folder."""
    with ctx.session_factory() as session:
        session.execute(sa.delete(ModelVersion).where(ModelVersion.id == version_id))
        session.commit()
    shutil.rmtree(folder, ignore_errors=True)
    storage = open_storage(ctx.settings)
    best_effort("unpublish", partial(storage.unpublish, storage.relative(folder)))


@job_handler(service.SEQUENTIAL_KIND)
def train_sequential_cell(ctx: JobContext) -> dict[str, Any]:
    """Train a version's sequential cell on the reviewed frames of imported videos (their
    training split), then measure it against the version's per-frame student on what it never
    trained on: the validation split's video frames and unlabelled windows of its own
    (``service.video_clips``). The cell lands beside the version's weights
    (``weldpool_core.student.sequential``) and the measurement on the version; a job that fails
    or is cancelled after the cell was written puts the version's previous cell back."""
    from dataclasses import replace

    from weldpool_core.student.checkpoint import read_student_config
    from weldpool_core.student.sequential import (
        SequentialConfig,
        measure_sequential,
        train_sequential,
    )

    settings, storage = ctx.settings, open_storage(ctx.settings)
    config = SequentialConfig(seed=int(ctx.params.get("seed") or 0), device=settings.device)
    if ctx.params.get("steps"):
        config = replace(config, steps=int(ctx.params["steps"]))
    model_id = int(ctx.params["model_version_id"])
    with ctx.session_factory() as session:
        version = service.get_model(session, model_id)
        root = service.model_folder(storage, version)
        name, trained = version.name, set(version.train_frame_ids or [])
        ctx.progress(0.0, "reading the labelled videos")
        student = read_student_config(root)
        clips = service.video_clips(session, storage, config, exclude=trained, student=student)
    if not any(clip.labels for clip in clips.train):
        raise InvalidInputError(
            "No reviewed frame of the training split comes from an imported video; label frames "
            "of a video to train the sequential cell."
        )
    previous = _cell_files(root)
    try:
        result = train_sequential(
            root,
            clips.train,
            config,
            progress=lambda fraction, message: ctx.progress(0.05 + 0.85 * fraction, message),
        )
        ctx.progress(0.92, "measuring the cell against the per-frame student")
        measured = measure_sequential(root, clips.check, config)
        record = {
            "trained_at": utcnow().isoformat(),
            "job_id": ctx.job_id,
            "windows": result.windows,
            "videos": sum(1 for clip in clips.train if clip.labels),
            "steps": config.steps,
            "seconds": round(result.seconds, 1),
            "measured": measured,
        }
        # The cell, on every machine, before its record (its files only: an int8 job may be
        # changing the version's others).
        storage.publish(_stored(storage, root), _cell_names())
        with ctx.session_factory() as session:
            again = session.get(ModelVersion, model_id)
            if again is None:  # deleted while training: its folder went with it
                raise InvalidInputError(f"Model version {model_id} was deleted during training.")
            again.sequential = record
            session.commit()
    except BaseException:
        _restore_cell_files(root, previous)
        best_effort("publish", partial(storage.publish, _stored(storage, root), _cell_names()))
        raise
    ctx.summary = f"{name}: sequential cell trained on {counted(result.windows, 'window')}; " + (
        _sequential_verdict(measured)
    )
    return {"model_version_id": model_id, "sequential": record}


def _cell_names() -> tuple[str, ...]:
    """The files of a version's sequential cell."""
    from weldpool_core.student.sequential import (
        SEQUENTIAL_CONFIG,
        SEQUENTIAL_ONNX,
        SEQUENTIAL_WEIGHTS,
    )

    return (SEQUENTIAL_WEIGHTS, SEQUENTIAL_CONFIG, SEQUENTIAL_ONNX)


def _stored(storage: Storage, folder: Path) -> str:
    """A version folder's path as the store names it."""
    return storage.relative(folder)


def _files(root: Path, names: tuple[str, ...]) -> dict[str, bytes]:
    """The bytes of those of a version's files ``names`` that exist now."""
    return {name: (root / name).read_bytes() for name in names if (root / name).is_file()}


def _cell_files(root: Path) -> dict[str, bytes]:
    """The bytes of a version's sequential cell files that exist now."""
    from weldpool_core.student.sequential import SEQUENTIAL_CONFIG, SEQUENTIAL_WEIGHTS

    return _files(root, (SEQUENTIAL_WEIGHTS, SEQUENTIAL_CONFIG))


def _write_bytes(path: Path, data: bytes) -> None:
    path.write_bytes(data)


def _put_back(root: Path, previous: dict[str, bytes], names: tuple[str, ...]) -> None:
    """Put a version's files ``names`` back as ``_files`` found them (absent ones removed);
    nothing when the version's folder is gone."""
    from weldpool_core.student import checkpoint

    if not root.is_dir():
        return
    for name in names:
        if name in previous:
            checkpoint.write_atomic(root / name, partial(_write_bytes, data=previous[name]))
        else:
            (root / name).unlink(missing_ok=True)


def _restore_cell_files(root: Path, previous: dict[str, bytes]) -> None:
    """Put a version's cell files back as ``_cell_files`` found them (absent ones removed; the
    ONNX export is made again from them on its next use)."""
    from weldpool_core.student.sequential import (
        SEQUENTIAL_CONFIG,
        SEQUENTIAL_ONNX,
        SEQUENTIAL_WEIGHTS,
    )

    if root.is_dir():
        (root / SEQUENTIAL_ONNX).unlink(missing_ok=True)
    _put_back(root, previous, (SEQUENTIAL_WEIGHTS, SEQUENTIAL_CONFIG))


def _sequential_verdict(measured: dict[str, Any]) -> str:
    """The measurement in words, as the models page shows it (IoU 3 decimals, change in %)."""
    parts = []
    if measured["per_frame_iou"] is not None:
        parts.append(
            f"mask IoU {measured['sequential_iou']:.3f} against the per-frame "
            f"{measured['per_frame_iou']:.3f} on {counted(measured['frames'], 'validation frame')}"
        )
    else:
        parts.append("no validation frame of a video to measure its accuracy on")
    if measured["per_frame_change"] is not None:
        parts.append(
            f"the mask changes {100 * measured['sequential_change']:.1f} % per frame against "
            f"{100 * measured['per_frame_change']:.1f} %"
        )
    return "; ".join(parts)


def _summary(
    name: str,
    kept: int,
    rounds: int,
    metrics: dict[str, Any],
    verdict: dict[str, Any],
    promoted: bool,
) -> str:
    """The job's last word: which round the version keeps (not the last one trained) and the
    gate's verdict; numbers rounded as every page shows them (mIoU 3 decimals, px 1)."""
    med = metrics.get("mED")
    scores = f"mIoU {metrics.get('mIoU', 0.0):.3f}" + (f", mED {med:.1f} px" if med else "")
    if not verdict["promote"]:
        verdict_text = f"not promoted: {verdict['reason'].removeprefix('Not promoted: ')}"
    elif promoted:
        verdict_text = "promoted"
    else:
        verdict_text = "passes the gate; promote it on the models page (auto-promotion is off)"
    return f"{name} keeps round {kept} of {rounds} ({scores}); {verdict_text}"


PSEUDO_PER_LABEL = 3
"""At most this many teacher pseudo-labels per reviewed label, the most confident first."""


def _pseudo_labels(ctx: JobContext, session: Any, storage: Storage, labels: int) -> list[Any]:
    """(frame id, TrainingFrame) of the teacher's confident proposals on unlabelled frames when
    the job asks for them (``service.pseudo_label_proposals``), each weighing
    ``pseudo_weight`` × the teacher's confidence; none otherwise."""
    from weldpool_core.student.data import TrainingFrame

    if not ctx.params.get("pseudo_labels"):
        return []
    threshold = float(ctx.params.get("pseudo_min_confidence", 0.8))
    weight = float(ctx.params.get("pseudo_weight", 0.5))
    chosen = sorted(service.pseudo_label_proposals(session, threshold), key=lambda pair: -pair[1])[
        : PSEUDO_PER_LABEL * labels
    ]
    frames = []
    for proposal, confidence in chosen:
        if weight * confidence <= 0:
            continue
        frame = session.get_one(Frame, proposal.frame_id)
        keypoints = np.asarray(proposal.keypoints, np.float64) if proposal.keypoints else None
        try:
            image, mask = frame_rgb(storage, frame), load_mask(storage, proposal.mask_path)
        except MissingFile:  # an unreviewed guess: without its files it is simply not used
            continue
        weighted = TrainingFrame(
            image, mask, keypoints, f"pseudo:{frame.id}", min(1.0, weight * confidence)
        )
        frames.append((frame.id, weighted))
    return frames


def _gate_and_promote(ctx: JobContext, version_id: int) -> dict[str, Any]:
    """Measure the new version (``app.training.gate``), store the verdict, and promote it when
    the gate says so and WELDPOOL_AUTO_PROMOTE is on; then re-score the review queue."""

    storage = open_storage(ctx.settings)
    with ctx.session_factory() as session:
        version = session.get_one(ModelVersion, version_id)
        folder = storage.local(version.checkpoint_path or f"models/{version.name}")
        incumbent = service.promoted_model(session)
        try:
            verdict = gate.measure(session, storage, version, incumbent, ctx.settings.device)
            version.gate = verdict
            session.commit()
        except BaseException:  # a version is recorded with its verdict, or not at all
            session.rollback()
            _forget_version(ctx, version_id, folder)
            raise
        if not (verdict["promote"] and ctx.settings.auto_promote):
            return verdict
        service.promote(session, version)  # measured and kept: a failure after is the queue's
        if ctx.queue is not None:
            service.queue_promoted_run(session, ctx.queue, version, None)
    return verdict


STUDENT_CHUNK = 16
"""Frames per chunk of a student run that several workers share (a few seconds of CPU)."""


@job_handler("student", max_attempts=2, fanout=True)
def student_proposals(ctx: JobContext) -> dict[str, Any]:
    """The promoted student's mask, heatmap and keypoints for frames, with its uncertainty
    (√ of its latent draws' spread × its mask's ambiguity, ⊕ novelty,
    ``weldpool_core.student.predict``) stored on the frame for the review queue, in chunks
    every worker the run reaches shares (``app.jobs.fanout``)."""
    from weldpool_core.student.predict import StudentPredictor

    storage = open_storage(ctx.settings)
    with ctx.session_factory() as session:
        version = service.get_model(session, int(ctx.params["model_version_id"]))
        name, path = version.name, service.model_folder(storage, version)
        version_id = version.id
    predictor = StudentPredictor.load(path, ctx.settings.device)
    fan = Fanout(ctx, STUDENT_CHUNK)
    if not ctx.helper:
        fan.plan(partial(_run_frames, ctx))
        fan.invite()
    for index in fan.chunks():
        with fan.working(index) as result:
            result.update(
                _student_chunk(ctx, storage, predictor, fan.items(index), name, version_id)
            )
        ctx.progress(fan.progress(), fan.message())
    if ctx.helper:
        return {}
    results = fan.results()
    proposed = sum(r["proposed"] for r in results)
    lost = [f for r in results for f in r["lost"]]
    gone = fan.size - proposed - len(lost)
    ctx.summary = (
        f"{name} proposed {counted(proposed, 'frame')}"
        + (f" ({gone} no longer exist)" if gone else "")
        + (f"; {counted(len(lost), 'frame')} left out, their files are lost" if lost else "")
    )
    return {"proposed": proposed, "model": name, "skipped_frame_ids": lost}


def _run_frames(ctx: JobContext) -> list[int]:
    """The run's frames, read when it starts (``app.frames.listing.scope_frames``)."""
    with ctx.session_factory() as session:
        return scope_frames(session, ctx.job_id, ctx.params)


def _student_chunk(
    ctx: JobContext,
    storage: Storage,
    predictor: Any,
    frame_ids: list[int],
    name: str,
    version_id: int,
) -> dict[str, Any]:
    """The student on one chunk's frames: how many it proposed, and those whose files are lost."""
    proposed, lost = 0, []
    for frame_id in frame_ids:
        with ctx.session_factory() as session:
            frame = session.get(Frame, frame_id)
            try:
                if frame is not None:
                    _student_proposal(ctx, session, storage, predictor, frame, name, version_id)
                    proposed += 1
            except FrameDeleted:
                pass
            except MissingFile:  # its file went with the frame, deleted meanwhile, or was lost
                if frame_exists(session, frame_id):
                    lost.append(frame_id)
        ctx.check_cancelled()
    return {"proposed": proposed, "lost": lost}


def _student_proposal(
    ctx: JobContext,
    session: Any,
    storage: Storage,
    predictor: Any,
    frame: Frame,
    name: str,
    version_id: int,
) -> None:
    """The student's proposal for one frame, with its disagreement with the teacher's and the
    frame re-scored; FrameDeleted when the frame went meanwhile."""
    prediction = predictor.predict([frame_rgb(storage, frame)], samples=UNCERTAINTY_SAMPLES)[0]
    keypoints = [[float(x), float(y)] for x, y in prediction.keypoints]
    teacher = latest_teacher_proposal(session, frame.id)
    disagreement = None
    if teacher is not None:
        disagreement = teacher_disagreement(
            prediction.mask, load_mask(storage, teacher.mask_path), keypoints, teacher.keypoints
        )
    ctx.check_cancelled()  # a lost or cancelled attempt records nothing more
    record_proposal(
        session,
        storage,
        frame,
        source=STUDENT,
        model_id=name,
        mask=prediction.mask,
        heatmap=prediction.heatmap,
        keypoints=keypoints,
        scores={
            "uncertainty": prediction.uncertainty,
            "uncertainty_parts": prediction.uncertainty_parts,
            "disagreement": disagreement,
        },
        weights=ctx.settings.uncertainty_weights,
        job_id=ctx.job_id,
        model_version_id=version_id,
    )


@job_handler(service.QUANTIZE_KIND, lane="quick")
def quantize_version(ctx: JobContext) -> dict[str, Any]:
    """Make a version's int8 student (``weldpool_core.student.quantize``), calibrated on frames
    spread over the project and checked against the float student on others; the version
    records the check and both speeds. A job that fails after the file was written puts the
    previous int8 file (or none) back, so the file and the record always agree."""
    from weldpool_core.student.checkpoint import EXPORT_FILE, INT8_ONNX_FILE
    from weldpool_core.student.quantize import quantize_student, remove_leftovers

    storage = open_storage(ctx.settings)
    model_id = int(ctx.params["model_version_id"])
    with ctx.session_factory() as session:
        version = service.get_model(session, model_id)
        root = service.model_folder(storage, version)
        name = version.name
        frame_ids = service.calibration_frame_ids(session)
        ctx.progress(0.0, f"reading {counted(len(frame_ids), 'frame')} to calibrate on")
        images = [frame_rgb(storage, session.get_one(Frame, i)) for i in frame_ids]
    leftovers = remove_leftovers(root)  # a killed worker's; this kind runs one at a time
    if leftovers:
        log.info("quantize_leftovers_removed", model=name, files=leftovers)
    files = (INT8_ONNX_FILE, EXPORT_FILE)
    previous = _files(root, files)
    ctx.progress(0.2, "quantizing, then checking it against the float student")
    try:
        result = quantize_student(root, images)
        record = {"made_at": utcnow().isoformat(), "job_id": ctx.job_id, **result.as_dict()}
        storage.publish(_stored(storage, root), files)  # the int8 file, before its record
        with ctx.session_factory() as session:
            again = session.get(ModelVersion, model_id)
            if again is None:  # deleted meanwhile: its folder went with it
                raise InvalidInputError(f"Model version {model_id} was deleted meanwhile.")
            again.int8 = record
            session.commit()
    except BaseException:
        _put_back(root, previous, files)
        best_effort("publish", partial(storage.publish, _stored(storage, root), files))
        raise
    ctx.summary = (
        f"{name}: int8 student made; masks agree with the float student's at IoU "
        f"{result.mean_iou:.3f} ({result.min_iou:.3f} at worst) on "
        f"{counted(result.check_frames, 'frame')}; {result.int8_ms:.1f} ms a frame against "
        f"{result.float_ms:.1f} ms here"
    )
    return {"model_version_id": model_id, "int8": record}
