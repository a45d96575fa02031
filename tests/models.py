"""The teacher's architectures built from configs with random weights (no download, ever).

Tiny configs keep the fast tests fast; ``full_*`` are the real sizes of facebook/dino-vits8 and
facebook/sam2.1-hiera-tiny, for the few slow tests. ``randomize`` gives every parameter (biases
too, which the models initialise to zero) a random value, so that comparisons between two code
paths cannot pass on zeros.
"""

from __future__ import annotations

from typing import Any

import torch
from transformers import Sam2Config, Sam2Model, ViTConfig
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


def tiny_sam2_config(hidden: int = 64) -> Sam2Config:
    backbone = Sam2HieraDetConfig(
        hidden_size=8,
        num_attention_heads=1,
        blocks_per_stage=[1, 2, 2, 1],
        embed_dim_per_stage=[8, 16, 32, 64],
        num_attention_heads_per_stage=[1, 1, 1, 1],
        global_attention_blocks=[4],
    )
    vision = Sam2VisionConfig(
        backbone_config=backbone, backbone_channel_list=[64, 32, 16, 8], fpn_hidden_size=hidden
    )
    return Sam2Config(
        vision_config=vision,
        prompt_encoder_config={"hidden_size": hidden},
        mask_decoder_config={
            "hidden_size": hidden,
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
    # One SAM2 checkpoint serves the image model (clicks, the teacher) and the video model
    # (propagation), as the hub's do.
    tiny_sam2_pair()[1].model.save_pretrained(directory / "sam2")
    return {
        "dino": str(directory / "dino"),
        "sam2": str(directory / "sam2"),
        "dino_input_size": 64,
        "device": "cpu",
    }


def tiny_sam2_video_config() -> Any:
    """The tiny SAM2 above as a video model (same image parts, plus memory attention). Its
    width is 128: SAM2's memory is 64 channels wide, and object pointers are split into
    memory-sized tokens, so the model must be wider than its memory (SAM2 is 256)."""
    from transformers import Sam2VideoConfig

    image = tiny_sam2_config(128)
    return Sam2VideoConfig(
        vision_config=image.vision_config,
        prompt_encoder_config=image.prompt_encoder_config.to_dict(),
        mask_decoder_config=image.mask_decoder_config.to_dict(),
        num_maskmem=3,  # SAM2: 7 memory frames, 16 object pointers; fewer keep tests quick
        max_object_pointers_in_encoder=4,
        memory_attention_hidden_size=128,
        memory_attention_num_layers=1,
        memory_attention_feed_forward_hidden_size=128,
        memory_encoder_hidden_size=128,
        memory_encoder_output_channels=64,
        mask_downsampler_embed_dim=128,
        memory_fuser_embed_dim=128,
        memory_fuser_intermediate_dim=128,
    )


def tiny_sam2_pair(seed: int = 0) -> tuple[Sam2Predictor, Any]:
    """A tiny random SAM2 video model and the image predictor sharing its weights (as one
    checkpoint directory gives both)."""
    from transformers import Sam2VideoModel

    from weldpool_core.teacher.propagate import Sam2Propagator

    torch.manual_seed(seed)
    config = tiny_sam2_video_config()
    config._attn_implementation = "sdpa"
    video = randomize(Sam2VideoModel(config), seed)
    image = Sam2Model(tiny_sam2_config(128))
    missing, _ = image.load_state_dict(video.state_dict(), strict=False)
    assert not missing, missing
    return Sam2Predictor(image), Sam2Propagator(video)
