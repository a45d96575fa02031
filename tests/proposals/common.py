"""Proposals the policy and gate tests set up by hand, at one small size (their frames:
``tests.factories.random_images`` at ``W``×``H``)."""

from __future__ import annotations

import numpy as np

from app.core.models import Proposal
from app.proposals.files import store_mask
from app.storage import Storage

W, H = 96, 64


def propose(
    session_factory, storage: Storage, frame_id: int, source: str, model_id: str, mask: np.ndarray
) -> int:
    with session_factory() as session:
        proposal = Proposal(
            frame_id=frame_id,
            source=source,
            model_id=model_id,
            mask_path=store_mask(storage, mask),
            keypoints=[],
        )
        session.add(proposal)
        session.commit()
        return proposal.id


def box(x0: int, x1: int) -> np.ndarray:
    mask = np.zeros((H, W), bool)
    mask[10:50, x0:x1] = True
    return mask
