"""Background work of the imports domain: a label import runs as a job with progress."""

from __future__ import annotations

from functools import partial
from typing import Any

from app.core.db import session_scope
from app.core.models import User
from app.imports.schemas import ImportOptions
from app.imports.service import import_labels
from app.imports.uploads import upload_name
from app.jobs.registry import JobContext, counted, job_handler
from app.storage import best_effort, open_storage
from weldpool_core.annotations import open_upload
from weldpool_core.errors import InvalidInputError


@job_handler("import_labels", max_attempts=1, lane="quick")
def import_labels_job(ctx: JobContext) -> dict[str, Any]:
    """Import the uploaded file's labels; the upload is removed when the job ends, whatever
    its outcome (a job that is not retried has no further use for it)."""
    params, storage = ctx.params, open_storage(ctx.settings)
    name = upload_name(params["upload"])
    options = ImportOptions(
        format=params["format"],
        sequence_id=params.get("sequence_id"),
        overwrite=bool(params.get("overwrite")),
        category=params.get("category"),
        keypoints=params.get("keypoints", "validation"),
        max_pixels=ctx.settings.max_image_pixels,
        review_stage=ctx.settings.review_stage,
        class_map=params.get("class_map") or {},
    )
    try:
        path = storage.fetch(name)  # from the object store when the web process is elsewhere
        with session_scope(ctx.session_factory) as session:
            user = session.get(User, int(params["user_id"]))
            if user is None:
                raise InvalidInputError("The user who started the import no longer exists.")
            source = open_upload(path, params["name"])
            try:
                report = import_labels(
                    session, storage, source, options, user, ctx.progress, ctx.check_cancelled
                )
            finally:
                source.close()
    finally:
        storage.local(name).unlink(missing_ok=True)
        best_effort("unpublish", partial(storage.unpublish, name))
    ctx.summary = (
        f"{counted(report.labels, 'label')} and {counted(report.keypoints, 'keypoint set')} "
        f"imported, {counted(report.frames, 'new frame')}; {len(report.skipped)} skipped, "
        f"{len(report.refused)} refused"
    )
    return report.as_result()
