"""/api/v1/metrics: the quality figures of the loop."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter

from app.deps import SessionDep, StorageDep
from app.insights.service import all_metrics
from app.security import CurrentUser

router = APIRouter(tags=["metrics"])


@router.get("/metrics")
def metrics(session: SessionDep, storage: StorageDep, _user: CurrentUser) -> dict[str, Any]:
    """Student mIoU / mED per version against its training labels (the learning curve), the
    teacher's mIoU against reviewed masks per sequence, the reviewers' acceptance rate of
    teacher proposals, and reviews per day."""
    return all_metrics(session, storage)
