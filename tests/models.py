"""The teacher's architectures built from configs with random weights (no download, ever).

Tiny configs keep the fast tests fast; ``full_*`` are the real sizes of facebook/dino-vits8 and
facebook/sam2.1-hiera-tiny, for the few slow tests. ``randomize`` gives every parameter (biases
too, which the models initialise to zero) a random value, so that comparisons between two code
paths cannot pass on zeros.
"""

from __future__ import annotations

import torch
from transformers import Sam2Config, ViTConfig
from transformers.models.sam2.configuration_sam2 import Sam2HieraDetConfig, Sam2VisionConfig

from weldpool_core.teacher.dino import DinoAttention, dino_vits8_config
from weldpool_core.teacher.sam2 import Sam2Predictor


def tiny_vit_config() -> ViTConfig:
    return ViTConfig(
        hidden_size=32,
        num_hidden_layers=3,
        num_attention_heads=2,
        intermediate_size=64,
        patch_size=8,
        image_size=64,
        qkv_bias=True,
        layer_norm_eps=1e-6,
    )


def tiny_sam2_config() -> Sam2Config:
    backbone = Sam2HieraDetConfig(
        hidden_size=8,
        num_attention_heads=1,
        blocks_per_stage=[1, 2, 2, 1],
        embed_dim_per_stage=[8, 16, 32, 64],
        num_attention_heads_per_stage=[1, 1, 1, 1],
        global_attention_blocks=[4],
    )
    vision = Sam2VisionConfig(
        backbone_config=backbone, backbone_channel_list=[64, 32, 16, 8], fpn_hidden_size=64
    )
    return Sam2Config(
        vision_config=vision,
        prompt_encoder_config={"hidden_size": 64},
        mask_decoder_config={
            "hidden_size": 64,
            "mlp_dim": 128,
            "iou_head_hidden_dim": 64,
            "num_attention_heads": 2,
        },
    )


def randomize(module: torch.nn.Module, seed: int = 0, std: float = 0.1) -> torch.nn.Module:
    """Every parameter and float buffer drawn from N(0, std) (norm weights around 1)."""
    generator = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for name, parameter in module.named_parameters():
            noise = torch.randn(parameter.shape, generator=generator) * std
            is_norm_weight = name.endswith("weight") and parameter.ndim == 1
            parameter.copy_(noise + 1.0 if is_norm_weight else noise)
    return module


def tiny_dino(seed: int = 0, input_size: int = 64) -> DinoAttention:
    torch.manual_seed(seed)
    dino = DinoAttention.from_config(tiny_vit_config(), input_size)
    randomize(dino.model, seed)
    return dino


def tiny_sam2(seed: int = 0) -> Sam2Predictor:
    torch.manual_seed(seed)
    predictor = Sam2Predictor.from_config(tiny_sam2_config())
    randomize(predictor.model, seed)
    return Sam2Predictor(predictor.model)  # recompute cached positional encodings


def full_dino(input_size: int = 480) -> DinoAttention:
    torch.manual_seed(0)
    return DinoAttention.from_config(dino_vits8_config(), input_size)


def full_sam2() -> Sam2Predictor:
    torch.manual_seed(0)
    return Sam2Predictor.from_config(Sam2Config())


def save_tiny_teacher(directory) -> dict[str, object]:  # type: ignore[no-untyped-def]
    """Tiny random DINO and SAM2 saved as Hugging Face directories; returns the settings that
    point the service at them."""
    tiny_dino().model.save_pretrained(directory / "dino")
    tiny_sam2().model.save_pretrained(directory / "sam2")
    return {
        "dino": str(directory / "dino"),
        "sam2": str(directory / "sam2"),
        "dino_input_size": 64,
        "device": "cpu",
    }
