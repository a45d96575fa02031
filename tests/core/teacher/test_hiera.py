"""SAM2's image encoder re-stated (``hiera.ImageEncoder``) gives transformers' numbers.

The tiny config keeps every path of the full one: windows that tile the map and windows that
need padding (14 on 64²), query pooling at each stage change, a global-attention block, the
FPN's top-down levels, the decoder's two projections and the no-memory embedding; here with
several heads per stage (as the full model has), so the heads' channel order is checked too.
Every parameter is random (biases and positional embeddings too), so a dropped term cannot pass.
"""

from __future__ import annotations

import copy

import pytest
import torch
import torch.nn.functional as F

from tests.models import randomize, tiny_sam2_config
from weldpool_core.teacher import hiera
from weldpool_core.teacher.hiera import ImageEncoder

PIXELS = torch.randn(1, 3, 1024, 1024, generator=torch.Generator().manual_seed(5))


def _model(top_down_levels: list[int] | None = None):
    from transformers import Sam2Model

    config = tiny_sam2_config()
    config.vision_config.backbone_config.num_attention_heads_per_stage = [1, 2, 2, 4]
    if top_down_levels is not None:
        config.vision_config.fpn_top_down_levels = top_down_levels
    config._attn_implementation = "sdpa"
    torch.manual_seed(0)
    return randomize(Sam2Model(config), seed=4).eval()


@pytest.fixture(scope="module")
def model():
    return _model()


def _compare(model, pixels, rtol: float, atol: float) -> None:
    with torch.inference_mode():
        theirs = model.get_image_embeddings(pixels)
        ours = ImageEncoder(model)(pixels)
    assert len(ours) == len(theirs) == 3
    for mine, reference in zip(ours, theirs, strict=True):
        assert mine.shape == reference.shape and mine.dtype == reference.dtype
        scale = float(reference.float().abs().max())
        torch.testing.assert_close(mine.float(), reference.float(), rtol=rtol, atol=atol * scale)


@pytest.mark.parametrize("band_tokens", [hiera.BAND_TOKENS, 8192])
def test_the_encoder_equals_transformers_forward_in_fp32(model, monkeypatch, band_tokens) -> None:
    """The first blocks whole (the default) and a band of rows at a time."""
    monkeypatch.setattr(hiera, "BAND_TOKENS", band_tokens)
    _compare(model, PIXELS, rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("amx", [False, True])
def test_the_encoder_equals_transformers_forward_in_bf16(model, monkeypatch, amx) -> None:
    """bf16 (a GPU's precision, and CPUs with AMX): the fused kernels round once where the
    separate ops round twice, so the two agree to bf16's precision, not to the bit; with the
    fused attention (a CPU with AMX) and with the banded one (without), whichever CPU runs it."""
    monkeypatch.setattr(hiera, "_AMX", amx)
    _compare(copy.deepcopy(model).to(torch.bfloat16), PIXELS.bfloat16(), rtol=0.02, atol=0.02)


def test_the_encoder_without_onednn_equals_transformers_forward(model, monkeypatch) -> None:
    """Where oneDNN is absent (or on a GPU) each layer runs as separate PyTorch ops."""
    monkeypatch.setattr(hiera, "_ONEDNN", False)
    _compare(model, PIXELS, rtol=1e-5, atol=1e-5)


def test_levels_with_a_top_down_sum_are_not_made_per_token() -> None:
    """SAM2's two finest levels take no top-down sum, so they are made band by band; where a
    config sums the finest level, it and the level that gives the sum are made as transformers
    makes them."""
    _compare(_model(top_down_levels=[0, 2, 3]), PIXELS, rtol=1e-5, atol=1e-5)


def test_the_positional_embedding_is_kept_per_size_and_precision(model) -> None:
    encoder = ImageEncoder(model)
    with torch.inference_mode():
        encoder(PIXELS)
        encoder(PIXELS)
    assert len(encoder._positions) == 1


@pytest.mark.parametrize("dtype", [torch.float32, torch.bfloat16])
def test_every_block_reads_a_contiguous_map(model, monkeypatch, dtype) -> None:
    """The patch embedding writes its map channels-last, so each block's layer norms and linear
    layers read whole channel vectors, not a permuted ``(B, C, H, W)`` view (one frame: a
    larger batch's bands are strided views of the map by construction)."""
    seen: list[bool] = []
    original = hiera._block

    def spy(module, hidden):
        seen.append(hidden.is_contiguous())
        return original(module, hidden)

    monkeypatch.setattr(hiera, "_block", spy)
    with torch.inference_mode():
        ImageEncoder(copy.deepcopy(model).to(dtype))(PIXELS.to(dtype))
    assert len(seen) >= len(model.vision_encoder.backbone.blocks) and all(seen)


@pytest.mark.parametrize("pooled", [False, True])
def test_bf16_attention_on_the_cpu_is_transformers_eager_attention(pooled: bool) -> None:
    """On a CPU without AMX, bf16 attention runs as matmuls and a bf16 softmax, a band of query
    rows at a time: it lies as close to fp32's kernel as transformers' own eager SAM2 attention
    in bf16 does (scores in bf16, softmax accumulated in fp32), on average and at worst, with
    several heads and bands (the last one short), the strided layout ``_attention`` passes, a
    scale bf16 cannot hold exactly, and (``pooled``) fewer queries than keys. Each query is
    1.6 × its own key (a permutation): peaked enough that a wrong mix of rows or a lost scale
    shows, not so peaked that the scale would not matter."""
    from transformers.models.sam2.modeling_sam2 import eager_attention_forward

    generator = torch.Generator().manual_seed(3)
    batch, heads, tokens, dim = 2, 3, 3 * hiera.ATTENTION_ROWS + 17, 24
    qkv = torch.randn(batch, tokens, 3, heads, dim, generator=generator).bfloat16()
    _, key, value = qkv.permute(2, 0, 3, 1, 4)  # (B, heads, tokens, d) views, as _attention has
    order = torch.randperm(tokens, generator=generator)
    query = 1.6 * key[:, :, order[: tokens // 4] if pooled else order]  # ~80 % on its own key
    scale = dim**-0.5
    with torch.inference_mode():
        ours = hiera._banded_attention(query, key, value, scale)
        eager, _ = eager_attention_forward(torch.nn.Module().eval(), query, key, value, None, scale)
        exact = [x.float() for x in (query, key, value)]
        fp32 = F.scaled_dot_product_attention(*exact, scale=scale)
        uniform = value.float().mean(dim=2, keepdim=True).expand_as(fp32)
    assert ours.dtype == torch.bfloat16 and ours.shape == fp32.shape
    ours_off = (ours.float() - fp32).abs()
    eager_off = (eager.transpose(1, 2).float() - fp32).abs()
    assert ours_off.mean() <= 1.05 * eager_off.mean() and ours_off.max() <= 1.05 * eager_off.max()
    torch.testing.assert_close(ours.float(), fp32, rtol=0.05, atol=0.05)
    assert (fp32 - uniform).abs().mean() > 0.3  # the case is not one a wrong mix would pass


@pytest.mark.parametrize("amx", [False, True])
def test_bf16_attention_takes_the_fused_kernel_where_the_cpu_has_amx(monkeypatch, amx) -> None:
    """PyTorch's fused attention multiplies bf16 on AMX tiles and at fp32's speed without them:
    with AMX the encoder's bf16 attention is that kernel, without it the banded matmuls; fp32
    always takes the kernel. (The flag is the CPU's own, read from PyTorch.)"""
    assert torch.cpu._is_amx_tile_supported() == hiera._AMX
    monkeypatch.setattr(hiera, "_AMX", amx)
    generator = torch.Generator().manual_seed(4)
    query, key, value = torch.randn(3, 1, 2, 2 * hiera.ATTENTION_ROWS, 24, generator=generator)
    scale = 24**-0.5
    with torch.inference_mode():
        for dtype in (torch.bfloat16, torch.float32):
            q, k, v = (x.to(dtype) for x in (query, key, value))
            fused = F.scaled_dot_product_attention(q, k, v, scale=scale)
            banded = hiera._banded_attention(q, k, v, scale)
            ours = hiera._scaled_attention(q, k, v, scale)
            expected = banded if dtype == torch.bfloat16 and not amx else fused
            other = fused if expected is banded else banded
            assert torch.equal(ours, expected), dtype
            if dtype == torch.bfloat16:
                assert not torch.equal(ours, other)  # the two differ: the test can tell them apart


def test_transformers_forward_serves_where_ours_was_not_measured_faster(model, monkeypatch):
    """The predictor encodes with ``ImageEncoder`` only on device types an interleaved bench
    measured it faster on; elsewhere with transformers' own forward, the same numbers."""
    from weldpool_core.teacher.sam2 import Sam2Predictor

    assert isinstance(hiera.image_encoder(model, torch.device("cpu")), ImageEncoder)
    reference = hiera.image_encoder(model, torch.device("cuda"))
    assert reference == model.get_image_embeddings
    image = (torch.rand(96, 128, 3, generator=torch.Generator().manual_seed(2)) * 255).byte()
    ours = Sam2Predictor(model).set_image(image.numpy())
    calls: list[int] = []
    forward = model.get_image_embeddings
    monkeypatch.setattr(model, "get_image_embeddings", lambda p: calls.append(1) or forward(p))
    monkeypatch.setattr(hiera, "MEASURED_FASTER", frozenset())
    theirs = Sam2Predictor(model).set_image(image.numpy())
    assert calls == [1]
    for mine, reference in zip(ours.features, theirs.features, strict=True):
        torch.testing.assert_close(mine, reference, rtol=1e-5, atol=1e-5 * float(mine.abs().max()))
