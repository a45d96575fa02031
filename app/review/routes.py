"""/api/v1: teacher runs, proposals, click segmentation, labels and validation keypoints."""

from __future__ import annotations

import base64
import binascii
from dataclasses import asdict
from typing import TYPE_CHECKING, Annotated, Literal

from fastapi import APIRouter, Query, status
from fastapi.responses import FileResponse, StreamingResponse

from app.core import budgets
from app.core.bounds import MAX_ID, IdPath, check_in_frame
from app.core.deps import QueueDep, SessionDep, SettingsDep, StorageDep
from app.core.errors import ConflictError, InvalidInputError, NotFoundError
from app.core.housekeeping import prune_exports
from app.core.models import Job, JobStatus, Split, User, ValidationKeypoints, get_frame
from app.core.security import CurrentUser, ReviewerUser
from app.frames.sequences import get_sequence
from app.jobs.schemas import JobCreated
from app.jobs.service import create_job
from app.labelconfig import service as labelconfig
from app.labelconfig.retired import Retired, retired
from app.review import service
from app.review.export import export_name, export_rows, export_size, stream_export
from app.review.propagation import check_prompts
from app.review.schemas import (
    ExportIn,
    KeypointsIn,
    KeypointsOut,
    LabelIn,
    LabelOut,
    LabelRevisionOut,
    OutlineIn,
    OutlineMaskIn,
    OutlineMaskOut,
    OutlineOut,
    PolygonIO,
    PropagateIn,
    RetiredParts,
    ReviewIn,
    SegmentIn,
    SegmentOut,
)
from app.system.doctor import frame_file
from app.training.service import maybe_retrain
from weldpool_core.io import decode_mask_png, encode_mask_png
from weldpool_core.outline import Polygon, check_editable, fill_polygons, mask_polygons

if TYPE_CHECKING:
    pass
else:
    pass

router = APIRouter(tags=["review"])


def _b64(data: bytes) -> str:
    return base64.b64encode(data).decode("ascii")


def _png_bytes(text: str, what: str) -> bytes:
    try:
        return base64.b64decode(text, validate=True)
    except (binascii.Error, ValueError):
        raise InvalidInputError(f"{what} is not valid base64.") from None


@router.post("/frames/{frame_id}/segment", response_model=SegmentOut)
def segment(
    frame_id: IdPath,
    body: SegmentIn,
    session: SessionDep,
    storage: StorageDep,
    settings: SettingsDep,
    _user: CurrentUser,
) -> SegmentOut:
    """A new mask from clicks / a box / a previous mask, from the frame's cached embedding."""
    frame = get_frame(session, frame_id)
    if body.box is not None:
        x0, y0, x1, y1 = body.box
        for x, y in ((x0, y0), (x1, y1)):
            check_in_frame(x, y, frame.width, frame.height, "box corner")
    previous = None
    if body.mask_png:
        previous = decode_mask_png(_png_bytes(body.mask_png, "mask_png"))
    elif body.mask_from is not None:
        previous = service.stored_mask(
            session,
            storage,
            frame,
            label_revision=body.mask_from.label_revision,
            proposal_id=body.mask_from.proposal_id,
        )
    with budgets.interactive(settings):  # never behind a job's threads for the CPU
        result = service.segment(
            storage,
            settings,
            frame,
            [(p.x, p.y, p.positive) for p in body.points],
            body.box,
            previous,
        )
    return SegmentOut(
        mask_png=_b64(encode_mask_png(result.mask)),
        score=result.score,
        scores=result.scores,
        elapsed_ms=result.elapsed_ms,
        embedding=result.embedding,
    )


@router.post("/frames/{frame_id}/outline", response_model=OutlineOut)
def outline(
    frame_id: IdPath, body: OutlineIn, session: SessionDep, _user: CurrentUser
) -> OutlineOut:
    """A mask of this frame traced as polygons (outer boundaries and holes), to edit by vertex."""
    frame = get_frame(session, frame_id)
    mask = decode_mask_png(_png_bytes(body.mask_png, "mask_png"))
    if mask.shape != (frame.height, frame.width):
        raise InvalidInputError("The mask must have the frame's size.")
    polygons = mask_polygons(mask, body.tolerance)
    check_editable(polygons, traced=body.tolerance)
    return OutlineOut(
        polygons=[
            PolygonIO(points=[list(p) for p in poly.points], hole=poly.hole) for poly in polygons
        ]
    )


@router.post("/frames/{frame_id}/outline/mask", response_model=OutlineMaskOut)
def outline_mask(
    frame_id: IdPath, body: OutlineMaskIn, session: SessionDep, _user: CurrentUser
) -> OutlineMaskOut:
    """An edited outline of this frame rasterised: regions filled, holes emptied (at most
    10,000 vertices in all, none more than one frame width or height outside the frame)."""
    frame = get_frame(session, frame_id)
    polygons = [Polygon([(p[0], p[1]) for p in poly.points], poly.hole) for poly in body.polygons]
    mask = fill_polygons(polygons, frame.height, frame.width)
    return OutlineMaskOut(mask_png=_b64(encode_mask_png(mask)), area=int(mask.sum()))


def _label_out(session: SessionDep, storage: StorageDep, label, user: User | None) -> LabelOut:  # type: ignore[no-untyped-def]
    config = labelconfig.current(session)
    mask = None
    if label.mask_path:
        path = frame_file(storage, label.mask_path, label.frame_id, "label mask")
        mask = _b64(path.read_bytes())
    return LabelOut(
        frame_id=label.frame_id,
        revision=label.revision,
        status=label.status,
        proposal_id=label.proposal_id,
        mask_changed=label.mask_changed,
        mask_png=mask,
        keypoints=label.keypoints,
        source=label.source,
        updated_by=user.username if user else None,
        updated_at=label.updated_at,
        review=label.review,
        review_comment=label.review_comment,
        objects=label.objects or [],
        tags=(label.frame_tags or {}).get("tags", []),
        attributes=(label.frame_tags or {}).get("attributes", {}),
        retired=RetiredParts(**asdict(retired(config, label.objects, label.frame_tags))),
    )


@router.get("/frames/{frame_id}/label", response_model=LabelOut)
def get_label(
    frame_id: IdPath, session: SessionDep, storage: StorageDep, _user: CurrentUser
) -> LabelOut:
    """The frame's current label."""
    get_frame(session, frame_id)
    label = service.current_label(session, frame_id)
    if label is None:
        raise NotFoundError(f"Frame {frame_id} has no label yet.")
    author = session.get(User, label.updated_by_id) if label.updated_by_id else None
    return _label_out(session, storage, label, author)


@router.put(
    "/frames/{frame_id}/label",
    response_model=LabelOut,
    responses={409: {"description": "base_revision is stale; the body has `revision`."}},
)
def put_label(
    frame_id: IdPath,
    body: LabelIn,
    session: SessionDep,
    storage: StorageDep,
    settings: SettingsDep,
    queue: QueueDep,
    user: CurrentUser,
) -> LabelOut:
    """Accept, correct or reject; a stale base_revision gets 409 with the current revision."""
    frame = get_frame(session, frame_id)
    mask_png = _png_bytes(body.mask_png, "mask_png") if body.mask_png else None
    label = service.save_label(
        session,
        storage,
        frame,
        user,
        status=body.status,
        base_revision=body.base_revision,
        mask_png=mask_png,
        keypoints=body.keypoints,
        proposal_id=body.proposal_id,
        review_stage=settings.review_stage,
        others=service.OtherClasses(
            body.objects,
            body.tags,
            body.attributes,
            Retired(**body.remove_retired.model_dump()) if body.remove_retired else None,
        ),
    )
    maybe_retrain(session, queue, settings.retrain_every, user)
    return _label_out(session, storage, label, user)


@router.post(
    "/frames/{frame_id}/label/review",
    response_model=LabelOut,
    responses={409: {"description": "base_revision is stale, or the decision is made already."}},
)
def review_label(
    frame_id: IdPath,
    body: ReviewIn,
    session: SessionDep,
    storage: StorageDep,
    settings: SettingsDep,
    queue: QueueDep,
    user: ReviewerUser,
) -> LabelOut:
    """The review stage (`WELDPOOL_REVIEW_STAGE`): approve an annotator's label (it trains
    from now on) or send it back with a `comment` (reviewers); a new revision by the reviewer,
    so the history shows who decided."""
    frame = get_frame(session, frame_id)
    label = service.review_label(
        session,
        frame,
        user,
        approve=body.decision == "approve",
        base_revision=body.base_revision,
        comment=body.comment,
        review_stage=settings.review_stage,
    )
    if body.decision == "approve":
        maybe_retrain(session, queue, settings.retrain_every, user)
    return _label_out(session, storage, label, user)


@router.get("/frames/{frame_id}/label/history", response_model=list[LabelRevisionOut])
def get_label_history(
    frame_id: IdPath, session: SessionDep, _user: CurrentUser
) -> list[LabelRevisionOut]:
    """Every change of the frame's label: who, when, what."""
    get_frame(session, frame_id)
    return [
        LabelRevisionOut(
            revision=r.revision,
            status=r.status,
            keypoints=r.keypoints,
            has_mask=r.mask_path is not None,
            source=r.source,
            review=r.review,
            review_comment=r.review_comment,
            objects=r.objects or [],
            tags=(r.frame_tags or {}).get("tags", []),
            user=name,
            created_at=r.created_at,
        )
        for r, name in service.label_history(session, frame_id)
    ]


@router.put(
    "/frames/{frame_id}/validation-keypoints",
    response_model=KeypointsOut,
    responses={409: {"description": "base_revision is stale; the body has `revision`."}},
)
def put_validation_keypoints(
    frame_id: IdPath, body: KeypointsIn, session: SessionDep, user: CurrentUser
) -> KeypointsOut:
    """Keypoints placed by hand; the frame joins the validation split. With `base_revision`
    (0: none yet), a stale edit gets 409 with the current revision."""
    row = service.save_validation_keypoints(
        session, get_frame(session, frame_id), user, body.keypoints, body.base_revision
    )
    return _keypoints_out(row)


@router.get("/frames/{frame_id}/validation-keypoints", response_model=KeypointsOut)
def get_validation_keypoints(
    frame_id: IdPath, session: SessionDep, _user: CurrentUser
) -> KeypointsOut:
    get_frame(session, frame_id)
    return _keypoints_out(service.get_validation_keypoints(session, frame_id))


def _keypoints_out(row: ValidationKeypoints) -> KeypointsOut:
    return KeypointsOut(
        frame_id=row.frame_id,
        keypoints=row.keypoints,
        updated_at=row.updated_at,
        revision=row.revision,
    )


@router.get(
    "/export",
    response_class=StreamingResponse,
    responses={200: {"content": {"application/zip": {}}}},
)
def export(
    session: SessionDep,
    storage: StorageDep,
    _user: CurrentUser,
    format: Literal["coco", "masks", "yolo", "cvat", "labelme"] = "masks",
    sequence_id: Annotated[int | None, Query(ge=1, le=MAX_ID)] = None,
    split: Split | None = None,
) -> StreamingResponse:
    """A zip of the accepted and corrected labels: COCO, the DATASET layout of
    `weldpool train` (images/, masks/, keypoints/, manifest.json), Ultralytics YOLO
    segmentation, CVAT for images 1.1 or LabelMe; streamed as it is written (`POST /exports`
    runs it as a job instead)."""
    rows = export_rows(session, sequence_id, split)
    return StreamingResponse(
        stream_export(storage, format, rows),
        media_type="application/zip",
        headers={"Content-Disposition": f'attachment; filename="weldpool-{format}.zip"'},
    )


@router.post("/exports", response_model=JobCreated, status_code=status.HTTP_202_ACCEPTED)
def start_export(
    body: ExportIn,
    session: SessionDep,
    storage: StorageDep,
    queue: QueueDep,
    user: CurrentUser,
) -> JobCreated:
    """Export as a job with progress (big sets); download the zip from `GET /exports/{job_id}`."""
    if export_size(session, body.sequence_id, body.split) == 0:
        raise InvalidInputError("There are no accepted or corrected labels to export.")
    prune_exports(storage)
    job = create_job(session, queue, "export", body.model_dump(mode="json"), user)
    return JobCreated(job_id=job.id)


@router.get(
    "/exports/{job_id}",
    response_class=FileResponse,
    responses={200: {"content": {"application/zip": {}}}},
)
def download_export(
    job_id: IdPath, session: SessionDep, storage: StorageDep, _user: CurrentUser
) -> FileResponse:
    """The zip an export job wrote (kept for a day)."""
    job = session.get(Job, job_id)
    if job is None or job.kind != "export":
        raise NotFoundError(f"There is no export job {job_id}.")
    if job.status != JobStatus.succeeded:
        raise ConflictError(
            f"Export job {job_id} is {job.status.value}; download it once it has succeeded."
        )
    path = storage.fetch(export_name(job_id))  # from the object store once, streamed to disk
    if not path.is_file():
        raise NotFoundError(f"The export of job {job_id} is no longer kept; export again.")
    return FileResponse(
        path, media_type="application/zip", filename=f"weldpool-{job.params['format']}-{job_id}.zip"
    )


@router.post(
    "/sequences/{sequence_id}/propagate",
    response_model=JobCreated,
    status_code=status.HTTP_202_ACCEPTED,
)
def propagate(
    sequence_id: IdPath,
    body: PropagateIn,
    session: SessionDep,
    queue: QueueDep,
    user: ReviewerUser,
) -> JobCreated:
    """SAM2's video model carries the reviewed masks of `from_frame_ids` through the run in
    frame order: one `propagated` proposal per frame with its confidence (a job)."""
    get_sequence(session, sequence_id)
    check_prompts(session, sequence_id, body.from_frame_ids)
    params = body.model_dump(mode="json") | {"sequence_id": sequence_id}
    job = create_job(session, queue, "propagate", params, user)
    return JobCreated(job_id=job.id)
