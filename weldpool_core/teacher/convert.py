"""Meta's original DINO checkpoints (``dino_deitsmall8_pretrain.pth``, …) → ``ViTModel``.

The DINO repository releases its backbones as plain PyTorch state dicts of its own ViT
(``cls_token``, ``pos_embed``, ``patch_embed.proj``, ``blocks.N.{norm1,attn.qkv,attn.proj,
norm2,mlp.fc1,mlp.fc2}``, ``norm``). ``dino_from_meta`` maps every key onto transformers'
``ViTModel`` (the fused ``qkv`` split into query, key and value), infers the architecture from
the tensors' shapes (width, depth, patch size, grid; 64 channels per head as in every DINO ViT),
and refuses a checkpoint with a key it does not use or a parameter it does not fill. Training
checkpoints (``checkpoint.pth`` with ``teacher`` / ``student``) give their ``teacher``
backbone; the projection head (``head.*``) is not part of the backbone and is left out.

``weldpool weights convert-dino FILE --out DIR`` writes the result with ``save_pretrained``, so
``WELDPOOL_DINO=DIR`` loads it like any local directory.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any, cast

import torch
from transformers import ViTConfig, ViTModel

from weldpool_core.errors import InvalidInputError

HEAD_DIM = 64
_BLOCK = re.compile(r"blocks\.(\d+)\.(.+)")
_BLOCK_NAMES = {
    "norm1": "layernorm_before",
    "attn.proj": "attention.o_proj",
    "norm2": "layernorm_after",
    "mlp.fc1": "mlp.fc1",
    "mlp.fc2": "mlp.fc2",
}
_TOP_NAMES = {
    "cls_token": "embeddings.cls_token",
    "pos_embed": "embeddings.position_embeddings",
    "patch_embed.proj.weight": "embeddings.patch_embeddings.projection.weight",
    "patch_embed.proj.bias": "embeddings.patch_embeddings.projection.bias",
    "norm.weight": "layernorm.weight",
    "norm.bias": "layernorm.bias",
}


def backbone_state(checkpoint: Mapping[str, Any]) -> dict[str, torch.Tensor]:
    """The backbone's tensors of a DINO checkpoint, prefixes (``module.``, ``backbone.``) off."""
    state: Mapping[str, Any] = checkpoint
    if "teacher" in checkpoint and isinstance(checkpoint["teacher"], Mapping):
        state = checkpoint["teacher"]
    elif "state_dict" in checkpoint and isinstance(checkpoint["state_dict"], Mapping):
        state = checkpoint["state_dict"]
    backbone: dict[str, torch.Tensor] = {}
    for key, value in state.items():
        name = key.removeprefix("module.").removeprefix("backbone.")
        if name.startswith("head."):
            continue  # DINO's projection head, used in training only
        if not isinstance(value, torch.Tensor):
            raise InvalidInputError(f"The checkpoint's entry {key!r} is not a tensor.")
        backbone[name] = value
    return backbone


def meta_dino_config(state: Mapping[str, torch.Tensor]) -> ViTConfig:
    """The ``ViTConfig`` of a DINO backbone, read off its tensors' shapes."""
    try:
        width = int(state["cls_token"].shape[-1])
        patch = int(state["patch_embed.proj.weight"].shape[-1])
        positions = int(state["pos_embed"].shape[1]) - 1
        hidden = int(state["blocks.0.mlp.fc1.weight"].shape[0])
    except KeyError as exc:
        raise InvalidInputError(
            f"This is not a DINO ViT checkpoint: it has no {exc.args[0]!r}."
        ) from None
    depth = 1 + max(int(m.group(1)) for key in state if (m := _BLOCK.match(key)))
    grid = math.isqrt(positions)
    if grid * grid != positions or width % HEAD_DIM:
        raise InvalidInputError("The checkpoint's position grid or width is not a DINO ViT's.")
    return ViTConfig(
        hidden_size=width,
        num_hidden_layers=depth,
        num_attention_heads=width // HEAD_DIM,
        intermediate_size=hidden,
        patch_size=patch,
        image_size=grid * patch,
        qkv_bias="blocks.0.attn.qkv.bias" in state,
        layer_norm_eps=1e-6,
    )


def _hf_tensors(name: str, value: torch.Tensor) -> dict[str, torch.Tensor]:
    """The ``ViTModel`` tensors that hold one tensor of Meta's ViT."""
    if name in _TOP_NAMES:
        return {_TOP_NAMES[name]: value}
    match = _BLOCK.match(name)
    if match is None:
        return {}
    index, rest = match.groups()
    prefix = f"layers.{index}."
    if rest.startswith("attn.qkv."):
        kind = rest.removeprefix("attn.qkv.")
        query, key, value_part = value.chunk(3, dim=0)
        return {
            f"{prefix}attention.q_proj.{kind}": query,
            f"{prefix}attention.k_proj.{kind}": key,
            f"{prefix}attention.v_proj.{kind}": value_part,
        }
    module, _, kind = rest.rpartition(".")
    if module in _BLOCK_NAMES:
        return {f"{prefix}{_BLOCK_NAMES[module]}.{kind}": value}
    return {}


def dino_from_meta(checkpoint: Mapping[str, Any]) -> ViTModel:
    """A ``ViTModel`` holding the backbone of Meta's DINO checkpoint (see the module doc)."""
    state = backbone_state(checkpoint)
    model = ViTModel(meta_dino_config(state), add_pooling_layer=False)
    targets = model.state_dict()
    converted: dict[str, torch.Tensor] = {}
    unused = []
    for name, value in state.items():
        tensors = _hf_tensors(name, value)
        if not tensors:
            unused.append(name)
        converted.update(tensors)
    if unused:
        raise InvalidInputError(
            f"The checkpoint has {len(unused)} tensors a DINO ViT does not use, e.g. {unused[0]!r}."
        )
    missing = sorted(set(targets) - set(converted))
    if missing:
        raise InvalidInputError(f"The checkpoint fills no {missing[0]!r} ({len(missing)} missing).")
    for name, value in converted.items():
        if tuple(value.shape) != tuple(targets[name].shape):
            raise InvalidInputError(
                f"{name}: the checkpoint's shape {tuple(value.shape)} is not the model's "
                f"{tuple(targets[name].shape)}."
            )
    model.load_state_dict(converted, strict=True)
    cast(Any, model).eval()
    return model


def convert_meta_dino(checkpoint_file: str | Path, out_dir: str | Path) -> ViTConfig:
    """Read Meta's DINO ``.pth`` and write a ``save_pretrained`` directory; returns its config."""
    path = Path(checkpoint_file)
    if not path.is_file():
        raise InvalidInputError(f"{path} does not exist.")
    try:
        checkpoint = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:
        raise InvalidInputError(
            f"{path} is not a plain PyTorch state dict ({type(exc).__name__}); give DINO's "
            "released backbone file (e.g. dino_deitsmall8_pretrain.pth)."
        ) from None
    if not isinstance(checkpoint, Mapping):
        raise InvalidInputError(f"{path} holds no state dict.")
    model = dino_from_meta(checkpoint)
    model.save_pretrained(out_dir)
    config: ViTConfig = model.config
    return config
