"""DINO attention: the last-block-only path equals the straightforward one."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from tests.models import full_dino, tiny_dino


def _frame(height: int = 90, width: int = 120, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (height, width, 3), dtype=np.uint8)


def _straightforward(dino, image):
    """Every attention returned by the eager path; the last block's CLS row, and the CLS."""
    model = dino.model
    model.config._attn_implementation = "eager"
    try:
        with torch.inference_mode():
            out = model(
                pixel_values=dino.preprocess(image),
                interpolate_pos_encoding=True,
                output_attentions=True,
            )
    finally:
        model.config._attn_implementation = "sdpa"
    return out.attentions[-1][0, :, 0, 1:].numpy(), out.last_hidden_state[0, 0].numpy()


def test_last_block_attention_equals_all_attentions_path() -> None:
    dino = tiny_dino(input_size=64)
    image = _frame()
    maps = dino(image)
    expected, cls = _straightforward(dino, image)
    heads = maps.heads.reshape(len(maps.heads), -1)
    np.testing.assert_allclose(heads, expected, atol=1e-6)
    np.testing.assert_allclose(maps.cls, cls, atol=1e-5)
    assert heads.std() > 1e-3  # the comparison is not between two flat maps


@pytest.mark.parametrize("dtype", [torch.bfloat16, torch.float16])
def test_half_precision_attention_follows_the_fp32_path(dtype: torch.dtype) -> None:
    """On a GPU DINO runs in bf16 (fp16 on older cards): its last-block path in that precision
    stays close to the fp32 eager path, and the attended region barely changes."""
    import copy

    from weldpool_core.teacher.dino import DinoAttention

    dino = tiny_dino(input_size=64)
    half = DinoAttention(copy.deepcopy(dino.model).to(dtype), 64)
    image = _frame()
    maps = half(image)
    expected, cls = _straightforward(dino, image)
    heads = maps.heads.reshape(len(maps.heads), -1)
    assert heads.dtype == np.float32  # maps come back in fp32 whatever the model runs in
    np.testing.assert_allclose(heads, expected, atol=0.02 * float(np.abs(expected).max()))
    np.testing.assert_allclose(maps.cls, cls, atol=0.05 * float(np.abs(cls).max()))
    full = dino(image)
    assert (maps.attended != full.attended).mean() < 0.1


def test_maps_threshold_and_upsampling() -> None:
    dino = tiny_dino(input_size=64)
    maps = dino(_frame(90, 120))
    assert maps.heads.shape == (2, 8, 8) and maps.grid == (8, 8)
    np.testing.assert_allclose(maps.mean, maps.heads.mean(0), atol=1e-7)
    assert np.array_equal(maps.attended, maps.mean > maps.mean.mean())
    assert maps.upsampled().shape == (90, 120)
    np.testing.assert_allclose(maps.heads.reshape(2, -1).sum(1), 1.0, atol=0.05)  # CLS ≈ 1/N


def test_input_size_must_fit_the_patches() -> None:
    from weldpool_core.errors import InvalidInputError

    with pytest.raises(InvalidInputError, match="multiple of the patch size"):
        tiny_dino(input_size=60)
    with pytest.raises(InvalidInputError, match="RGB uint8"):
        tiny_dino()(np.zeros((10, 10), np.uint8))


@pytest.mark.slow
def test_full_size_dino_vits8_at_224() -> None:
    dino = full_dino(224)
    image = _frame(800, 1280)
    maps = dino(image)
    assert maps.heads.shape == (6, 28, 28) and maps.cls.shape == (384,)
    expected, _ = _straightforward(dino, image)
    np.testing.assert_allclose(maps.heads.reshape(6, -1), expected, atol=1e-6)
