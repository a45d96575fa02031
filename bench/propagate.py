"""SAM2 propagation through a weld run on this machine: ms per frame with the teacher's cached
embeddings and without them, against the per-frame teacher and against the FLOP floor, and the
memory the session holds after a short and a long run (it must not grow with the run).

Random weights in SAM2's full video architecture (no download; the cost does not depend on the
weights). Frames: the real WAAM video when ../shared is here (every frame), else synthetic
1280×800 pools.

    PYTHONPATH=. .venv/bin/python bench/propagate.py [--frames 10] [--long 30] [--threads 2]

Prints a table of medians over the frames propagated.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np
import torch
from torch.utils.flop_counter import FlopCounterMode

REPO = Path(__file__).resolve().parents[1]
VIDEO = REPO.parent / "shared" / "data" / "waam" / "video" / "compressed_0mm.mp4"
MATMUL_GFLOPS = 185.0
"""fp32 matmul rate measured here (160–210 GFLOP/s on 2 threads): FLOPs ÷ this is the floor."""


def frames(count: int) -> list[np.ndarray]:
    from weldpool_core.synth import SynthParams, synth_frame
    from weldpool_core.video import iter_video_frames

    if VIDEO.exists():
        out = []
        for frame in iter_video_frames(VIDEO, 1):
            pixels = frame.pixels
            out.append(np.repeat(pixels[:, :, None], 3, 2) if pixels.ndim == 2 else pixels)
            if len(out) == count:
                return out
    params = SynthParams(1280, 800)
    images = [synth_frame(seed=i, params=params).image for i in range(count)]
    return [np.repeat(i[:, :, None], 3, 2) if i.ndim == 2 else i for i in images]


def session_bytes(session) -> int:  # type: ignore[no-untyped-def]
    total = 0
    for per_obj in session.output_dict_per_obj.values():
        for outputs in per_obj.values():
            for item in outputs.values():
                total += sum(
                    v.numel() * v.element_size() for v in item.values() if torch.is_tensor(v)
                )
    return total


def held_after(propagator, prompt, embeddings, length: int) -> float:  # type: ignore[no-untyped-def]
    """MiB of tracked outputs the session holds after propagating ``length`` frames."""
    sessions = []
    make = propagator.session

    def recording(*args):  # type: ignore[no-untyped-def]
        sessions.append(make(*args))
        return sessions[-1]

    propagator.session = recording
    try:
        for _ in propagator.propagate(
            length, {0: prompt}, lambda i: embeddings[i % len(embeddings)], "forward"
        ):
            pass
    finally:
        del propagator.session
    return session_bytes(sessions[0]) / 2**20


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=10)
    parser.add_argument("--long", type=int, default=60, help="frames of the long memory run")
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)

    from transformers import Sam2Config, Sam2Model, Sam2VideoConfig, Sam2VideoModel

    from weldpool_core.synth import SynthParams, synth_frame
    from weldpool_core.teacher.propagate import Sam2Propagator
    from weldpool_core.teacher.sam2 import Sam2Predictor

    torch.manual_seed(0)
    config = Sam2VideoConfig()
    config._attn_implementation = "sdpa"
    video = Sam2VideoModel(config).eval()
    # One checkpoint serves both, as in the product: the image model shares the video model's
    # image parts.
    image_model = Sam2Model(
        Sam2Config(
            vision_config=config.vision_config,
            prompt_encoder_config=config.prompt_encoder_config.to_dict(),
            mask_decoder_config=config.mask_decoder_config.to_dict(),
        )
    )
    image_model.load_state_dict(video.state_dict(), strict=False)
    predictor = Sam2Predictor(image_model)
    propagator = Sam2Propagator(video)

    run = frames(max(args.frames, 2))
    prompt = synth_frame(seed=0, params=SynthParams(run[0].shape[1], run[0].shape[0])).mask

    # Encoder per frame (what a frame costs when the teacher has not seen it).
    encode_ms, embeddings = [], []
    for picture in run:
        start = time.perf_counter()
        embeddings.append(predictor.set_image(picture))
        encode_ms.append(1000 * (time.perf_counter() - start))

    # Propagation from cached embeddings: memory attention, decoder, memory encoder.
    step_ms: list[float] = []
    last = time.perf_counter()
    for _ in propagator.propagate(len(run), {0: prompt}, lambda i: embeddings[i], "forward"):
        now = time.perf_counter()
        step_ms.append(1000 * (now - last))
        last = now
    steady = step_ms[1:] or step_ms

    # FLOPs of one steady step (a frame with a full memory bank).
    counter = FlopCounterMode(display=False)
    items = propagator.propagate(len(run), {0: prompt}, lambda i: embeddings[i], "forward")
    for _ in range(min(len(run) - 2, int(config.num_maskmem))):
        next(items)
    from torch.nn.attention import SDPBackend, sdpa_kernel

    with counter, sdpa_kernel(SDPBackend.MATH):  # attention as matmuls, so they are counted
        next(items, None)
    flops = counter.get_total_flops()

    # Memory held by the session after two runs longer than twice what SAM2 looks back on
    # (its memory frames and object pointers): the same, however long the run.
    lengths = (2 * propagator.keep + 8, args.long)
    held = {length: held_after(propagator, prompt, embeddings, length) for length in lengths}

    floor_ms = 1000 * flops / (MATMUL_GFLOPS * 1e9)
    encode = statistics.median(encode_ms)
    step = statistics.median(steady)
    print(
        f"SAM2 video (random weights), frames {run[0].shape[1]}×{run[0].shape[0]}, "
        f"{args.threads} threads, {len(steady)} steady frames"
    )
    print(f"{'what':46s} {'ms / frame':>11s} {'vs floor':>9s}")
    print(f"{'propagation, cached embeddings':46s} {step:11.0f} {step / floor_ms:8.2f}×")
    print(f"{'propagation, uncached (encoder + step)':46s} {encode + step:11.0f}")
    print(f"{'  encoder alone':46s} {encode:11.0f}")
    print(f"{'per-frame teacher (an earlier run)':46s} {4200:11.0f}")
    rate = f"({flops / 1e9:.0f} GFLOP at {MATMUL_GFLOPS:.0f} GFLOP/s)"
    print(f"{'FLOP floor of one step':46s} {floor_ms:11.0f}   {rate}")
    for length, mib in held.items():
        print(f"{f'session memory after {length} frames':46s} {mib:10.1f} MiB")


if __name__ == "__main__":
    main()
