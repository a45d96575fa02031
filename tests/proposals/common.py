"""Frames and proposals the policy and gate tests set up by hand, at one small size."""

from __future__ import annotations

import numpy as np
from fastapi.testclient import TestClient

from app.core.models import Proposal
from app.proposals.files import store_mask
from app.storage import Storage
from tests.helpers import auth, image_bytes

W, H = 96, 64


def upload(client: TestClient, token: str, first_seed: int, count: int) -> list[int]:
    files = [
        ("files", (f"{i}.png", image_bytes(W, H, seed=first_seed + i), "image/png"))
        for i in range(count)
    ]
    stored = client.post("/api/v1/frames", files=files, headers=auth(token)).json()["stored"]
    return [f["id"] for f in stored]


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
