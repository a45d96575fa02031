"""/api/v1/live: start, watch and stop live views of a student (see ``app.live.service``)."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator

from fastapi import APIRouter, Query, Request
from fastapi.responses import StreamingResponse

from app.core.bounds import IdPath
from app.core.config import Settings
from app.core.deps import SessionDep, SettingsDep, StorageDep
from app.core.errors import ConflictError, InvalidInputError
from app.core.security import CurrentUser, ReviewerUser
from app.live.schemas import LiveIn, LiveOut, LiveOutputOut, LiveRecords
from app.live.service import ACTIVE, LiveView, LiveViews, check_outputs
from app.training.service import get_model, model_folder, promoted_model
from weldpool_core.cell.outputs import OutputsConfig

router = APIRouter(prefix="/live", tags=["live"])
BOUNDARY = "weldpool-frame"


def _views(request: Request) -> LiveViews:
    views: LiveViews = request.app.state.live_views
    return views


def _out(view: LiveView) -> LiveOut:
    last = view.records[-1] if view.records else None
    return LiveOut(
        id=view.id,
        source=view.source,
        model_name=view.model_name,
        model_id=view.model_id,
        gate=view.gate,
        started_by=view.started_by,
        started_at=view.started_at,
        state=view.state,
        message=view.message,
        frames=view.frames,
        dropped=view.dropped,
        smooth=view.smooth,
        sequential=view.sequential,
        int8=view.int8,
        mm_per_px=view.mm_per_px,
        last=last,
        outputs=[
            LiveOutputOut(
                kind=status.kind,
                address=status.address,
                state=status.state,
                subscribers=status.subscribers,
                sent=status.sent,
                skipped=status.skipped,
                added_p99_ms=status.added_p99_ms,
            )
            for status in (view.outputs.statuses() if view.outputs is not None else [])
        ],
        **view.stats(),
    )


@router.post("", response_model=LiveOut, status_code=201)
def start_live(
    body: LiveIn,
    request: Request,
    session: SessionDep,
    storage: StorageDep,
    settings: SettingsDep,
    user: ReviewerUser,
) -> LiveOut:
    """Run a student on a source on this server and keep its newest frame and records."""
    if body.model_id is None:
        model = promoted_model(session)
        if model is None:
            raise ConflictError("No student is promoted yet; promote one or choose a version.")
    else:
        model = get_model(session, body.model_id)
    folder = model_folder(storage, model)
    if body.int8 and body.sequential:
        raise InvalidInputError("The int8 student runs frame by frame; choose int8 or sequential.")
    if body.sequential and not model.sequential:
        raise InvalidInputError(
            f"{model.name} has no sequential cell; train one on the models page first."
        )
    if body.int8 and not model.int8:
        raise InvalidInputError(
            f"{model.name} has no int8 student; make one on the models page first."
        )
    view = _views(request).start(
        {
            "source": body.source,
            "model_name": model.name,
            "model_id": model.id,
            "gate": model.gate,
            "model_dir": folder,
            "started_by": user.username,
            "smooth": body.smooth,
            "sequential": body.sequential,
            "int8": body.int8,
            "mm_per_px": body.mm_per_px,
            "travel_deg": body.travel_deg,
        },
        _outputs_config(body, settings),
    )
    return _out(view)


def _outputs_config(body: LiveIn, settings: Settings) -> OutputsConfig:
    """The outputs the form asked for, within what the admin allows (``check_outputs``; no
    security on OPC UA: the CLI has the options)."""
    from weldpool_core.cell.outputs.mqtt import MqttOptions
    from weldpool_core.cell.outputs.opcua import OpcUaOptions

    zeromq, opcua, mqtt = (
        (value or "").strip() or None for value in (body.zeromq, body.opcua, body.mqtt)
    )
    check_outputs(zeromq, opcua, mqtt, settings)
    return OutputsConfig(
        zeromq=zeromq,
        opcua=OpcUaOptions(opcua) if opcua else None,
        mqtt=MqttOptions(mqtt) if mqtt else None,
    )


@router.get("", response_model=list[LiveOut])
def list_live(request: Request, _user: CurrentUser) -> list[LiveOut]:
    """Live views of this server process, newest first."""
    return [_out(view) for view in _views(request).all()]


@router.get("/{view_id}", response_model=LiveOut)
def get_live(view_id: IdPath, request: Request, _user: CurrentUser) -> LiveOut:
    return _out(_views(request).get(view_id))


@router.get("/{view_id}/records", response_model=LiveRecords)
def live_records(
    view_id: IdPath,
    request: Request,
    _user: CurrentUser,
    after: int = Query(default=-1, ge=-1, le=2**62, description="Only frames after this index."),
    limit: int = Query(default=300, ge=1, le=900),
) -> LiveRecords:
    """The kept records (the last 900 frames) after frame index ``after``, oldest first."""
    return LiveRecords(records=_views(request).get(view_id).records_after(after, limit))


@router.get(
    "/{view_id}/mjpeg",
    response_class=StreamingResponse,
    responses={200: {"content": {f"multipart/x-mixed-replace; boundary={BOUNDARY}": {}}}},
)
def live_mjpeg(view_id: IdPath, request: Request, _user: CurrentUser) -> StreamingResponse:
    """The newest frames with the mask outline and keypoints drawn, as an MJPEG stream (an
    ``<img>`` shows it); it ends when the view ends."""
    view = _views(request).get(view_id)

    async def frames() -> AsyncIterator[bytes]:
        seen = 0
        while True:
            number, jpeg = await asyncio.to_thread(view.next_jpeg, seen, 1.0)
            if await request.is_disconnected():
                return
            if number > seen and jpeg:
                seen = number
                yield (
                    (
                        f"--{BOUNDARY}\r\nContent-Type: image/jpeg\r\n"
                        f"Content-Length: {len(jpeg)}\r\n\r\n"
                    ).encode()
                    + jpeg
                    + b"\r\n"
                )
            elif view.state not in ACTIVE:
                return

    return StreamingResponse(
        frames(),
        media_type=f"multipart/x-mixed-replace; boundary={BOUNDARY}",
        headers={"Cache-Control": "no-store"},
    )


@router.post("/{view_id}/stop", response_model=LiveOut)
def stop_live(view_id: IdPath, request: Request, _user: ReviewerUser) -> LiveOut:
    """Stop a view after its current frame."""
    return _out(_views(request).stop(view_id))
