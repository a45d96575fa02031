"""Meta's DINO checkpoint format → ViTModel: every key used, every parameter filled, same outputs.

The reference below is the forward pass of the DINO repository's ViT written out from its
description (patch conv, CLS token, position embeddings, pre-norm blocks with a fused qkv,
exact GELU, final norm), run on a Meta-format state dict of random tensors.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from tests.helpers import run_cli
from weldpool_core.errors import InvalidInputError
from weldpool_core.teacher.convert import convert_meta_dino, dino_from_meta, meta_dino_config
from weldpool_core.teacher.dino import DinoAttention, dino_vits8_config

WIDTH, DEPTH, PATCH, GRID, HIDDEN = 128, 3, 8, 4, 256


def meta_state(
    width: int = WIDTH,
    depth: int = DEPTH,
    patch: int = PATCH,
    grid: int = GRID,
    hidden: int = HIDDEN,
) -> dict[str, torch.Tensor]:
    """A random state dict with the keys and shapes of the DINO repository's ViT."""
    g = torch.Generator().manual_seed(0)

    def rand(*shape: int, scale: float = 0.05, offset: float = 0.0) -> torch.Tensor:
        return offset + scale * torch.randn(*shape, generator=g)

    state = {
        "cls_token": rand(1, 1, width, scale=0.5),
        "pos_embed": rand(1, grid * grid + 1, width, scale=0.5),
        "patch_embed.proj.weight": rand(width, 3, patch, patch),
        "patch_embed.proj.bias": rand(width),
        "norm.weight": rand(width, offset=1.0),
        "norm.bias": rand(width),
    }
    for i in range(depth):
        state |= {
            f"blocks.{i}.norm1.weight": rand(width, offset=1.0),
            f"blocks.{i}.norm1.bias": rand(width),
            f"blocks.{i}.attn.qkv.weight": rand(3 * width, width, scale=0.2),
            f"blocks.{i}.attn.qkv.bias": rand(3 * width),
            f"blocks.{i}.attn.proj.weight": rand(width, width),
            f"blocks.{i}.attn.proj.bias": rand(width),
            f"blocks.{i}.norm2.weight": rand(width, offset=1.0),
            f"blocks.{i}.norm2.bias": rand(width),
            f"blocks.{i}.mlp.fc1.weight": rand(hidden, width),
            f"blocks.{i}.mlp.fc1.bias": rand(hidden),
            f"blocks.{i}.mlp.fc2.weight": rand(width, hidden),
            f"blocks.{i}.mlp.fc2.bias": rand(width),
        }
    return state


def reference_forward(
    state: dict[str, torch.Tensor], pixels: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """DINO's ViT at its native size: the final normed tokens, and the last block's attention."""
    width = state["cls_token"].shape[-1]
    heads = width // 64

    def norm(x: torch.Tensor, name: str) -> torch.Tensor:
        return F.layer_norm(x, (width,), state[f"{name}.weight"], state[f"{name}.bias"], 1e-6)

    def linear(x: torch.Tensor, name: str) -> torch.Tensor:
        return F.linear(x, state[f"{name}.weight"], state[f"{name}.bias"])

    patch_embed = (state["patch_embed.proj.weight"], state["patch_embed.proj.bias"])
    x = F.conv2d(pixels, *patch_embed, stride=state["patch_embed.proj.weight"].shape[-1])
    x = x.flatten(2).transpose(1, 2)
    x = torch.cat([state["cls_token"].expand(x.shape[0], -1, -1), x], dim=1) + state["pos_embed"]
    depth = 1 + max(int(k.split(".")[1]) for k in state if k.startswith("blocks."))
    attention = torch.empty(0)
    for i in range(depth):
        b = f"blocks.{i}"
        batch, tokens, _ = x.shape
        qkv = linear(norm(x, f"{b}.norm1"), f"{b}.attn.qkv")
        q, k, v = qkv.reshape(batch, tokens, 3, heads, width // heads).permute(2, 0, 3, 1, 4)
        attention = ((q @ k.transpose(-2, -1)) * (width // heads) ** -0.5).softmax(dim=-1)
        mixed = (attention @ v).transpose(1, 2).reshape(batch, tokens, width)
        x = x + linear(mixed, f"{b}.attn.proj")
        x = x + linear(F.gelu(linear(norm(x, f"{b}.norm2"), f"{b}.mlp.fc1")), f"{b}.mlp.fc2")
    return norm(x, "norm"), attention


def test_converted_model_computes_what_dinos_vit_computes() -> None:
    state = meta_state()
    model = dino_from_meta(state)
    pixels = torch.randn(
        2, 3, GRID * PATCH, GRID * PATCH, generator=torch.Generator().manual_seed(1)
    )
    expected_tokens, _ = reference_forward(state, pixels)
    with torch.inference_mode():
        tokens = model(pixel_values=pixels).last_hidden_state
    assert torch.allclose(tokens, expected_tokens, atol=1e-4)

    dino = DinoAttention(model, input_size=GRID * PATCH)
    frame = np.random.default_rng(2).integers(0, 256, (48, 64, 3), dtype=np.uint8)
    maps = dino(frame)
    frame_tokens, attention = reference_forward(state, dino.preprocess(frame))
    cls_to_patches = attention[0, :, 0, 1:].reshape(-1, GRID, GRID).numpy()
    assert np.allclose(maps.heads, cls_to_patches, atol=1e-5)
    assert np.allclose(maps.cls, frame_tokens[0, 0].numpy(), atol=1e-4)


def test_the_vits8_checkpoint_gives_the_hub_models_architecture() -> None:
    config = meta_dino_config(meta_state(width=384, depth=12, patch=8, grid=28, hidden=1536))
    hub = dino_vits8_config()
    for field in (
        "hidden_size",
        "num_hidden_layers",
        "num_attention_heads",
        "intermediate_size",
        "patch_size",
        "image_size",
        "qkv_bias",
        "layer_norm_eps",
        "hidden_act",
    ):
        assert getattr(config, field) == getattr(hub, field), field


def test_training_checkpoints_give_their_teacher_backbone() -> None:
    state = meta_state()
    wrapped = {f"module.backbone.{k}": v for k, v in state.items()}
    wrapped["module.head.last_layer.weight"] = torch.zeros(4, 4)  # DINO's projection head
    checkpoint = {"teacher": wrapped, "student": {}, "epoch": 100}
    plain = dino_from_meta(state).state_dict()
    for name, value in dino_from_meta(checkpoint).state_dict().items():
        assert torch.equal(value, plain[name]), name


def test_every_key_is_used_and_every_parameter_filled() -> None:
    state = meta_state()
    with pytest.raises(InvalidInputError, match=r"does not use, e\.g\. 'blocks\.0\.attn\.extra'"):
        dino_from_meta(state | {"blocks.0.attn.extra": torch.zeros(1)})
    missing = {k: v for k, v in state.items() if k != "blocks.1.mlp.fc2.bias"}
    with pytest.raises(InvalidInputError, match=r"fills no 'layers\.1\.mlp\.fc2\.bias'"):
        dino_from_meta(missing)
    with pytest.raises(InvalidInputError, match="not a DINO ViT checkpoint"):
        dino_from_meta({"weight": torch.zeros(3)})
    wrong = state | {"blocks.0.mlp.fc2.weight": torch.zeros(WIDTH, 7)}
    with pytest.raises(InvalidInputError, match="shape"):
        dino_from_meta(wrong)


def test_convert_writes_a_directory_the_teacher_loads(tmp_path) -> None:  # type: ignore[no-untyped-def]
    from transformers import ViTModel

    state = meta_state()
    checkpoint = tmp_path / "dino_deitsmall8_pretrain.pth"
    torch.save(state, checkpoint)
    out = tmp_path / "dino"
    result = run_cli("weights", "convert-dino", checkpoint, "--out", out)
    assert result.returncode == 0, result.stderr
    assert f"set WELDPOOL_DINO={out}" in result.stderr
    loaded = ViTModel.from_pretrained(out, add_pooling_layer=False)
    pixels = torch.randn(1, 3, GRID * PATCH, GRID * PATCH)
    with torch.inference_mode():
        tokens = loaded(pixel_values=pixels).last_hidden_state
    assert torch.allclose(tokens, reference_forward(state, pixels)[0], atol=1e-4)
    status = run_cli("weights", "status", env={"WELDPOOL_DINO": str(out)})
    assert '"source": "local"' in status.stdout and '"detail": "ready"' in status.stdout

    again = run_cli("weights", "convert-dino", checkpoint, "--out", out)
    assert again.returncode == 2 and "is not empty" in again.stderr
    (tmp_path / "junk.pth").write_bytes(b"not a checkpoint")
    junk = run_cli("weights", "convert-dino", tmp_path / "junk.pth", "--out", tmp_path / "x")
    lines = junk.stderr.strip().splitlines()
    assert junk.returncode == 2 and len(lines) == 1
    junk_file = tmp_path / "junk.pth"
    assert lines[0].startswith(f"weldpool: {junk_file} is not a plain PyTorch state dict (")
    with pytest.raises(InvalidInputError, match="does not exist"):
        convert_meta_dino(tmp_path / "nope.pth", tmp_path / "y")
