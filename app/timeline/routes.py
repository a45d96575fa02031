"""/api/v1/sequences/{id}/geometry: a weld run's pool geometry over time (JSON or CSV)."""

from __future__ import annotations

from typing import Any, Literal

from fastapi import APIRouter, Response

from app.core.bounds import IdPath
from app.core.deps import SessionDep, StorageDep
from app.core.security import CurrentUser
from app.timeline import service
from app.timeline.schemas import Timeline

router = APIRouter(tags=["timeline"])


@router.get(
    "/sequences/{sequence_id}/geometry",
    response_model=Timeline,
    responses={200: {"content": {"text/csv": {"schema": {"type": "string"}}}}},
)
def sequence_geometry(
    sequence_id: IdPath,
    session: SessionDep,
    storage: StorageDep,
    _user: CurrentUser,
    format: Literal["json", "csv"] = "json",
) -> Any:
    """Per frame in frame order: status, source (its label, else the proposal shown) and
    confidence, pool area, length along the run's travel axis and width across it, centroid and
    keypoints — in pixels, and in mm when the run has a scale."""
    timeline = service.sequence_geometry(session, storage, sequence_id)
    if format == "csv":
        name = f"weld-run-{sequence_id}-geometry.csv"
        return Response(
            service.geometry_csv(timeline),
            media_type="text/csv",
            headers={"Content-Disposition": f'attachment; filename="{name}"'},
        )
    return timeline
