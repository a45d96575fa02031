"""/api/v1/process-map and /api/v1/sequences/{id}/signature: runs against their parameters, and
one run's signature."""

from __future__ import annotations

from typing import Any, Literal

from fastapi import APIRouter, Query, Response

from app.core.bounds import IdPath
from app.core.deps import SessionDep, StorageDep
from app.core.security import CurrentUser
from app.process import service
from app.process.service import XName, YName
from app.process.signatures import run_signature_of, signature_payload

router = APIRouter(tags=["process"])


@router.get(
    "/process-map",
    responses={200: {"content": {"text/csv": {"schema": {"type": "string"}}}}},
)
def process_map(
    session: SessionDep,
    storage: StorageDep,
    _user: CurrentUser,
    x: XName = Query("heat_input_j_mm", description="A process parameter or a derived one."),
    y: YName = Query("width_mm", description="A figure of the runs' signatures."),
    color: XName | YName | None = Query(None, description="A third name, as the points' colour."),
    format: Literal["json", "csv"] = "json",
) -> Any:
    """One point per run (`sequence_id`, `name`, `x`, `y`, its IQR `y_q1`..`y_q3` for a median
    figure, `color`, `outlier`, `residual_pct`, its first unstable frame), the runs that cannot
    be drawn under `skipped` with the reason (mm figures need a scale), and the power law
    y = a·x^b fitted on logs (`fit`: `a`, `b` with its 95 % interval `b_low`..`b_high`, `r2`,
    `n`, the `excluded` outliers). Signatures are stored; a run whose labels or proposals
    changed is measured again first."""
    result = service.process_map(session, storage, x, y, color)
    if format == "csv":
        return Response(
            service.map_csv(result),
            media_type="text/csv",
            headers={"Content-Disposition": f'attachment; filename="process-map-{x}-{y}.csv"'},
        )
    return result


@router.get("/sequences/{sequence_id}/signature")
def sequence_signature(
    sequence_id: IdPath, session: SessionDep, storage: StorageDep, _user: CurrentUser
) -> dict[str, Any]:
    """A run's signature: median, quartiles and trend of width, length and area (mm with the
    run's scale, else px: `unit`), the width's coefficient of variation, its dominant
    oscillation (Hz and strength, from the frame times), and its unstable stretches with their
    frames; `rolling_cv` per frame."""
    return signature_payload(run_signature_of(session, storage, sequence_id))
