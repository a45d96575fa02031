"""Where SAM2's image encoder spends its time on the CPU, block by block, against the FLOP floor.

Run: ``.venv/bin/python bench/sam2_encoder.py [--runs 5] [--threads 2] [--dtype float32|bfloat16]``
(a minute or two; run it alone).

The full-size sam2.1-hiera-tiny architecture with random weights encodes one 1024² input, as a
click's first embedding and the teacher do: transformers' ``Sam2Model.get_image_embeddings``
(the naive way) and ours, ``hiera.ImageEncoder`` (what ``Sam2Predictor.set_image`` runs),
alternately. The floor is the encoder's FLOPs (``torch.utils.flop_counter``: matmuls,
convolutions, and attention: ``floor.flop_counter``) at this machine's matmul rate in the same
precision (a 2048³ product, same threads), read before each run (median of the readings). In
transformers' forward each Hiera block, the patch embedding and the neck are timed with forward
hooks; ours is timed block by block around the same blocks (median of the runs); a ratio is the
part's time over its own floor. Elementwise work (layer norms, GELU, window partition copies,
softmax) counts no FLOPs, so it shows as the ratio above 1 of the blocks that do it.
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections import defaultdict
from typing import Any

import torch
from floor import flop_counter, matmul_rate
from results import recorded


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--dtype", choices=["float32", "bfloat16"], default="float32")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    from transformers import Sam2Config, Sam2Model

    from weldpool_core.teacher import hiera

    torch.manual_seed(0)
    dtype = getattr(torch, args.dtype)
    config = Sam2Config()
    config._attn_implementation = "sdpa"  # as the loader loads it
    model = Sam2Model(config).eval().to(dtype)
    encoder = hiera.ImageEncoder(model)
    pixels = torch.randn(1, 3, 1024, 1024, dtype=dtype)
    backbone = model.vision_encoder.backbone
    parts: dict[str, Any] = {"patch embedding": backbone.patch_embed}
    for index, block in enumerate(backbone.blocks):
        kind = "window" if block.window_size > 0 else "global"
        stride = " + q-pool" if block.attn.query_stride else ""
        parts[f"block {index:2d} ({kind} {block.window_size}, dim {block.dim_out}{stride})"] = block
    parts["neck (FPN)"] = model.vision_encoder.neck

    with torch.inference_mode(), flop_counter() as counter:
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
    ours: dict[str, list[float]] = defaultdict(list)  # per run: a banded block's bands summed
    this_run: dict[str, float] = defaultdict(float)
    block_of = {id(block): name for name, block in parts.items()}
    plain_block = hiera._block

    def timed_block(block: Any, hidden: torch.Tensor) -> torch.Tensor:
        start = time.perf_counter()
        out = plain_block(block, hidden)
        this_run[block_of[id(block)]] += time.perf_counter() - start
        return out

    whole: dict[str, list[float]] = defaultdict(list)
    chosen, bands = hiera.BAND_TOKENS, 8192

    def in_bands(pixels: torch.Tensor) -> Any:  # ours with the first blocks in smaller bands
        hiera.BAND_TOKENS = bands
        try:
            return encoder(pixels)
        finally:
            hiera.BAND_TOKENS = chosen

    paths = {"transformers": model.get_image_embeddings, "ours": encoder, "bands": in_bands}
    rates: list[float] = []  # read before each run's pair: the floor sees the runs' states
    with torch.inference_mode():
        for run in range(args.runs + 1):  # the first of each is a warm-up
            rates.append(matmul_rate(dtype))
            for path, encode in paths.items():
                hiera._block = timed_block if path == "ours" else plain_block
                this_run.clear()
                start = time.perf_counter()
                encode(pixels)
                whole[path].append(time.perf_counter() - start)
            for name, seconds in this_run.items():
                ours[name].append(seconds)
            if run == 0:
                timings.clear(), ours.clear(), whole.clear(), rates.clear()
    hiera._block = plain_block
    rate = statistics.median(rates)
    root = type(model.vision_encoder).__name__  # the counter names modules from the one called
    names = {module: f"{root}.{key}" for key, module in model.vision_encoder.named_modules()}

    def flops_of(module: Any) -> int:
        return sum(by_module.get(names[module], {}).values())

    print(
        f"SAM2 hiera-tiny image encoder, 1024², {args.dtype}, {args.threads} threads; "
        f"{args.dtype} matmul {rate / 1e9:.0f} GFLOP/s; median of {args.runs}\n"
    )
    print("| part | GFLOP | floor ms | transformers ms | × floor | ours ms | × floor |")
    print("|---|---:|---:|---:|---:|---:|---:|")

    def ratio(ms: float, floor: float) -> str:
        return f"{ms / floor:.2f}×" if floor > 0.05 else "–"

    for name, module in parts.items():
        flops = flops_of(module)
        floor = 1000 * flops / rate
        theirs = 1000 * statistics.median(timings[name])
        mine = f"{1000 * statistics.median(ours[name]):.1f}" if name in ours else "–"
        mine_ratio = ratio(float(mine), floor) if name in ours else "–"
        print(
            f"| {name} | {flops / 1e9:.2f} | {floor:.1f} | {theirs:.1f} | "
            f"{ratio(theirs, floor)} | {mine} | {mine_ratio} |"
        )
    floor = 1000 * total_flops / rate
    theirs, mine = (1000 * statistics.median(whole[path]) for path in ("transformers", "ours"))
    print(
        f"| **whole encoder** | {total_flops / 1e9:.2f} | {floor:.1f} | {theirs:.1f} | "
        f"**{ratio(theirs, floor)}** | {mine:.1f} | **{ratio(mine, floor)}** |"
    )
    print(f"\nours ÷ transformers: {mine / theirs:.2f}× the time (the same outputs: a test)")
    print(
        "\n| whole encoder, interleaved | median ms | ÷ transformers |\n|---|---:|---:|\n"
        + "\n".join(
            f"| {label} | {1000 * statistics.median(whole[path]):.1f} | "
            f"{statistics.median(whole[path]) / statistics.median(whole['transformers']):.2f}× |"
            for path, label in (
                ("transformers", "transformers' forward"),
                ("ours", f"ours, first blocks in bands of ≤ {chosen} tokens"),
                ("bands", f"ours, first blocks in bands of {bands} tokens"),
            )
        )
    )


if __name__ == "__main__":
    with recorded(__file__):
        main()
