"""Pixels read back from the store: a mask, a proposal's heatmap, a frame as the models see it."""

from __future__ import annotations

from typing import TYPE_CHECKING

from app.storage import Storage
from app.system.doctor import frame_file
from weldpool_core.io import decode_mask_png, read_image, to_rgb8

if TYPE_CHECKING:
    import numpy as np
    from numpy.typing import NDArray

    from app.core.models import Frame, Proposal
else:
    from weldpool_core.lazy import np


def load_mask(storage: Storage, path: str) -> NDArray[np.bool_]:
    return decode_mask_png(storage.existing(path).read_bytes())


def load_heatmap(storage: Storage, proposal: Proposal) -> NDArray[np.float32]:
    """The H×W×2 array (heatmap, mask) of a proposal, as Algorithm 1 returned it."""
    mask = load_mask(storage, proposal.mask_path).astype(np.float32)
    if proposal.heatmap_path is None:
        return np.stack([np.zeros_like(mask), mask], axis=2)
    with np.load(storage.existing(proposal.heatmap_path)) as data:
        heat = data["heatmap"].astype(np.float32)
    return np.stack([heat, mask], axis=2)


def frame_rgb(storage: Storage, frame: Frame) -> NDArray[np.uint8]:
    """The frame as the models see it (RGB uint8, 16-bit stretched); a lost file is the
    frame's MissingFile (which frame, what restores it)."""
    return to_rgb8(read_image(frame_file(storage, frame.path, frame.id)))


def stored_rgb(storage: Storage, path: str) -> NDArray[np.uint8]:
    """``frame_rgb`` of the frame file at ``path`` (for a thread that holds no row)."""
    return to_rgb8(read_image(storage.existing(path)))
