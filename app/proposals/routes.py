"""The proposal endpoints: the proposal a frame shows (or one asked for), every proposal of a
frame with the policy's choice, and the shown proposal's mask and heatmap as files."""

from __future__ import annotations

import base64
from typing import TYPE_CHECKING, Annotated

from fastapi import APIRouter, Depends, Query, Response

from app.core.bounds import IdPath
from app.core.deps import SessionDep, StorageDep
from app.core.errors import NotFoundError
from app.core.models import Proposal, get_frame
from app.core.security import CurrentUser
from app.proposals import policy
from app.proposals.schemas import ProposalList, ProposalOut, ProposalSummary
from app.storage.pixels import load_heatmap
from app.system.doctor import frame_file
from weldpool_core.heatmap import heatmap_rgba
from weldpool_core.io import encode_png

if TYPE_CHECKING:
    import numpy as np
else:
    from weldpool_core.lazy import np

router = APIRouter(tags=["proposals"])


def _b64(data: bytes) -> str:
    return base64.b64encode(data).decode("ascii")


SourceQuery = Annotated[
    str | None,
    Query(
        max_length=300,
        description="A source key (`teacher`, `student:<version>`) instead of the policy's.",
    ),
]


ProposalQuery = Annotated[
    int | None, Query(ge=1, le=2**31 - 1, description="One proposal of the frame, by id.")
]


def _shown_proposal(
    frame_id: IdPath,
    session: SessionDep,
    storage: StorageDep,
    source: SourceQuery = None,
    proposal_id: ProposalQuery = None,
) -> Proposal:
    """The proposal a request means: ``proposal_id``, else the newest of ``source``, else the
    policy's pick; 404 when the frame has none."""
    get_frame(session, frame_id)
    proposal = policy.pick(session, storage, frame_id, source, proposal_id)
    if proposal is None:
        raise NotFoundError(f"Frame {frame_id} has no proposal yet; run the teacher on it.")
    return proposal


ShownProposal = Annotated[Proposal, Depends(_shown_proposal)]


def _summary(proposal, chosen: int | None) -> ProposalSummary:  # type: ignore[no-untyped-def]
    return ProposalSummary(
        id=proposal.id,
        frame_id=proposal.frame_id,
        source=proposal.source,
        source_key=policy.source_key(proposal),
        model_id=proposal.model_id,
        model_version_id=proposal.model_version_id,
        job_id=proposal.job_id,
        keypoints=proposal.keypoints,
        scores=proposal.scores,
        created_at=proposal.created_at,
        chosen=proposal.id == chosen,
    )


@router.get("/frames/{frame_id}/proposal", response_model=ProposalOut)
def get_proposal(
    frame_id: IdPath,
    session: SessionDep,
    storage: StorageDep,
    _user: CurrentUser,
    proposal: ShownProposal,
) -> ProposalOut:
    """The proposal the policy picks for review (or the one asked for): mask (base64 PNG),
    keypoints, prompts, scores and where it came from."""
    chosen = policy.pick(session, storage, frame_id)
    return ProposalOut(
        **_summary(proposal, chosen.id if chosen else None).model_dump(),
        mask_png=_b64(_proposal_mask(storage, proposal)),
        prompts=proposal.prompts,
        timings=proposal.timings,
    )


@router.get("/frames/{frame_id}/proposals", response_model=ProposalList)
def list_proposals(
    frame_id: IdPath, session: SessionDep, storage: StorageDep, _user: CurrentUser
) -> ProposalList:
    """Every proposal the frame has, newest first, with its source and scores; `chosen` marks
    the one the policy shows, and `policy` says why that source."""
    get_frame(session, frame_id)
    chosen = policy.pick(session, storage, frame_id)
    return ProposalList(
        items=[
            _summary(p, chosen.id if chosen else None)
            for p in policy.frame_proposals(session, frame_id)
        ],
        policy=policy.current(session, storage).as_dict(),
    )


@router.get(
    "/frames/{frame_id}/proposal/mask.png",
    response_class=Response,
    responses={200: {"content": {"image/png": {}}}},
)
def get_proposal_mask(storage: StorageDep, _user: CurrentUser, proposal: ShownProposal) -> Response:
    """The shown proposal's mask as a PNG (0 / 255)."""
    return Response(_proposal_mask(storage, proposal), media_type="image/png")


def _proposal_mask(storage: StorageDep, proposal: Proposal) -> bytes:
    return frame_file(storage, proposal.mask_path, proposal.frame_id, "proposal mask").read_bytes()


@router.get(
    "/frames/{frame_id}/proposal/heatmap.png",
    response_class=Response,
    responses={200: {"content": {"image/png": {}}}},
)
def get_proposal_heatmap_png(
    storage: StorageDep, _user: CurrentUser, proposal: ShownProposal
) -> Response:
    """The heatmap as a colour map (RGBA, transparent where it is zero) for display."""
    rgba = heatmap_rgba(load_heatmap(storage, proposal)[:, :, 0])
    return Response(encode_png(rgba), media_type="image/png")


@router.get(
    "/frames/{frame_id}/proposal/heatmap.npy",
    response_class=Response,
    responses={200: {"content": {"application/octet-stream": {}}}},
)
def get_proposal_heatmap_npy(
    storage: StorageDep, _user: CurrentUser, proposal: ShownProposal
) -> Response:
    """The raw H×W×2 float32 array (heatmap, mask) as a .npy file."""
    import io

    buffer = io.BytesIO()
    np.save(buffer, load_heatmap(storage, proposal))
    return Response(buffer.getvalue(), media_type="application/octet-stream")
