"""/api/v1/label-config: the instance's label configuration (any user reads it; admins save a
new version of it)."""

from __future__ import annotations

from fastapi import APIRouter

from app.core.deps import SessionDep
from app.core.security import AdminUser, CurrentUser
from app.labelconfig import service
from app.labelconfig.schemas import LabelConfigIn, LabelConfigOut

router = APIRouter(tags=["label configuration"])


def _out(now: service.Current) -> LabelConfigOut:
    return LabelConfigOut(
        **now.config,
        version=now.version,
        updated_by=now.user,
        updated_at=now.row.created_at if now.row is not None else None,
    )


@router.get("/label-config", response_model=LabelConfigOut, response_model_exclude_none=True)
def get_label_config(session: SessionDep, user: CurrentUser) -> LabelConfigOut:
    """The classes (the built-in `pool` first), their attributes, and the frame's tags and
    attributes, with the version a change starts from."""
    return _out(service.current(session))


@router.put("/label-config", response_model=LabelConfigOut, response_model_exclude_none=True)
def put_label_config(body: LabelConfigIn, session: SessionDep, user: AdminUser) -> LabelConfigOut:
    """A new version of the configuration (admins): 409 when `version` is not the current one,
    or when labels hold objects of a class it removes (unless `force`)."""
    return _out(service.save(session, user, body))
