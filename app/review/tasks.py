"""Background work of the review domain: the teacher proposing masks for frames."""

from __future__ import annotations

import os
from typing import Any

import structlog

from app.jobs.registry import (
    JobContext,
    counted,
    job_handler,
)
from app.review import propagation
from app.review.export import SKIPPED_LIST, Skipped, build_export, export_name
from app.storage import open_storage
from app.teacher import runtime

log = structlog.get_logger(__name__)


@job_handler("export", max_attempts=1, lane="quick")
def export_run(ctx: JobContext) -> dict[str, Any]:
    """Write an export zip with progress per label; ``GET /exports/{job id}`` downloads it."""
    storage = open_storage(ctx.settings)
    skipped: Skipped = []
    with ctx.session_factory() as session:
        written = build_export(
            session,
            storage,
            ctx.params["format"],
            sequence_id=ctx.params.get("sequence_id"),
            split=ctx.params.get("split"),
            progress=ctx.progress,
            skipped=skipped,
        )
    target = storage.local(export_name(ctx.job_id))
    target.parent.mkdir(parents=True, exist_ok=True)
    os.replace(written, target)
    storage.publish(export_name(ctx.job_id))  # streamed to the object store, if there is one
    size = target.stat().st_size
    if storage.remote:  # the web process serves it from the bucket: this machine keeps none
        target.unlink()
    ctx.summary = f"{ctx.params['format']} export ready: {size / 1e6:.1f} MB" + (
        f"; {counted(len(skipped), 'frame')} left out, their files are missing "
        f"(listed in {SKIPPED_LIST}; `weldpool doctor` says what restores them)"
        if skipped
        else ""
    )
    return {
        "format": ctx.params["format"],
        "size_bytes": size,
        "skipped": len(skipped),
        "skipped_frames": [{"frame_id": f, "reason": reason} for f, reason in skipped],
    }


@job_handler("propagate", max_attempts=1)
def propagate_run(ctx: JobContext) -> dict[str, Any]:
    """SAM2's video model carries reviewed masks through a weld run (``app.review.propagation``)."""
    storage = open_storage(ctx.settings)
    ctx.progress(0.0, "loading SAM2's video model")
    propagator = runtime.propagator(ctx.settings)  # missing weights: the job fails here
    predictor = runtime.sam2_predictor(ctx.settings)
    ctx.check_cancelled()
    embed = propagation.frame_embedding(storage, predictor, runtime.embedding_cache(ctx.settings))
    with ctx.session_factory() as session:
        result = propagation.propagate_run(
            session,
            storage,
            propagator,
            embed,
            sequence_id=int(ctx.params["sequence_id"]),
            from_frame_ids=[int(i) for i in ctx.params["from_frame_ids"]],
            direction=str(ctx.params.get("direction", "both")),
            until_frame_index=ctx.params.get("until_frame_index"),
            threshold=float(ctx.params.get("threshold", 0.5)),
            model_id=propagation.model_id(ctx.settings.sam2),
            job_id=ctx.job_id,
            progress=ctx.progress,
            weights=ctx.settings.uncertainty_weights,
        )
    stops = "; ".join(
        f"stopped {s['direction']} at frame #{s['frame_id']} (confidence fell)"
        for s in result["stopped"]
    )
    proposed, deleted = int(result["proposed"]), len(result["deleted_frame_ids"])
    ctx.summary = (
        f"{counted(proposed, 'frame')} proposed, "
        f"{len(result['low_confidence_frame_ids'])} with low confidence"
        + (f"; {stops}" if stops else "")
        + (f"; {counted(deleted, 'frame')} skipped (deleted meanwhile)" if deleted else "")
    )
    return result
