"""Where SAM2's image encoder spends its time on the CPU, block by block, against the FLOP floor.

Run: ``.venv/bin/python bench/sam2_encoder.py [--runs 3] [--threads 2] [--dtype float32|bfloat16]``
(a minute or two; run it alone).

The full-size sam2.1-hiera-tiny architecture with random weights encodes one 1024² input
(``Sam2Model.get_image_embeddings``, what a click's first embedding and the teacher run). The
floor is the encoder's FLOPs (``torch.utils.flop_counter``: matmuls, convolutions, and attention,
whose CPU kernel the counter is taught here)
at this machine's measured fp32 matmul rate (a 2048³ product, same threads). Each Hiera block,
the patch embedding and the neck are timed with forward hooks (median of the runs); a ratio is
the module's time over its own floor. Elementwise work (layer norms, GELU, window partition
copies, softmax) counts no FLOPs here, so it shows as the ratio above 1 of the blocks that do it.
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections import defaultdict
from typing import Any

import torch
from torch.utils.flop_counter import FlopCounterMode, sdpa_flop_count


def _cpu_attention_flops(query: Any, key: Any, value: Any, *args: Any, **kwargs: Any) -> int:
    """The CPU attention kernel's FLOPs (QKᵀ and the weighted sum), which the counter's own
    table (its GPU kernels) lacks."""
    shapes = [getattr(x, "shape", x) for x in (query, key, value)]  # the counter passes shapes
    return int(sdpa_flop_count(*shapes))


CUSTOM = {torch.ops.aten._scaled_dot_product_flash_attention_for_cpu: _cpu_attention_flops}


def matmul_rate(runs: int) -> float:
    """GFLOP/s of a 2048³ fp32 product on this machine (median of ``runs`` × 3)."""
    a, b = torch.randn(2048, 2048), torch.randn(2048, 2048)
    a @ b
    times = []
    for _ in range(3 * runs):
        start = time.perf_counter()
        a @ b
        times.append(time.perf_counter() - start)
    return 2 * 2048**3 / statistics.median(times) / 1e9


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--dtype", choices=["float32", "bfloat16"], default="float32")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    from transformers import Sam2Config, Sam2Model

    torch.manual_seed(0)
    dtype = getattr(torch, args.dtype)
    model = Sam2Model(Sam2Config()).eval().to(dtype)
    pixels = torch.randn(1, 3, 1024, 1024, dtype=dtype)
    backbone = model.vision_encoder.backbone
    parts: dict[str, Any] = {"patch embedding": backbone.patch_embed}
    for index, block in enumerate(backbone.blocks):
        kind = "window" if block.window_size > 0 else "global"
        stride = " + q-pool" if block.attn.query_stride else ""
        parts[f"block {index:2d} ({kind} {block.window_size}, dim {block.dim_out}{stride})"] = block
    parts["neck (FPN)"] = model.vision_encoder.neck

    with torch.inference_mode(), FlopCounterMode(display=False, custom_mapping=CUSTOM) as counter:
        model.get_image_embeddings(pixels)
    by_module = counter.get_flop_counts()
    total_flops = counter.get_total_flops()

    timings: dict[str, list[float]] = defaultdict(list)
    started: dict[str, float] = {}
    for name, module in parts.items():
        module.register_forward_pre_hook(
            lambda *_, n=name: started.__setitem__(n, time.perf_counter())
        )
        module.register_forward_hook(
            lambda *_, n=name: timings[n].append(time.perf_counter() - started[n])
        )
    whole = []
    with torch.inference_mode():
        model.get_image_embeddings(pixels)  # warm-up
        timings.clear()
        for _ in range(args.runs):
            start = time.perf_counter()
            model.get_image_embeddings(pixels)
            whole.append(time.perf_counter() - start)
    rate = matmul_rate(args.runs) * 1e9  # measured right after, in the same state
    root = type(model.vision_encoder).__name__  # the counter names modules from the one called
    names = {module: f"{root}.{key}" for key, module in model.vision_encoder.named_modules()}

    def flops_of(module: Any) -> int:
        return sum(by_module.get(names[module], {}).values())

    print(
        f"SAM2 hiera-tiny image encoder, 1024², {args.dtype}, {args.threads} threads; "
        f"fp32 matmul {rate / 1e9:.0f} GFLOP/s; median of {args.runs}\n"
    )
    print("| part | GFLOP | ms | floor ms | × floor |")
    print("|---|---:|---:|---:|---:|")
    counted = 0.0
    for name, module in parts.items():
        flops = flops_of(module)
        ms = 1000 * statistics.median(timings[name])
        counted += ms
        floor = 1000 * flops / rate
        ratio = f"{ms / floor:.2f}×" if floor > 0.05 else "–"
        print(f"| {name} | {flops / 1e9:.2f} | {ms:.1f} | {floor:.1f} | {ratio} |")
    ms = 1000 * statistics.median(whole)
    floor = 1000 * total_flops / rate
    print(
        f"| **whole encoder** | {total_flops / 1e9:.2f} | {ms:.1f} | {floor:.1f} | "
        f"{ms / floor:.2f}× |"
    )
    print(f"\noutside the parts above (pre-/post-processing of the call): {ms - counted:.1f} ms")


if __name__ == "__main__":
    main()
