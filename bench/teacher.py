"""Teacher timings on full-size architectures (random weights): median of several runs, with
each case's peak memory measured in a process of its own.

Cases: DINO ViT-S/8 at 224² and 480² (last-block-only attention, and the straightforward path
that returns every attention, for the ratio), SAM2 hiera-tiny image encoder at 1024², one click
decoded from a cached embedding (ours and transformers' Sam2Model.forward), and the whole teacher
on a 1280×800 frame. Each case's FLOP floor (``bench/floor.py``): its FLOPs (matmuls,
convolutions, attention) at the fp32 matmul rate read before each of its runs; the rest of a
case (resizing, prompts, Algorithm 1, elementwise work) counts none and shows as the ratio above 1.

    .venv/bin/python bench/teacher.py [--runs 5] [--device cpu|cuda] [--threads 2]
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import resource
import shlex
import statistics
import sys
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import torch
from floor import flop_counter, timed_against_floor
from results import Table, record

FRAME_SHAPE = (800, 1280, 3)


def _rss_mb() -> float:
    with open("/proc/self/statm") as handle:
        return int(handle.read().split()[1]) * resource.getpagesize() / 2**20


def _timed(fn: Callable[[], Any], runs: int, device: str) -> list[float]:
    fn()  # warm-up
    times = []
    for _ in range(runs):
        if device.startswith("cuda"):
            torch.cuda.synchronize()
        start = time.perf_counter()
        fn()
        if device.startswith("cuda"):
            torch.cuda.synchronize()
        times.append(time.perf_counter() - start)
    return times


def _case(name: str, runs: int, device: str, threads: int, queue: Any) -> None:
    """Build what case ``name`` needs, then time it; runs in its own process."""
    torch.set_num_threads(threads)
    torch.manual_seed(0)
    from transformers import Sam2Config

    from weldpool_core.teacher.dino import DinoAttention, dino_vits8_config
    from weldpool_core.teacher.sam2 import Prompts, Sam2Predictor
    from weldpool_core.teacher.teacher import Teacher

    dev = torch.device(device)
    frame = np.random.default_rng(0).integers(0, 256, FRAME_SHAPE, dtype=np.uint8)
    click = Prompts(((640.0, 400.0),), (1,))
    if name.startswith("dino"):
        size = int(name.split()[1].split("²")[0])
        dino = DinoAttention.from_config(dino_vits8_config(), size, dev)
        if "all attentions" in name:
            pixels = dino.preprocess(frame)
            dino.model.config._attn_implementation = "eager"

            def fn() -> Any:
                with torch.inference_mode():
                    return dino.model(
                        pixel_values=pixels, interpolate_pos_encoding=True, output_attentions=True
                    )
        else:

            def fn() -> Any:
                return dino(frame)
    else:
        sam2 = Sam2Predictor.from_config(Sam2Config(), dev)
        if name == "sam2 encode 1024²":

            def fn() -> Any:
                return sam2.set_image(frame)
        elif name.startswith("sam2 click"):
            embedding = sam2.set_image(frame)
            if "Sam2Model" in name:
                scale = torch.tensor([1024 / FRAME_SHAPE[1], 1024 / FRAME_SHAPE[0]])
                points = (torch.tensor(click.points) * scale)[None, None].to(dev)
                labels = torch.tensor(click.labels)[None, None].to(dev)

                def fn() -> Any:
                    with torch.inference_mode():
                        out = sam2.model(
                            image_embeddings=list(embedding.features),
                            input_points=points,
                            input_labels=labels,
                        )
                        masks = torch.nn.functional.interpolate(
                            out.pred_masks[0], size=FRAME_SHAPE[:2], mode="bilinear"
                        )
                        return (masks > 0).cpu()
            else:

                def fn() -> Any:
                    return sam2.predict(embedding, click).mask
        else:  # the whole teacher
            teacher = Teacher(DinoAttention.from_config(dino_vits8_config(), 480, dev), sam2, "x")

            def fn() -> Any:
                return teacher.run(frame)

    before = _rss_mb()
    if device == "cpu":  # the rate read before each run: the floor sees the runs' states
        times, rate = timed_against_floor(fn, runs)
    else:
        times, rate = _timed(fn, runs, device), float("nan")
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    flops = _flops(fn)
    queue.put((name, statistics.median(times), min(times), peak - before, peak, flops, rate))


def _flops(fn: Callable[[], Any]) -> int:
    """FLOPs of one call of ``fn`` (matmuls, convolutions, attention): counted with the SAM2
    encoder's linear layers on ``F.linear`` (the counter does not see oneDNN's fused calls;
    they multiply the same matrices)."""
    from weldpool_core.teacher import hiera

    fused = hiera._fused
    hiera._fused = lambda hidden: False
    try:
        with flop_counter() as counter:
            fn()
    finally:
        hiera._fused = fused
    return int(counter.get_total_flops())


CASES = [
    "dino 224² (last block only)",
    "dino 480² (last block only)",
    "dino 480² (all attentions)",
    "sam2 encode 1024²",
    "sam2 click (ours, cached inputs)",
    "sam2 click (Sam2Model.forward)",
    "teacher per 1280×800 frame",
]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--only", help="run the cases whose name contains this text")
    args = parser.parse_args()
    context = mp.get_context("spawn")
    results = []
    for name in CASES:
        if args.only and args.only not in name:
            continue
        queue = context.Queue()
        runs = (
            max(3, args.runs // 2) if "teacher" in name or "all attentions" in name else args.runs
        )
        process = context.Process(target=_case, args=(name, runs, args.device, args.threads, queue))
        process.start()
        results.append(queue.get())
        process.join()
    print(
        f"\nteacher on {args.device}, {args.threads} threads, random weights, median of "
        f"{args.runs} runs (3 for the slow cases)"
    )
    print(
        f"{'case':<34} {'median':>10} {'best':>10} {'GFLOP':>7} {'floor':>10} {'× floor':>8} "
        f"{'peak extra MB':>14} {'peak RSS MB':>12}"
    )
    columns = ["case", "median", "best", "GFLOP", "floor", "× floor", "peak extra MB"]
    table = Table("case", [*columns, "peak RSS MB"], [])
    for name, median, best, extra, peak, flops, rate in results:
        unit, scale = ("ms", 1000) if median < 1 else ("s", 1)
        floor = flops / rate  # nan off the CPU: no rate read there
        print(
            f"{name:<34} {median * scale:>8.1f}{unit:>2} {best * scale:>8.1f}{unit:>2} "
            f"{flops / 1e9:>7.1f} {floor * scale:>8.2f}{unit:>2} {median / floor:>7.2f}× "
            f"{extra:>14.0f} {peak:>12.0f}"
        )
        table.rows.append(
            [
                *(name, f"{median * scale:.1f} {unit}", f"{best * scale:.1f} {unit}"),
                *(f"{flops / 1e9:.1f}", f"{floor * scale:.2f} {unit}", f"{median / floor:.2f}×"),
                *(f"{extra:.0f}", f"{peak:.0f}"),
            ]
        )
    command = shlex.join([".venv/bin/python", "bench/teacher.py", *sys.argv[1:]])
    print(f"written to {record('bench/teacher.py', [table], command)}")
    rates = [r[-1] for r in results]
    if args.device == "cpu":
        print(
            f"floor: the case's FLOPs at the fp32 matmul rate read before each run "
            f"({min(rates) / 1e9:.0f}–{max(rates) / 1e9:.0f} GFLOP/s, the cases' medians)"
        )
    by_name = {r[0]: r[1] for r in results}
    pairs = [
        ("dino 480² (all attentions)", "dino 480² (last block only)"),
        ("sam2 click (Sam2Model.forward)", "sam2 click (ours, cached inputs)"),
    ]
    for slow, fast in pairs:
        if slow in by_name and fast in by_name:
            print(f"speed-up of '{fast}' over '{slow}': {by_name[slow] / by_name[fast]:.2f}×")


if __name__ == "__main__":
    main()
