"""/api/v1/sequences, /frames and /videos: weld runs, frame upload and listing, video upload."""

from __future__ import annotations

from typing import Annotated, Any, Literal

import anyio
from fastapi import APIRouter, Depends, Query, Request, status
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import FileResponse, JSONResponse, Response

from app.core.bounds import MAX_ID, IdPath, OffsetQuery
from app.core.deps import QueueDep, SessionDep, SettingsDep, StorageDep
from app.core.errors import InvalidInputError
from app.core.models import FrameStatus, ReviewState, Split, User
from app.core.models import get_frame as frame_by_id
from app.core.security import CurrentUser, ReviewerUser
from app.frames import assignments, deletion, ingest, listing, sequences, videos
from app.frames.multipart import StreamedForm, one_spooled_file, openapi_form, optional_int
from app.frames.schemas import (
    AlsoIn,
    AssignIn,
    AssignOut,
    DeletionOut,
    Duplicate,
    FrameDetail,
    FrameOut,
    FramePage,
    FramesDeleteIn,
    IngestOut,
    Rejected,
    SequenceIn,
    SequenceOut,
    SequencePatch,
    VideoAccepted,
    VideoOut,
)
from app.jobs.service import create_job
from app.labelconfig import facets
from app.labelconfig import service as labelconfig
from app.system.doctor import frame_file

router = APIRouter(tags=["frames"])


# --- sequences ---------------------------------------------------------------------------------


def _sequence_out(sequence: Any, count: int) -> SequenceOut:
    return SequenceOut.model_validate(sequence).model_copy(update={"frame_count": count})


@router.post("/sequences", response_model=SequenceOut, status_code=status.HTTP_201_CREATED)
def create_sequence(body: SequenceIn, session: SessionDep, user: CurrentUser) -> SequenceOut:
    """A named weld run with its process parameters."""
    return _sequence_out(sequences.create_sequence(session, body.model_dump(), user), 0)


@router.get("/sequences", response_model=list[SequenceOut])
def list_sequences(session: SessionDep, _user: CurrentUser) -> list[SequenceOut]:
    """Every weld run, newest first, with its number of frames."""
    runs = sequences.list_sequences(session)
    counts = sequences.frame_counts(session, [s.id for s in runs])
    return [_sequence_out(s, counts.get(s.id, 0)) for s in runs]


@router.get("/sequences/{sequence_id}", response_model=SequenceOut)
def get_sequence(sequence_id: IdPath, session: SessionDep, _user: CurrentUser) -> SequenceOut:
    sequence = sequences.get_sequence(session, sequence_id)
    return _sequence_out(
        sequence, sequences.frame_counts(session, [sequence_id]).get(sequence_id, 0)
    )


@router.patch("/sequences/{sequence_id}", response_model=SequenceOut)
def update_sequence(
    sequence_id: IdPath, body: SequencePatch, session: SessionDep, _user: CurrentUser
) -> SequenceOut:
    """Change a weld run's name, process parameters or notes."""
    sequence = sequences.update_sequence(
        session, sequences.get_sequence(session, sequence_id), body.model_dump(exclude_unset=True)
    )
    return _sequence_out(
        sequence, sequences.frame_counts(session, [sequence_id]).get(sequence_id, 0)
    )


def _deletion_out(done: deletion.Deletion) -> DeletionOut:
    return DeletionOut(
        deleted_frames=done.frames, deleted_reviewed=done.reviewed, removed_files=done.files
    )


ForceQuery = Annotated[
    bool, Query(description="Also delete frames with reviewed labels (else 409 says how many).")
]


@router.delete("/sequences/{sequence_id}", response_model=DeletionOut)
def delete_sequence(
    sequence_id: IdPath,
    session: SessionDep,
    storage: StorageDep,
    _user: ReviewerUser,
    force: ForceQuery = False,
) -> DeletionOut:
    """Delete a weld run with its frames, videos, proposals and labels (reviewers)."""
    sequence = sequences.get_sequence(session, sequence_id)
    return _deletion_out(deletion.delete_sequence(session, storage, sequence, force=force))


# --- frames ------------------------------------------------------------------------------------


@router.post("/frames/assign", response_model=AssignOut)
def assign_frames(body: AssignIn, session: SessionDep, _user: ReviewerUser) -> AssignOut:
    """Hand frames to a person (reviewers): the `frame_ids` given, or the `next` N frames of
    the queue nobody has yet; `assignee_id` null takes them back. Anyone may still review an
    assigned frame; the assignee's queue is `GET /frames?assignee=me`."""
    ids = assignments.assign_frames(
        session,
        body.assignee_id,
        frame_ids=body.frame_ids,
        next_count=body.next,
        sequence_id=body.sequence_id,
    )
    person = assignments.assignee(session, body.assignee_id)
    return AssignOut(assigned=len(ids), frame_ids=ids, assignee=person.username if person else None)


@router.post("/frames/delete", response_model=DeletionOut)
def delete_frames(
    body: FramesDeleteIn, session: SessionDep, storage: StorageDep, _user: ReviewerUser
) -> DeletionOut:
    """Delete several frames at once, in one transaction (reviewers)."""
    return _deletion_out(deletion.delete_frames(session, storage, body.frame_ids, force=body.force))


@router.delete("/frames/{frame_id}", response_model=DeletionOut)
def delete_frame(
    frame_id: IdPath,
    session: SessionDep,
    storage: StorageDep,
    _user: ReviewerUser,
    force: ForceQuery = False,
) -> DeletionOut:
    """Delete one frame with its proposals and labels (reviewers)."""
    return _deletion_out(deletion.delete_frames(session, storage, [frame_id], force=force))


@router.post(
    "/frames",
    response_model=IngestOut,
    status_code=status.HTTP_201_CREATED,
    openapi_extra=openapi_form(
        {
            "files": {"type": "array", "items": {"type": "string", "format": "binary"}},
            "sequence_id": {"type": "integer"},
        },
        ["files"],
    ),
    responses={
        200: {"description": "Nothing new: every file was a duplicate."},
        422: {"description": "No file could be stored; each has its reason."},
    },
)
async def upload_frames(
    request: Request,
    session: SessionDep,
    storage: StorageDep,
    settings: SettingsDep,
    user: CurrentUser,
) -> Response:
    """Upload one or many frames (PNG, JPEG, TIFF, BMP; 8/16-bit): each is checked once (from
    the moment it has arrived), stored by content hash and recorded; duplicates and refusals
    are listed."""
    checks = ingest.FrameChecks(storage, settings.max_image_pixels)
    try:
        form = StreamedForm(
            lambda field, name, data: (
                checks.add(ingest.IncomingFile(name, data)) if field == "files" else None
            ),
            max_files=settings.max_files_per_request,
            max_fields=64,
        )
        await form.read(request.headers.get("content-type", ""), request.stream())
        sequence_id = optional_int(form.fields, "sequence_id")
        if not len(checks):
            raise InvalidInputError("The request has no `files` part; attach one or more frames.")
    except BaseException:
        with anyio.CancelScope(shield=True):  # a cancelled request still removes its files
            await run_in_threadpool(checks.discard)
        raise
    result = await run_in_threadpool(
        ingest.record_checked, session, storage, checks, sequence_id=sequence_id, user=user
    )
    body = IngestOut(
        stored=[FrameOut.model_validate(f) for f in result.stored],
        duplicates=[
            Duplicate(name=d.name, sha256=d.sha256, frame_id=d.frame_id) for d in result.duplicates
        ],
        rejected=[Rejected(name=r.name, reason=r.reason) for r in result.rejected],
        also_in=[
            AlsoIn(frame_id=f, other_frame_id=o, sequence_id=s, sequence_name=n)
            for f, o, s, n in listing.also_in(session, result.stored)
        ],
    )
    if result.stored:
        code = status.HTTP_201_CREATED
    elif result.rejected:
        code = status.HTTP_422_UNPROCESSABLE_CONTENT
    else:
        code = status.HTTP_200_OK
    payload = body.model_dump(mode="json")
    if code == status.HTTP_422_UNPROCESSABLE_CONTENT:
        first = result.rejected[0]
        payload["detail"] = f"No frame was stored; {first.name or 'the file'}: {first.reason}"
        payload["errors"] = [{"loc": ["files", r.name], "msg": r.reason} for r in result.rejected]
    return JSONResponse(payload, status_code=code)


def _assignee(value: str | None, user: User) -> int | Literal["none"] | None:
    """The `assignee` filter as the list takes it: a user id, `none`, or no filter."""
    if value is None:
        return None
    if value == "none":
        return "none"
    return user.id if value == "me" else int(value)


UNSTABLE_NOTE = (
    "Only frames inside their run's unstable stretches (as its stored signature last found "
    "them); with `order=uncertainty`: the review queue kept to them."
)


CLASS_NOTE = (
    "Only frames whose label holds an object of this class (`pool`: a pool mask); repeated: "
    "every class given. An unknown class is a 400 naming the configured ones."
)
TAG_NOTE = "Only frames whose label has this frame tag; repeated: every tag given."
ATTR_NOTE = (
    "`name:value`: only frames whose label gives that frame attribute that value (a flag: "
    "`true`/`false`; a number: as written, `3` matches 3.0); repeated: every one given."
)


def label_filters(
    session: SessionDep,
    class_: Annotated[
        list[str] | None, Query(alias="class", max_length=8, description=CLASS_NOTE)
    ] = None,
    tag: Annotated[list[str] | None, Query(max_length=8, description=TAG_NOTE)] = None,
    attr: Annotated[list[str] | None, Query(max_length=8, description=ATTR_NOTE)] = None,
) -> list[Any]:
    """The list's conditions on what labels hold (``app.labelconfig.facets``), checked
    against the label configuration in force (read only when one is given)."""
    if not (class_ or tag or attr):
        return []
    config = labelconfig.current(session)
    return facets.filter_conditions(config, class_ or (), tag or (), attr or ())


@router.get("/frames", response_model=FramePage)
def list_frames(
    session: SessionDep,
    settings: SettingsDep,
    user: CurrentUser,
    held: Annotated[list[Any], Depends(label_filters)],
    sequence_id: Annotated[int | None, Query(ge=1, le=MAX_ID)] = None,
    status: Annotated[
        FrameStatus | Literal["unreviewed", "all"] | None,
        Query(
            description="One status; `unreviewed`: new or proposed (still to review, the "
            "queue's default in the UI); `all` or none: every frame."
        ),
    ] = None,
    split: Split | None = None,
    order: str = Query(
        "id",
        pattern="^(id|-id|frame_index|uncertainty)$",
        description="`uncertainty`: the active-learning queue, most unsure first.",
    ),
    assignee: Annotated[
        str | None,
        Query(
            pattern=r"^(me|none|[1-9][0-9]{0,8})$",
            description="`me`: the frames handed to the caller (with no `status` or `review`: "
            "the caller's work, what was sent back to them first, then what is still to "
            "review); `none`: to nobody; a user id.",
        ),
    ] = None,
    review: Annotated[
        ReviewState | None,
        Query(
            description="The review stage: frames whose label awaits a reviewer, was sent back, "
            "or is approved (labels saved with the stage off count as approved)."
        ),
    ] = None,
    unstable: Annotated[bool, Query(description=UNSTABLE_NOTE)] = False,
    limit: int = Query(50, ge=1, le=500),
    offset: OffsetQuery = 0,
    after: Annotated[
        str | None,
        Query(
            max_length=200,
            description="Cursor: the previous page's `next_after`. The page after it reads "
            "only its own rows, however deep (an `offset` walks every row it skips).",
        ),
    ] = None,
) -> FramePage:
    """Frames, filtered and paginated (by `offset`, or by the cursor `after`)."""
    work = assignee == "me" and status is None and review is None
    page = listing.list_frames(
        session,
        sequence_id=sequence_id,
        status=None if status == "all" else status,
        split=split,
        order=order,
        limit=limit,
        offset=offset,
        after=after,
        diversity=settings.queue_diversity,
        diversity_pool=settings.queue_diversity_pool,
        assignee=None if work else _assignee(assignee, user),
        review=review,
        work_for=user.id if work else None,
        unstable=unstable,
        facets=held,
    )
    reviews = listing.review_states(session, [r.id for r in page.rows])
    return FramePage(
        items=[
            FrameOut.model_validate(r).model_copy(update=reviews.get(r.id, {})) for r in page.rows
        ],
        total=page.total,
        limit=limit,
        offset=offset,
        next_after=page.next_after,
        ordering=listing.ordering_note(
            order, settings.queue_diversity, settings.queue_diversity_pool, work=work
        ),
    )


@router.get("/frames/{frame_id}", response_model=FrameDetail)
def get_frame(
    frame_id: IdPath, session: SessionDep, storage: StorageDep, _user: CurrentUser
) -> FrameDetail:
    """A frame's metadata with its label and the state of the proposal the policy shows."""
    frame = frame_by_id(session, frame_id)
    return FrameDetail.model_validate(
        FrameOut.model_validate(frame).model_dump() | listing.frame_state(session, storage, frame)
    )


@router.get(
    "/frames/{frame_id}/image",
    response_class=FileResponse,
    responses={
        200: {"content": {"image/png": {}, "image/jpeg": {}, "image/tiff": {}, "image/bmp": {}}}
    },
)
def get_frame_image(
    frame_id: IdPath,
    session: SessionDep,
    storage: StorageDep,
    _user: CurrentUser,
    variant: str = Query(
        "original",
        pattern="^(original|display|thumb)$",
        description="original: the stored file, untouched; display: 8-bit "
        "PNG for browsers; thumb: 8-bit PNG, 256 px.",
    ),
) -> Response:
    """The frame's image: the original file, or an 8-bit PNG for display."""
    frame = frame_by_id(session, frame_id)
    headers = {"Cache-Control": "private, max-age=31536000, immutable"}
    if variant == "original":
        return FileResponse(
            frame_file(storage, frame.path, frame.id), media_type=frame.media_type, headers=headers
        )
    path = listing.display_image(storage, frame, variant)
    return FileResponse(path, media_type="image/png", headers=headers)


# --- videos ------------------------------------------------------------------------------------


@router.post(
    "/videos",
    response_model=VideoAccepted,
    status_code=status.HTTP_202_ACCEPTED,
    openapi_extra=openapi_form(
        {
            "file": {"type": "string", "format": "binary"},
            "every_nth": {"type": "integer", "default": 1},
            "sequence_id": {"type": "integer"},
        },
        ["file"],
    ),
)
async def upload_video(
    request: Request,
    session: SessionDep,
    storage: StorageDep,
    settings: SettingsDep,
    queue: QueueDep,
    user: CurrentUser,
) -> VideoAccepted:
    """Upload an MP4 or AVI video; a job extracts every n-th frame into the sequence (a new
    sequence named after the file when none is given)."""
    # spooled into the store's scratch folder and hashed on the way, then renamed into place
    form = one_spooled_file(
        request, "video", max_fields=64, spool_dir=storage.scratch(), hashed=True
    )
    async with form as (fields, name, upload):
        every_nth = optional_int(fields, "every_nth", 1) or 0
        sequence_id = optional_int(fields, "sequence_id")
        video = await run_in_threadpool(
            videos.store_video,
            session,
            storage,
            upload,
            name=name,
            every_nth=every_nth,
            sequence_id=sequence_id,
            user=user,
        )
    job = create_job(session, queue, "extract_video", {"video_id": video.id}, user)
    video.job_id = job.id
    session.commit()
    return VideoAccepted(job_id=job.id, video=VideoOut.model_validate(video))
