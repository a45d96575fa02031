"""The one loader of the teacher's models: DINO and SAM2 (image and video) from a hub id or a
local directory.

``Teacher.load`` (command line, library) and the service's runtime (worker jobs, clicks) both
load through here, so the device, the precision, the attention kernel and the weights' identity
(which names cached embeddings) are chosen in one place.
"""

from __future__ import annotations

import logging
from typing import Any

from weldpool_core.teacher.dino import DinoAttention
from weldpool_core.teacher.propagate import Sam2Propagator
from weldpool_core.teacher.sam2 import Sam2Predictor


def load_sam2(ref: str, device: str = "auto") -> Sam2Predictor:
    """SAM2 named by ``ref`` (WELDPOOL_SAM2), in the device's inference precision.

    Raises WeightsUnavailableError when the weights are not on this machine.
    """
    from transformers import Sam2Model
    from transformers.utils import logging as hf_logging

    from weldpool_core.device import inference_dtype, resolve_device
    from weldpool_core.teacher.weights import resolve_weights, weights_identity

    torch_device = resolve_device(device)
    path = resolve_weights(ref, "WELDPOOL_SAM2")
    # The image model from a video checkpoint (the hub's SAM2.1 are those) is expected: no
    # "model of type sam2_video" warning on every load.
    verbosity = hf_logging.get_verbosity()
    hf_logging.set_verbosity(logging.ERROR)
    try:
        model = Sam2Model.from_pretrained(
            path, attn_implementation="sdpa", dtype=inference_dtype(torch_device)
        )
    finally:
        hf_logging.set_verbosity(verbosity)
    return Sam2Predictor(model, torch_device, weights_id=weights_identity(ref, path))


def load_sam2_video(
    ref: str, device: str = "auto", image_model: Sam2Predictor | None = None
) -> Sam2Propagator:
    """SAM2's video model from the same weights as ``load_sam2`` (one checkpoint holds the image
    parts and the memory), for propagation through a run.

    ``image_model``: the process's image predictor loaded from the same checkpoint. Propagation
    takes every frame's features from the image predictor (the one embedding seam), so the video
    model's own vision encoder — most of SAM2's weights — would sit unused beside an identical
    copy: it is replaced by the image model's (one copy in memory). Refused when the two were
    not loaded from the same weights.
    """
    from transformers import Sam2VideoModel

    from weldpool_core.device import inference_dtype, resolve_device
    from weldpool_core.teacher.weights import resolve_weights, weights_identity

    torch_device = resolve_device(device)
    path = resolve_weights(ref, "WELDPOOL_SAM2")
    model = Sam2VideoModel.from_pretrained(
        path, attn_implementation="sdpa", dtype=inference_dtype(torch_device)
    )
    if image_model is not None:
        expected = weights_identity(ref, path)
        if image_model.weights_id != expected:
            raise ValueError(
                f"The image model ({image_model.weights_id}) is not from the video model's "
                f"weights ({expected}); its vision encoder cannot be shared."
            )
        share_vision_encoder(model, image_model)
    return Sam2Propagator(model, torch_device)


def share_vision_encoder(video_model: Any, image_model: Sam2Predictor) -> None:
    """Give ``video_model`` (a ``Sam2VideoModel``) the image predictor's vision encoder in place
    of its own (same class, same checkpoint: the same weights), freeing its copy."""
    ours, theirs = video_model.vision_encoder, image_model.model.vision_encoder
    if type(ours) is not type(theirs) or ours.config.to_dict() != theirs.config.to_dict():
        raise ValueError("The image model's vision encoder is not the video model's.")
    video_model.vision_encoder = theirs


def load_dino(ref: str, device: str = "auto", input_size: int = 480) -> DinoAttention:
    """DINO named by ``ref`` (WELDPOOL_DINO), in the device's inference precision."""
    from transformers import ViTModel

    from weldpool_core.device import inference_dtype, resolve_device
    from weldpool_core.teacher.weights import resolve_weights, weights_identity

    torch_device = resolve_device(device)
    path = resolve_weights(ref, "WELDPOOL_DINO")
    model = ViTModel.from_pretrained(
        path,
        add_pooling_layer=False,
        attn_implementation="sdpa",
        dtype=inference_dtype(torch_device),
    )
    dino = DinoAttention(model, input_size, torch_device)
    dino.weights_id = weights_identity(ref, path)
    return dino
