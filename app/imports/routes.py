"""/api/v1/labels/import: labels made elsewhere (COCO, YOLO, mask folders, LabelMe, CVAT)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from fastapi import APIRouter, Request, status
from fastapi.concurrency import run_in_threadpool

from app.core.deps import QueueDep, SessionDep, StorageDep
from app.core.errors import InvalidInputError
from app.core.housekeeping import prune_shared
from app.core.security import CurrentUser
from app.frames.multipart import one_spooled_file, openapi_form, optional_int
from app.frames.sequences import get_sequence
from app.imports.schemas import KEYPOINT_ROLES, checked_class_map
from app.imports.uploads import IMPORTS_DIR, keep_upload
from app.jobs.schemas import JobCreated
from app.jobs.service import create_job
from weldpool_core.annotations import ARCHIVE_ONLY, READERS
from weldpool_core.annotations.source import is_zip

router = APIRouter(tags=["labels"])


def _checked(form: dict[str, str], name: str) -> dict[str, Any]:
    fmt = (form.get("format") or "").strip().lower()
    if fmt not in READERS:
        raise InvalidInputError(f"format must be one of {', '.join(READERS)}.")
    overwrite = (form.get("overwrite") or "false").strip().lower()
    if overwrite not in ("true", "false", "1", "0", "yes", "no", "on", "off"):
        raise InvalidInputError("overwrite must be true or false.")
    keypoints = (form.get("keypoints") or "validation").strip().lower()
    if keypoints not in KEYPOINT_ROLES:
        raise InvalidInputError(f"keypoints must be one of {', '.join(KEYPOINT_ROLES)}.")
    category = (form.get("category") or "").strip() or None
    if category is not None and len(category) > 200:
        raise InvalidInputError("category is at most 200 characters.")
    return {
        "format": fmt,
        "name": Path(name.replace("\\", "/")).name[:255] or "labels",
        "overwrite": overwrite in ("true", "1", "yes", "on"),
        "category": category,
        "sequence_id": optional_int(form, "sequence_id"),
        "keypoints": keypoints,
        "class_map": checked_class_map(form.get("class_map")),
    }


@router.post(
    "/labels/import",
    response_model=JobCreated,
    status_code=status.HTTP_202_ACCEPTED,
    openapi_extra=openapi_form(
        {
            "file": {"type": "string", "format": "binary"},
            "format": {"type": "string", "enum": list(READERS)},
            "sequence_id": {"type": "integer"},
            "overwrite": {"type": "boolean", "default": False},
            "category": {"type": "string"},
            "class_map": {"type": "string", "description": "theirs=ours,… (class names)"},
            "keypoints": {
                "type": "string",
                "enum": ["validation", "label"],
                "default": "validation",
            },
        },
        ["file", "format"],
    ),
)
async def import_labels(
    request: Request,
    session: SessionDep,
    storage: StorageDep,
    queue: QueueDep,
    user: CurrentUser,
) -> JobCreated:
    """Import labels made elsewhere: a zip (annotations with their images, or a mask folder),
    or one COCO, LabelMe or CVAT file whose images are already stored. Hand-placed pool
    keypoints become validation keypoints (`keypoints=validation`, the frame joins the
    validation split) or the label's own (`keypoints=label`). Regions of other classes become
    objects of the label-configuration's classes (`class_map` renames the file's: `theirs=ours,…`);
    the rest are counted, never refusing the file. A job reads it; its result counts `frames`,
    `labels` and `keypoints`, lists every `skipped` and `refused` item with its reason, and
    counts the other classes' regions by outcome (`classes`: kept, unknown, …)."""
    # spooled beside the store's folders, so that keep_upload moves it there: written once
    form = one_spooled_file(request, "zip or annotation file", spool_dir=storage.scratch())
    async with form as (fields, name, upload):
        params = _checked(fields, name)
        if params["sequence_id"] is not None:
            get_sequence(session, params["sequence_id"])
        head = upload.read(4)
        if not head:
            raise InvalidInputError("The file is empty.")
        if params["format"] in ARCHIVE_ONLY and not is_zip(head):
            raise InvalidInputError(
                f"A {params['format']} import is a zip of its folders; the file is not a zip."
            )
        upload.seek(0)
        suffix = ".zip" if is_zip(head) else Path(params["name"]).suffix[:8]
        await run_in_threadpool(prune_shared, storage, IMPORTS_DIR)
        kept = await run_in_threadpool(keep_upload, storage, upload, suffix)
    job = create_job(
        session, queue, "import_labels", params | {"upload": kept, "user_id": user.id}, user
    )
    return JobCreated(job_id=job.id)
