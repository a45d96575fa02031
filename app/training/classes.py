"""Which of the label configuration's other classes a student learns, and their labels.

A class of kind ``mask``, ``instances`` or ``points`` with at least
``Settings.student_class_min_labels`` reviewed labels among the frames a student trains and is
measured on (one at least among those it trains on) becomes extra output channels of that
version (``weldpool_core.student.classes``); the pool is learned as always. A points class's
channels are its configured ``point_names``, else the point names its labels use (sorted).
Labels give each class's truth from their stored ``objects``: a mask class's mask, an instances
class's instances as one union, a points class's named points.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import sqlalchemy as sa
from sqlalchemy.orm import Session

from app.core.config import Settings
from app.core.models import Frame, Label, ModelVersion
from app.labelconfig import service as labelconfig
from app.labelconfig.retired import object_retired
from app.labelconfig.schemas import POOL
from app.training.service import TRAINABLE_LABEL
from weldpool_core.outline import rle_mask

if TYPE_CHECKING:
    from weldpool_core.student.classes import ClassTruth, LearnedClass
    from weldpool_core.student.model import StudentConfig

Sample = tuple[int, Any]
"""``(frame id, (image, mask, keypoints))`` as ``tasks._samples`` gives them."""


def _objects(session: Session, frame_ids: list[int]) -> dict[int, list[dict[str, Any]]]:
    """The stored objects of the trainable labels of ``frame_ids``, by frame."""
    rows = session.execute(
        sa.select(Label.frame_id, Label.objects).where(
            TRAINABLE_LABEL, Label.frame_id.in_(frame_ids)
        )
    )
    return {frame_id: list(objects or []) for frame_id, objects in rows}


def learned_classes(
    session: Session,
    frame_ids: list[int],
    min_labels: int,
    training: list[int] | None = None,
) -> tuple[LearnedClass, ...]:
    """The configured classes with at least ``min_labels`` labelled frames among
    ``frame_ids``, in the configuration's order (none when ``min_labels`` is 0). With
    ``training`` (the part of ``frame_ids`` trained on, the rest measures), a class also needs
    one label there: ten labelled frames of which two are held out still learn the class."""
    from weldpool_core.student.classes import KINDS, MAX_POINTS, LearnedClass

    if min_labels <= 0:
        return ()
    configured = labelconfig.current(session).config["classes"]
    by_name = {spec["name"]: spec for spec in configured}
    objects = {  # an object the configuration retired (a class re-kinded) is no label of it
        frame: [o for o in held if not object_retired(by_name, o)]
        for frame, held in _objects(session, frame_ids).items()
    }
    counts: Counter[str] = Counter()
    names: dict[str, set[str]] = {}
    for held in objects.values():
        for name in {str(o.get("class")) for o in held}:
            counts[name] += 1
        for item in held:
            names.setdefault(str(item.get("class")), set()).update(item.get("points") or {})
    learned = []
    for spec in configured:
        name, kind = spec["name"], spec.get("kind")
        if name == POOL or kind not in KINDS or counts[name] < min_labels:
            continue
        if training is not None and not any(
            name in {str(o.get("class")) for o in objects.get(i, [])} for i in training
        ):
            continue
        points = spec.get("point_names") or sorted(names.get(name, ()))
        if kind == "points" and not points:
            continue
        chosen = tuple(points[:MAX_POINTS]) if kind == "points" else ()
        learned.append(LearnedClass(name, kind, chosen))
    return tuple(learned)


def _truth(kind: str, held: list[dict[str, Any]]) -> ClassTruth | None:
    from weldpool_core.student.classes import ClassTruth

    if kind == "points":
        points: dict[str, tuple[float, float]] = {}
        for item in held:
            for point, xy in (item.get("points") or {}).items():
                points.setdefault(point, (float(xy[0]), float(xy[1])))
        return ClassTruth(points=points) if points else None
    masks = [rle_mask(item["rle"]) for item in held if item.get("rle")]
    if not masks:
        return None
    union = masks[0].copy()
    for mask in masks[1:]:
        union |= mask
    return ClassTruth(mask=union)


def class_truths(
    session: Session, frame_ids: list[int], classes: tuple[LearnedClass, ...]
) -> dict[int, dict[str, ClassTruth]]:
    """Each frame's labels of ``classes`` (those it has), by frame id."""
    truths: dict[int, dict[str, ClassTruth]] = {}
    if not classes:
        return truths
    for frame_id, held in _objects(session, frame_ids).items():
        mine = {}
        for learned in classes:
            found = _truth(learned.kind, [o for o in held if o.get("class") == learned.name])
            if found is not None:
                mine[learned.name] = found
        truths[frame_id] = mine
    return truths


def _with_truths(samples: list[Sample], truths: dict[int, dict[str, ClassTruth]]) -> list[Any]:
    """``(frame id, TrainingFrame)`` of samples, each with its class labels."""
    from weldpool_core.student.train import as_training_frame

    return [
        (frame_id, replace(as_training_frame(sample, frame_id), classes=truths.get(frame_id, {})))
        for frame_id, sample in samples
    ]


def with_classes(
    session: Session,
    settings: Settings,
    student: StudentConfig,
    training: list[Sample],
    validation: list[Sample],
) -> tuple[StudentConfig, list[Sample], list[Any]]:
    """The student with the classes its training and validation frames label often enough, its
    training samples (``(frame id, sample)``) and validation samples, with their class labels;
    as given (validation without ids) when no class qualifies."""
    ids = [frame_id for frame_id, _ in training]
    every = ids + [frame_id for frame_id, _ in validation]
    classes = learned_classes(session, every, settings.student_class_min_labels, ids)
    if not classes:
        return student, training, [sample for _, sample in validation]
    truths = class_truths(session, every, classes)
    held = [frame for _, frame in _with_truths(validation, truths)]
    return replace(student, classes=classes), _with_truths(training, truths), held


def version_classes(version: ModelVersion) -> tuple[LearnedClass, ...]:
    """The classes a version learned (its stored student configuration's)."""
    from weldpool_core.student.classes import LearnedClass

    saved = (version.config or {}).get("student") or {}
    return tuple(LearnedClass.from_dict(c) for c in saved.get("classes") or ())


def shared_classes(candidate: ModelVersion, incumbent: ModelVersion) -> tuple[LearnedClass, ...]:
    """The candidate's classes that the incumbent learned too: the same name, kind and, for a
    points class, the same points (so that both figures measure the same thing)."""
    theirs = set(version_classes(incumbent))
    return tuple(learned for learned in version_classes(candidate) if learned in theirs)


def gate_figures(
    session: Session,
    version: ModelVersion,
    frame_ids: list[int],
    answers: dict[int, dict[str, Any]],
    only: tuple[LearnedClass, ...] | None = None,
) -> dict[str, dict[str, Any]] | None:
    """The version's figures per learned class (``only`` these, when given) on the gate's
    frames that have the class labelled (``student.classes.class_figures``; None for a
    pool-only version). Reported beside the pool's, never part of its promotion rule."""
    from weldpool_core.student.classes import class_figures

    classes = version_classes(version) if only is None else only
    if not classes:
        return None
    truths = class_truths(session, frame_ids, classes)
    measured = [f for f in frame_ids if f in answers]
    rows = session.execute(
        sa.select(Frame.id, Frame.height, Frame.width).where(Frame.id.in_(measured))
    )
    sizes = {frame_id: (int(height), int(width)) for frame_id, height, width in rows}
    measured = [f for f in measured if f in sizes]
    return class_figures(
        classes,
        [answers[f] for f in measured],
        [truths.get(f, {}) for f in measured],
        [sizes[f] for f in measured],
    )
