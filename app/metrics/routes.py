"""/api/v1/metrics: the quality figures of the loop, and per person (/metrics/people)."""

from __future__ import annotations

import datetime as dt
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Query, Response

from app.core.deps import SessionDep, StorageDep
from app.core.errors import InvalidInputError
from app.core.security import CurrentUser
from app.metrics.classes import class_figures, classes_csv
from app.metrics.people import IDLE_GAP_S, people_csv, people_figures
from app.metrics.service import all_metrics

router = APIRouter(tags=["metrics"])


@router.get("/metrics")
def metrics(session: SessionDep, storage: StorageDep, _user: CurrentUser) -> dict[str, Any]:
    """Student mIoU / mED per version against its training labels (the learning curve), the
    teacher's mIoU against reviewed masks per sequence (leaving out the labels that kept the
    teacher's mask unchanged; `including_unchanged` has them), the reviewers' acceptance rate
    of teacher proposals, reviews per day, and per class and frame tag the frames labelled
    with it (`classes`, as `/metrics/classes` gives them)."""
    return all_metrics(session, storage)


@router.get(
    "/metrics/classes",
    responses={200: {"content": {"text/csv": {"schema": {"type": "string"}}}}},
)
def classes(
    session: SessionDep, _user: CurrentUser, format: Literal["json", "csv"] = "json"
) -> Any:
    """Per class: the frames whose label holds it (`pool`: a pool mask), its objects, and the
    frames among them whose label is approved (the review stage off: every saved label); per
    frame tag: the frames tagged. Classes and tags the configuration no longer has but labels
    still hold come last, `configured` false."""
    figures = class_figures(session)
    if format == "csv":
        return Response(
            classes_csv(figures),
            media_type="text/csv",
            headers={"Content-Disposition": 'attachment; filename="weldpool-classes.csv"'},
        )
    return figures


PeriodQuery = Annotated[
    dt.datetime | None,
    Query(description="ISO date or date-time (UTC unless it says otherwise)."),
]


def _utc(moment: dt.datetime | None) -> dt.datetime | None:
    if moment is None:
        return None
    return moment.replace(tzinfo=dt.UTC) if moment.tzinfo is None else moment.astimezone(dt.UTC)


@router.get(
    "/metrics/people",
    responses={200: {"content": {"text/csv": {"schema": {"type": "string"}}}}},
)
def people(
    session: SessionDep,
    storage: StorageDep,
    user: CurrentUser,
    since: PeriodQuery = None,
    until: PeriodQuery = None,
    format: Literal["json", "csv"] = "json",
) -> Any:
    """One row per user: labels saved, submitted and sent back (and the rate), active hours,
    seconds per frame and frames per hour (gaps over 5 minutes are pauses), mask IoU and
    keypoint distance (px) of their submissions against what was approved; for reviewers,
    decisions (approved, corrected and approved, sent back) and the median turnaround.
    `since` ≤ time < `until`; an annotator gets her own row only."""
    start, end = _utc(since), _utc(until)
    if start is not None and end is not None and end <= start:
        raise InvalidInputError("`until` must come after `since`.")
    rows = people_figures(session, storage, user, start, end)
    if format == "csv":
        return Response(
            people_csv(rows),
            media_type="text/csv",
            headers={"Content-Disposition": 'attachment; filename="weldpool-people.csv"'},
        )
    return {"since": start, "until": end, "idle_gap_s": IDLE_GAP_S, "people": rows}
