"""SAM2's image encoder for inference: ``Sam2Model.get_image_embeddings``'s numbers, less traffic.

transformers' forward (the Hiera backbone, the FPN neck and the decoder's two projections) spends
as much time moving memory as multiplying on the CPU (``bench/sam2_encoder.py``): every
attention also computes a per-token head-by-head softmax it never uses, the neck computes a sine
positional encoding for every level that ``get_image_embeddings`` drops, the windowed
positional embedding is re-interpolated from the weights on every frame, and each window
partition, unpartition and attention output is copied twice, every linear layer writes its
output twice (the bias first), and the neck's 1×1 convolutions read channels-last views as
strided images. ``ImageEncoder`` re-states the same computation with the same weights (a test
holds it equal to transformers' forward in fp32 and bf16): the dropped work is skipped, the
positional embedding is kept per input size, the window unpartition is fused into the residual
sum, the patch embedding writes its map channels-last (not a permuted view strided by channel),
the 1×1 convolutions and poolings run on the ``(B, H, W, C)`` maps as they are, and on the CPU
each linear layer is one oneDNN call with its bias, GELU or residual sum fused in (the kernels
PyTorch's own compiler emits for these layers; they round as the separate ops do in fp32), and
the window-local first blocks (with the two finest FPN levels) can run a band of rows at a time
(``BAND_TOKENS``: by measurement, one band, the whole map);
in bf16 on a CPU without AMX, where PyTorch's fused attention kernel runs at fp32's speed,
attention is two bf16 matmuls and a softmax a band of query rows at a time.
The weights are read as they are at each call; only the positional embedding, a function of the
weights alone, is kept (per input size): a model is not trained while it encodes.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from typing import Any, cast

import torch
import torch.nn.functional as F

_ONEDNN: bool = torch.backends.mkldnn.is_available()  # type: ignore[no-untyped-call]


def _fused(hidden: torch.Tensor) -> bool:
    """Whether oneDNN's fused linear serves this tensor: on the CPU, in fp32, or in bf16 where
    the processor has bf16 instructions."""
    if not _ONEDNN or hidden.device.type != "cpu":
        return False
    if hidden.dtype == torch.float32:
        return True
    return hidden.dtype == torch.bfloat16 and bool(torch.ops.mkldnn._is_mkldnn_bf16_supported())


MEASURED_FASTER: frozenset[str] = frozenset({"cpu"})
"""The device types where ``bench/sam2_encoder.py``, run interleaved beside transformers' forward,
measured ``ImageEncoder`` faster (2 cores: 0.54× its time in fp32, 0.41× in bf16, 0.69× in bf16
with oneDNN held to instructions without bf16). Elsewhere (a GPU, until ``bench/gpu.py``'s
encoder step measures it there) transformers' own forward runs."""


def image_encoder(model: Any, device: torch.device) -> Callable[[torch.Tensor], list[torch.Tensor]]:
    """What encodes pixels into the three feature maps on ``device``: ``ImageEncoder`` where an
    interleaved bench measured it faster, transformers' ``get_image_embeddings`` elsewhere."""
    if device.type in MEASURED_FASTER:
        return ImageEncoder(model)
    return cast(Callable[[torch.Tensor], list[torch.Tensor]], model.get_image_embeddings)


class ImageEncoder:
    """``model.get_image_embeddings(pixels)`` for a ``Sam2Model`` in eval mode, in inference."""

    def __init__(self, model: Any) -> None:
        self.model = model
        self._positions: dict[tuple[int, int, torch.dtype, torch.device], torch.Tensor] = {}

    @torch.inference_mode()
    def __call__(self, pixels: torch.Tensor) -> list[torch.Tensor]:
        """Pixels ``(B, 3, 1024, 1024)`` → the three feature maps, highest resolution first."""
        vision, decoder = self.model.vision_encoder, self.model.mask_decoder
        projections = {0: decoder.conv_s0, 1: decoder.conv_s1}  # levels, highest resolution first
        # A projected level that neither takes nor gives a top-down sum is a per-token map of its
        # stage (lateral 1×1, then the decoder's 1×1): made as its stage's bands come out.
        finished = {
            level: functools.partial(_lateral_projection, vision.neck, level, projection)
            for level, projection in projections.items()
            if _per_token(vision.neck, level)
        }
        stages = self._backbone(vision.backbone, pixels, finished)
        levels = _neck(vision.neck, stages, set(finished))[-vision.num_feature_levels :][::-1]
        for level, projection in projections.items():
            if level not in finished:
                levels[level] = _conv(projection, levels[level])
        levels[-1] = levels[-1] + self.model.no_memory_embedding.view(1, 1, 1, -1)
        return [level.permute(0, 3, 1, 2) for level in levels]

    def _position(self, backbone: Any, height: int, width: int, like: torch.Tensor) -> torch.Tensor:
        """The backbone's positional embedding at this size, ``(1, H, W, C)`` (weights only)."""
        key = (height, width, like.dtype, like.device)
        if key not in self._positions:
            self._positions[key] = backbone._get_pos_embed((height, width)).contiguous()
        return self._positions[key]

    def _backbone(
        self, backbone: Any, pixels: torch.Tensor, finished: dict[int, Any]
    ) -> list[torch.Tensor]:
        """The Hiera blocks; the output of each stage's last block, ``(B, H, W, C)``, or for a
        stage in ``finished`` that function of it."""
        projection = backbone.patch_embed.projection
        # Channels-last: the map is (B, H, W, C) in memory, not a permuted (B, C, H, W) view.
        pixels = pixels.to(projection.weight.dtype, memory_format=torch.channels_last)
        hidden = projection(pixels).permute(0, 2, 3, 1)
        hidden = hidden + self._position(backbone, hidden.shape[1], hidden.shape[2], hidden)
        blocks = list(backbone.blocks)
        stage_of = {index: stage for stage, index in enumerate(backbone.stage_ends)}

        def output(index: int, hidden: torch.Tensor) -> torch.Tensor:
            stage = stage_of[index]
            return finished[stage](hidden) if stage in finished else hidden

        local, rows = _local_blocks(blocks, hidden.shape[1], hidden.shape[2])
        ended: dict[int, list[torch.Tensor]] = {i: [] for i in range(local) if i in stage_of}
        if local:
            # The first blocks see only their own windows: run them a band of rows at a time.
            # A band's tensors stay small enough for the allocator to reuse (a whole 256² map's
            # are not: each would be mapped and page-faulted anew on every frame) and in cache.
            last: list[torch.Tensor] = []  # the last of them: what the next block reads
            for top in range(0, hidden.shape[1], rows):
                band = hidden[:, top : top + rows]
                for index in range(local):
                    band = _block(blocks[index], band)
                    if index in ended:
                        ended[index].append(output(index, band))
                last.append(band)
            hidden = torch.cat(last, dim=1)
        stages = [torch.cat(parts, dim=1) for parts in ended.values()]
        for index in range(local, len(blocks)):
            hidden = _block(blocks[index], hidden)
            if index in stage_of:
                stages.append(output(index, hidden))
        return stages


BAND_TOKENS = 1 << 16
"""At most how many tokens of the first map one band of the window-local blocks holds: SAM2's
whole 256² map, one band. ``bench/sam2_encoder.py``, interleaved on a loaded 2-core machine,
measured bands of 8,192 tokens at 0.69× transformers' time in bf16 against 0.32× whole, and 0.76×
against 0.73× in fp32 (on a quiet machine, earlier, 8,192 had beaten 4,096 and 16,384)."""


def _local_blocks(blocks: list[Any], height: int, width: int) -> tuple[int, int]:
    """How many leading blocks attend within windows that tile the map without padding, and
    the band height (rows of the first map) whose windows all those blocks share."""
    scale, rows, count = 1, 1, 0
    for block in blocks:
        window = block.window_size
        h, w = height // scale, width // scale
        if window <= 0 or h % window or w % window:
            break
        stride = block.query_stride[0] if block.query_stride else 1
        if block.query_stride and (len(set(block.query_stride)) > 1 or window % stride):
            break
        rows = math.lcm(rows, window * scale)
        scale *= stride
        count += 1
    if count == 0 or height % rows:
        return 0, height
    while rows * 2 * width <= BAND_TOKENS and height % (rows * 2) == 0:
        rows *= 2
    return count, rows


def _per_token(neck: Any, level: int) -> bool:
    """Whether the FPN level is its stage's lateral 1×1 alone: it takes no top-down sum from
    the level below it and gives none to the level above."""
    last = len(neck.convs) - 1
    takes = level in neck.fpn_top_down_levels and level != last
    gives = level > 0 and level - 1 in neck.fpn_top_down_levels
    return not takes and not gives


def _lateral_projection(
    neck: Any, level: int, projection: Any, stage: torch.Tensor
) -> torch.Tensor:
    """A per-token FPN level of a stage's output (or of a band of it), then ``projection``."""
    lateral = neck.convs[len(neck.convs) - 1 - level]
    return _conv(projection, _conv(lateral, stage))


def _neck(neck: Any, stages: list[torch.Tensor], finished: set[int]) -> list[torch.Tensor]:
    """The FPN's feature maps ``(B, H, W, C)``, lowest resolution first, without the sine
    positional encodings that ``get_image_embeddings`` does not return; the levels in
    ``finished`` come made in ``stages``."""
    last = len(neck.convs) - 1
    levels: list[torch.Tensor] = []
    previous = stages[last]
    for i in range(last, -1, -1):
        if i in finished:
            levels.append(stages[i])
            continue
        lateral = _conv(neck.convs[last - i], stages[i])
        if i not in neck.fpn_top_down_levels or i == last:
            previous = lateral
        else:  # nearest 2× upsampling: each value repeated over a 2×2 block
            batch, height, width, channels = previous.shape
            tiles = previous[:, :, None, :, None].expand(batch, height, 2, width, 2, channels)
            previous = lateral + tiles.reshape(lateral.shape)
        levels.append(previous)
    return levels


def _conv(conv: Any, hidden: torch.Tensor) -> torch.Tensor:
    """A ``Conv2d`` on a ``(B, H, W, C)`` map; a 1×1 one (all of SAM2's here) is a linear layer."""
    if conv.kernel_size == (1, 1) and conv.stride == (1, 1) and conv.padding in ((0, 0), "valid"):
        return _linear(hidden, conv.weight.flatten(1), conv.bias)
    out: torch.Tensor = conv(hidden.permute(0, 3, 1, 2))
    return out.permute(0, 2, 3, 1)


def _linear(
    hidden: torch.Tensor,
    weight: torch.Tensor,
    bias: torch.Tensor | None,
    gelu: bool = False,
    residual: torch.Tensor | None = None,
) -> torch.Tensor:
    """``residual + gelu(hidden @ weightᵀ + bias)`` (each part optional) over the last axis; on
    the CPU one oneDNN matmul with the bias and the GELU or the sum in its epilogue."""
    if bias is not None and _fused(hidden):
        flat = hidden.reshape(-1, hidden.shape[-1])
        out: torch.Tensor
        if residual is not None and not gelu:
            other = residual.reshape(-1, weight.shape[0])
            out = torch.ops.mkldnn._linear_pointwise.binary(flat, other, weight, bias, "add")
        else:
            attr = "gelu" if gelu else "none"
            out = torch.ops.mkldnn._linear_pointwise(flat, weight, bias, attr, [], "none")
            if residual is not None:
                out = residual.reshape(out.shape) + out
        return out.view(*hidden.shape[:-1], weight.shape[0])
    plain = F.linear(hidden, weight, bias)
    plain = F.gelu(plain) if gelu else plain
    return plain if residual is None else residual + plain


def _block(block: Any, hidden: torch.Tensor) -> torch.Tensor:
    """One ``Sam2MultiScaleBlock``: windowed (or global) attention with optional query pooling,
    then the MLP, each with its residual."""
    norm1, norm2 = block.layer_norm1, block.layer_norm2
    normed = F.layer_norm(hidden, norm1.normalized_shape, norm1.weight, norm1.bias, norm1.eps)
    stride = block.query_stride
    residual = hidden
    if block.dim != block.dim_out:
        residual = _pool(_linear(normed, block.proj.weight, block.proj.bias), stride)
    window = block.window_size
    if window > 0:
        attended = _attention(block.attn, _partition(normed, window))
        hidden = _add_unpartitioned(residual, attended, window // (stride[0] if stride else 1))
    else:
        hidden = _attention(block.attn, normed, residual)
    normed = F.layer_norm(hidden, norm2.normalized_shape, norm2.weight, norm2.bias, norm2.eps)
    mlp = block.mlp
    gelu = _is_exact_gelu(mlp.activation)
    inner = _linear(normed, mlp.proj_in.weight, mlp.proj_in.bias, gelu=gelu)
    inner = inner if gelu else mlp.activation(inner)
    for layer in mlp.layers:
        inner = _linear(inner, layer.weight, layer.bias, gelu=gelu)
        inner = inner if gelu else mlp.activation(inner)
    return _linear(inner, mlp.proj_out.weight, mlp.proj_out.bias, residual=hidden)


def _is_exact_gelu(activation: Any) -> bool:
    """Whether ``activation`` is the erf GELU (transformers' ``GELUActivation``, SAM2's)."""
    return type(activation).__name__ == "GELUActivation" and not getattr(
        activation, "use_gelu_python", False
    )


def _pool(hidden: torch.Tensor, stride: Any) -> torch.Tensor:
    """Max pooling of a ``(B, H, W, C)`` map by ``stride`` (transformers' ``do_pool``), read in
    place: the elementwise maximum of the ``stride`` offsets' strided views (each reads whole
    channel vectors; a reduction over the strided axes runs 10× slower here)."""
    if not stride:
        return hidden
    (sh, sw), rows, cols = stride, hidden.shape[1] // stride[0], hidden.shape[2] // stride[1]
    cropped = hidden[:, : rows * sh, : cols * sw]
    offsets = [cropped[:, i::sh, j::sw] for i in range(sh) for j in range(sw)]
    return functools.reduce(torch.maximum, offsets)


def _attention(
    attn: Any, tokens: torch.Tensor, residual: torch.Tensor | None = None
) -> torch.Tensor:
    """``Sam2MultiScaleAttention`` on ``(B, h, w, C)`` windows, without the unused weights
    (plus ``residual``, when given, summed in the output projection)."""
    batch, height, width, _ = tokens.shape
    heads = attn.num_attention_heads
    qkv = _linear(tokens, attn.qkv.weight, attn.qkv.bias).view(batch, height, width, 3, -1)
    query = qkv[..., 0, :]
    if attn.query_stride:  # pooled over (h, w) with channels in transformers' (heads, d) order
        query = _pool(query, attn.query_stride)
    height, width = query.shape[1:3]
    query = query.reshape(batch, height * width, heads, -1).transpose(1, 2)
    key, value = qkv.view(batch, -1, 3, heads, qkv.shape[-1] // heads)[:, :, 1:].permute(
        2, 0, 3, 1, 4
    )
    out = _scaled_attention(query, key, value, attn.scale)
    out = out.transpose(1, 2).reshape(batch, height, width, -1)
    return _linear(out, attn.proj.weight, attn.proj.bias, residual=residual)


ATTENTION_ROWS = 128
"""Query rows a bf16 attention on a CPU without AMX takes at a time (its scores: rows × keys ×
heads; measured on 4,096 keys: 64 and 128 rows ran at 1.6× the floor, 256 and 512 at
3.1–3.2×)."""


_AMX: bool = bool(torch.cpu._is_amx_tile_supported())
"""Whether the CPU has AMX tiles, on which PyTorch's fused attention multiplies bf16 with oneDNN's
brgemm (a global block 40–43 ms against the banded matmuls' 70–71 ms, the whole encoder 575 →
414 ms, on an Intel CPU with them); without them that kernel computes bf16 at about fp32's
speed."""


def _scaled_attention(
    query: torch.Tensor, key: torch.Tensor, value: torch.Tensor, scale: float
) -> torch.Tensor:
    """``softmax(query · keyᵀ · scale) · value`` per batch and head, ``(B, heads, N, d)``: the
    fused kernel, except in bf16 on a CPU without AMX (``_banded_attention``)."""
    if query.dtype == torch.bfloat16 and query.device.type == "cpu" and not _AMX:
        return _banded_attention(query, key, value, scale)
    return F.scaled_dot_product_attention(query, key, value, scale=scale)


def _banded_attention(
    query: torch.Tensor, key: torch.Tensor, value: torch.Tensor, scale: float
) -> torch.Tensor:
    """bf16 attention on a CPU without AMX: two bf16 matmuls and a bf16 softmax (which
    accumulates in fp32), a band of ``ATTENTION_ROWS`` query rows at a time. PyTorch's fused
    kernel runs bf16 about as fast as fp32 there (2.5–2.8× the bf16 floor on 4,096 tokens,
    3.8–15× on SAM2's windows, against 1.6× and 2.2–10× this way). It lies as close to fp32 as
    transformers' eager attention in bf16 (the scores rounded to bf16, where the fused kernel
    keeps them in fp32; the query is scaled first, one rounding where eager makes two)."""
    # Laid out once for the matmuls (strided views would be copied for every band).
    query = (query * scale).contiguous()
    keys, value = key.contiguous().transpose(-1, -2), value.contiguous()
    bands = [
        torch.matmul(torch.softmax(torch.matmul(band, keys), dim=-1), value)
        for band in torch.split(query, ATTENTION_ROWS, dim=-2)
    ]
    return bands[0] if len(bands) == 1 else torch.cat(bands, dim=-2)


def _partition(hidden: torch.Tensor, window: int) -> torch.Tensor:
    """``(B, H, W, C)`` → ``(B · windows, window, window, C)``, zero-padded to whole windows."""
    batch, height, width, channels = hidden.shape
    pad_h, pad_w = (-height) % window, (-width) % window
    if pad_h or pad_w:
        hidden = F.pad(hidden, (0, 0, 0, pad_w, 0, pad_h))
    rows, cols = (height + pad_h) // window, (width + pad_w) // window
    grid = hidden.view(batch, rows, window, cols, window, channels).permute(0, 1, 3, 2, 4, 5)
    return grid.reshape(-1, window, window, channels)


def _add_unpartitioned(residual: torch.Tensor, windows: torch.Tensor, window: int) -> torch.Tensor:
    """``residual + unpartition(windows)``: the windows are read in place by the sum where no
    padding is cut off (one pass instead of a copy and a sum)."""
    batch, height, width, channels = residual.shape
    pad_h, pad_w = (-height) % window, (-width) % window
    rows, cols = (height + pad_h) // window, (width + pad_w) // window
    grid = windows.view(batch, rows, cols, window, window, -1).permute(0, 1, 3, 2, 4, 5)
    if pad_h or pad_w:
        full = grid.reshape(batch, height + pad_h, width + pad_w, -1)
        return residual + full[:, :height, :width]
    tiled = residual.reshape(batch, rows, window, cols, window, channels)
    return torch.add(tiled, grid).reshape(batch, height, width, channels)
