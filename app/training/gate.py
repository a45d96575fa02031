"""The promotion gate: a student version is promoted only when measured better, at promotion
time, on frames none of the compared models trained on.

The frames: the validation split's reviewed masks, else the frames the candidate's training
held out; minus every frame the candidate or the incumbent trained on. On them the candidate,
the promoted incumbent (re-scored now, not read from its old metrics) and the teacher's newest
proposals are scored with one rule, ``weldpool_core.metrics.proposal_quality``: mIoU and the
penalised keypoint distance (a keypoint missed, or on a frame whose IoU is under 0.5, counts as
the frame's diagonal).

- usable: the candidate is no worse than the teacher on the frames the teacher proposed for
  (mIoU at least the teacher's, penalised mED at most the teacher's); where the teacher
  proposed for none of them, it meets ``MIN_MIOU`` and misses no keypoint.
- promoted: usable, and with an incumbent, a lower penalised mED (a higher mIoU when there are
  no true keypoints, or on a tie) and an mIoU no lower than the incumbent's minus
  ``MIOU_TOLERANCE``.
No frames to measure on: not usable, with the reason.

Learned classes (``app.training.classes``): the candidate's figures per class (IoU for mask and
instances classes, point distance in px for points classes) on the measured frames that have the
class labelled, in ``classes``; with an incumbent, its figures on the same frames in
``incumbent_classes`` (per candidate class; None where it did not learn that class, with the
same kind and points). Reported only, never part of the rule above: a class never decides a
promotion.

A fair yardstick: a label a reviewer accepted unchanged from a model's proposal *is* that
model's output, so the model scores 1.0 on it and nobody can beat it there. Each comparison
therefore leaves out the frames whose label was taken unchanged from one of the two models
compared (``taken_from``): the teacher is compared on frames whose labels were drawn or
corrected, the incumbent likewise. On the frames accepted from the teacher the candidate only
has to reach ``MIN_MIOU`` (a reviewer found the teacher right there: the candidate must not be
far off). Where every frame's label came from the teacher, the candidate is judged by that
floor alone, as when the teacher proposed for none.
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING, Any, TypeAlias

import sqlalchemy as sa
from sqlalchemy.orm import Session
from sqlalchemy.orm.exc import ObjectDeletedError

from app.core.db import utcnow
from app.core.errors import ConflictError, InvalidInputError
from app.core.models import Frame, Label, ModelVersion, Proposal
from app.storage import Storage
from app.storage.pixels import frame_rgb, load_mask
from app.training import classes, service
from weldpool_core.metrics import proposal_quality

if TYPE_CHECKING:
    import numpy as np
else:
    from weldpool_core.lazy import np

MIN_MIOU = 0.7
"""The least mIoU a first student needs where the teacher has no proposal to compare with."""
MIOU_TOLERANCE = 0.005
"""How much mIoU a candidate may lose to the incumbent while its keypoints improve."""

Truth: TypeAlias = "dict[int, tuple[np.ndarray, Any]]"


def gate_frames(
    session: Session, candidate: ModelVersion, incumbent: ModelVersion | None
) -> list[int]:
    """The frames to measure on (module doc), in id order."""
    trained = set(candidate.train_frame_ids or [])
    if incumbent is not None:
        trained |= set(incumbent.train_frame_ids or [])
    validation = service.validation_frame_ids(session)
    pool = validation if validation else list(candidate.held_out_frame_ids or [])
    return [f for f in pool if f not in trained]


def taken_from(session: Session, frame_ids: list[int]) -> dict[int, tuple[str, int | None]]:
    """The frames among ``frame_ids`` whose label is a proposal accepted unchanged: its
    source (``teacher``, ``student``, ``propagated``) and model version."""
    rows = session.execute(
        sa.select(Label.frame_id, Proposal.source, Proposal.model_version_id)
        .join(Proposal, Proposal.id == Label.proposal_id)
        .where(Label.frame_id.in_(frame_ids), Label.mask_changed.is_(False))
    )
    return {frame_id: (source, version) for frame_id, source, version in rows}


def _truth(session: Session, storage: Storage, frame_ids: list[int]) -> Truth:
    truth: Truth = {}
    lost: list[tuple[int, str]] = []  # a frame whose files are lost is not measured on
    for frame_id, _, mask, keypoints in service.labelled_samples(
        session, storage, frame_ids, with_images=False, skipped=lost
    ):
        if mask is not None:
            truth[frame_id] = (mask, keypoints or [])
    return truth


Outputs: TypeAlias = "dict[int, tuple[np.ndarray, Any]]"


def _student_outputs(
    session: Session,
    storage: Storage,
    version: ModelVersion,
    frame_ids: list[int],
    device: str,
    answers: dict[int, dict[str, Any]] | None = None,
) -> Outputs:
    """The version's mask and keypoints on each frame, predicted now (and into ``answers``,
    when given, its learned classes' answers)."""
    from weldpool_core.student.predict import StudentPredictor

    if version.checkpoint_path is None:
        raise InvalidInputError(f"{version.name} has no checkpoint to measure.")
    try:
        folder = storage.folder(version.checkpoint_path)
        if folder is None:
            raise FileNotFoundError(version.checkpoint_path)
        predictor = StudentPredictor.load(folder, device)
        images = [frame_rgb(storage, session.get_one(Frame, f)) for f in frame_ids]
    except (FileNotFoundError, sa.exc.NoResultFound, ObjectDeletedError):
        if len(service.existing_frame_ids(session, frame_ids)) == len(frame_ids):
            raise
        raise ConflictError(
            "A frame it is measured on was deleted meanwhile; measure it again."
        ) from None
    except InvalidInputError as exc:  # the core names files by their path on this server
        home = f"{storage.home}{os.sep}"
        raise InvalidInputError(
            f"{version.name} cannot be measured: {exc.message.replace(home, '')}"
        ) from None
    predictions = predictor.predict(images)
    if answers is not None:
        answers.update({f: p.classes for f, p in zip(frame_ids, predictions, strict=True)})
    return {f: (p.mask, p.keypoints) for f, p in zip(frame_ids, predictions, strict=True)}


def _teacher_outputs(session: Session, storage: Storage, frame_ids: list[int]) -> Outputs:
    """The teacher's newest proposal on each frame that has one."""
    newest = (
        sa.select(sa.func.max(Proposal.id))
        .where(Proposal.source == "teacher", Proposal.frame_id.in_(frame_ids))
        .group_by(Proposal.frame_id)
    )
    proposals = session.scalars(sa.select(Proposal).where(Proposal.id.in_(newest)))
    return {p.frame_id: (load_mask(storage, p.mask_path), p.keypoints) for p in proposals}


def _score(outputs: Outputs, truth: Truth, frame_ids: list[int]) -> dict[str, Any]:
    scores = proposal_quality({str(f): (*outputs[f], *truth[f]) for f in frame_ids})
    scores.pop("per_image")
    return scores


def _no_worse(first: dict[str, Any], second: dict[str, Any]) -> bool:
    """``first`` is at least as good as ``second`` in mIoU and penalised keypoint distance."""
    if first["mIoU"] < second["mIoU"]:
        return False
    a, b = first["mED_penalised"], second["mED_penalised"]
    return a is None or b is None or a <= b


def _count(frames: int) -> str:
    return f"{frames} held-out frame{'' if frames == 1 else 's'}"


def _fmt(scores: dict[str, Any]) -> str:
    med = scores["mED_penalised"]
    return f"mIoU {scores['mIoU']:.3f}" + ("" if med is None else f", penalised mED {med:.1f} px")


def _comparable(
    storage: Storage, candidate: ModelVersion, incumbent: ModelVersion | None
) -> ModelVersion | None:
    """The incumbent to compare with: not the candidate itself, nor one whose files are gone."""
    if incumbent is None or incumbent.id == candidate.id or incumbent.checkpoint_path is None:
        return None
    return incumbent if storage.has_folder(incumbent.checkpoint_path) else None


def _against_teacher(
    verdict: dict[str, Any],
    mine: Outputs,
    truth: dict[int, Any],
    teacher: Outputs,
    accepted: list[int],
) -> list[str]:
    """Why the candidate is unusable next to the teacher (none: usable): below the floor on
    labels accepted from the teacher, worse than the teacher on the frames that are fair to
    both, or below the floor with no teacher proposal to compare with."""
    reasons = []
    if accepted and (floor := _score(mine, truth, accepted))["mIoU"] < MIN_MIOU:
        reasons.append(
            f"below the minimum quality on {_count(len(accepted))} whose labels were accepted "
            f"from the teacher unchanged ({_fmt(floor)}; needs mIoU ≥ {MIN_MIOU})"
        )
    if teacher:
        common = sorted(teacher)
        mine_common, theirs = _score(mine, truth, common), _score(teacher, truth, common)
        verdict["teacher"] = theirs | {"candidate_on_these": mine_common}
        if not _no_worse(mine_common, theirs):
            reasons.append(
                f"worse than the teacher on {_count(len(common))} "
                f"({_fmt(mine_common)} vs {_fmt(theirs)})"
            )
        return reasons
    verdict["teacher"] = None
    own = verdict["candidate"]
    if own["mIoU"] < MIN_MIOU or own["missed"]:
        reasons.append(
            f"below the minimum quality with no teacher proposal to compare with "
            f"({_fmt(own)}, {own['missed']} keypoints missed; needs mIoU "
            f"≥ {MIN_MIOU} and none missed)"
        )
    return reasons


Context: TypeAlias = tuple[Session, Storage, str]
"""The session, storage and device a verdict is measured with."""


def _incumbent_classes(
    context: Context,
    verdict: dict[str, Any],
    candidate: ModelVersion,
    incumbent: ModelVersion | None,
    ids: list[int],
) -> Outputs | None:
    """The incumbent's figures for each of the candidate's classes on the same frames, into
    ``incumbent_classes`` (None for a class it did not learn); its outputs on ``ids`` when it
    was run for them (the pool's comparison reuses them)."""
    if incumbent is None or verdict["classes"] is None:
        return None
    session, storage, device = context
    shared = classes.shared_classes(candidate, incumbent)
    outputs, figures = None, {}
    answers: dict[int, dict[str, Any]] = {}
    if shared:
        outputs = _student_outputs(session, storage, incumbent, ids, device, answers)
        figures = classes.gate_figures(session, incumbent, ids, answers, shared) or {}
    verdict["incumbent_classes"] = {name: figures.get(name) for name in verdict["classes"]}
    return outputs


def _against_incumbent(
    context: Context,
    verdict: dict[str, Any],
    mine: Outputs,
    truth: dict[int, Any],
    fair: list[int],
    compared: tuple[ModelVersion, Outputs | None],
) -> str | None:
    """Why the candidate does not beat the incumbent (with its outputs, when already run) on
    the labels neither of them proposed (None: it does)."""
    incumbent, ran = compared
    if not fair:
        return (
            f"every held-out label was accepted unchanged from {incumbent.name} or this "
            "version, so they cannot be compared fairly; draw or correct some held-out labels"
        )
    session, storage, device = context
    outputs = (
        ran if ran is not None else _student_outputs(session, storage, incumbent, fair, device)
    )
    theirs = _score(outputs, truth, fair)
    verdict["incumbent_scores"] = theirs
    ours = _score(mine, truth, fair)
    if _better(ours, theirs):
        return None
    return (
        f"not better than {incumbent.name} on {_count(len(fair))} ({_fmt(ours)} vs {_fmt(theirs)})"
    )


def _promotion_reason(
    verdict: dict[str, Any], incumbent: ModelVersion | None, frames: int, accepted: bool
) -> str:
    others = [incumbent.name] if incumbent else []
    others += ["the teacher"] if verdict["teacher"] else []
    if others:
        reason = f"Better than {' and '.join(others)} on {_count(frames)}"
    else:  # no teacher proposal to compare with on these frames: the floor alone
        reason = f"Meets the minimum quality on {_count(frames)} (no teacher proposal to "
        reason += "compare with" + (", those there were accepted unchanged)" if accepted else ")")
    return reason + f" ({_fmt(verdict['candidate'])})."


def measure(
    session: Session,
    storage: Storage,
    candidate: ModelVersion,
    incumbent: ModelVersion | None,
    device: str = "auto",
) -> dict[str, Any]:
    """The gate's verdict on ``candidate`` against ``incumbent`` and the teacher (module doc):
    ``usable``, ``promote``, ``reason`` and the scores behind them (JSON-ready)."""
    incumbent = _comparable(storage, candidate, incumbent)
    frame_ids = gate_frames(session, candidate, incumbent)
    truth = _truth(session, storage, frame_ids)
    verdict: dict[str, Any] = {
        "measured_at": utcnow().isoformat(),
        "frames": sorted(truth),
        "incumbent": incumbent.name if incumbent else None,
    }
    if not truth:
        return verdict | {
            "usable": False,
            "promote": False,
            "reason": "No reviewed frame is held out from its training to measure it on; label "
            "more frames or put some in the validation split.",
        }
    ids = sorted(truth)
    answers: dict[int, dict[str, Any]] = {}
    mine = _student_outputs(session, storage, candidate, ids, device, answers)
    verdict["candidate"] = _score(mine, truth, ids)
    verdict["classes"] = classes.gate_figures(session, candidate, ids, answers)
    context = (session, storage, device)
    ran = _incumbent_classes(context, verdict, candidate, incumbent, ids)
    taken = taken_from(session, ids)
    accepted = [f for f in ids if taken.get(f, ("",))[0] == "teacher"]
    verdict["accepted_from_teacher"] = accepted
    from_candidate = {f for f, (_, version) in taken.items() if version == candidate.id}
    teacher = {
        f: out
        for f, out in _teacher_outputs(session, storage, ids).items()
        if f not in accepted and f not in from_candidate
    }
    reasons = _against_teacher(verdict, mine, truth, teacher, accepted)
    usable = better = not reasons
    if usable and incumbent is not None:
        compared = {candidate.id, incumbent.id}
        fair = [f for f in ids if taken.get(f, ("", None))[1] not in compared]
        worse = _against_incumbent(context, verdict, mine, truth, fair, (incumbent, ran))
        better = worse is None
        reasons += [worse] if worse else []
    if usable and better:
        reason = _promotion_reason(verdict, incumbent, len(ids), bool(accepted))
    else:
        reason = "Not promoted: " + "; ".join(reasons) + "."
    return verdict | {"usable": usable, "promote": usable and better, "reason": reason}


def _better(candidate: dict[str, Any], incumbent: dict[str, Any]) -> bool:
    """Lower penalised mED (higher mIoU without true keypoints or on a tie), mIoU not lower
    beyond the tolerance."""
    if candidate["mIoU"] < incumbent["mIoU"] - MIOU_TOLERANCE:
        return False
    a, b = candidate["mED_penalised"], incumbent["mED_penalised"]
    if a is None or b is None or a == b:
        return bool(candidate["mIoU"] > incumbent["mIoU"])
    return bool(a < b)
