"""The GPU check: every model path on CUDA, in the precision it runs in there (bf16), end to end.

For whoever has a GPU (CI has none). Random weights in the real architectures (no download):
DINO ViT-S/8 and SAM2 Hiera-tiny are saved with ``save_pretrained`` and loaded back through the
product's one loader, so device, precision and the weights' identity are chosen as in
production. Steps, each timed, with a verdict:

1. load  — both models through ``weldpool_core.teacher.loader`` (bf16 on CUDA).
1b. encoder — ``hiera.ImageEncoder`` against transformers' ``get_image_embeddings`` on the
   device, in its precision: same outputs, both timed, and which one ``set_image`` runs there
   (``hiera.MEASURED_FASTER``: add the device type where ours is measured faster).
2. teacher — ``Teacher.run`` on a 1280×800 frame (a real WAAM frame when ../shared is here),
   its embedding written to a disk cache.
2b. teacher batch — ``Teacher.run_many`` on 8 frames (a GPU worker's teacher run): ms per frame
   against one by one, and each mask as the frame alone gives it.
3. click from disk — a new cache on the same folder (another process's view): the embedding
   comes from disk, in the model's precision, and a click decodes from it.
3b. propagate — SAM2's video model (from the same checkpoint) through 6 frames from the cached
   embeddings, in the inference precision.
4. train — a light student for a few steps on CUDA (synthetic frames).
5. predict — the trained student on CUDA (autocast in the inference precision).
6. export — ONNX and TorchScript of it, checked against PyTorch.

    PYTHONPATH=. .venv/bin/python bench/gpu.py                # CUDA (fails without one)
    PYTHONPATH=. .venv/bin/python bench/gpu.py --device cpu --dtype bf16   # the same on CPU

Prints a table (median ms of ``--runs`` where repeated) and exits 1 if any step failed.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch

REPO = Path(__file__).resolve().parents[1]
SHARED_FRAME = REPO.parent / "shared" / "data" / "waam" / "frames" / "compressed_0mm_f0250.png"


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def _median_ms(fn: Callable[[], Any], runs: int, device: torch.device) -> tuple[float, Any]:
    result, times = None, []
    for _ in range(runs):
        _sync(device)
        start = time.perf_counter()
        result = fn()
        _sync(device)
        times.append((time.perf_counter() - start) * 1000)
    return statistics.median(times), result


def _frame() -> np.ndarray:
    from weldpool_core.io import read_image, to_rgb8
    from weldpool_core.synth import SynthParams, synth_frame

    if SHARED_FRAME.exists():
        return to_rgb8(read_image(SHARED_FRAME.read_bytes()).pixels)
    return synth_frame(seed=3, params=SynthParams(1280, 800)).image


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cuda")
    parser.add_argument("--dtype", choices=["auto", "bf16", "fp16", "fp32"], default="auto")
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--steps", type=int, default=40, help="student training steps")
    args = parser.parse_args()

    import weldpool_core.device as device_module
    from weldpool_core.device import resolve_device

    device = resolve_device(args.device)
    if args.dtype != "auto":  # e.g. bf16 on a CPU, to check dtype handling without a GPU
        chosen = {"bf16": torch.bfloat16, "fp16": torch.float16, "fp32": torch.float32}[args.dtype]
        device_module.inference_dtype = lambda _device: chosen  # type: ignore[assignment]
    dtype = device_module.inference_dtype(device)
    name = torch.cuda.get_device_name(device) if device.type == "cuda" else "cpu"
    print(f"device {device} ({name}), inference dtype {dtype}, torch {torch.__version__}")

    rows: list[tuple[str, str, str, str]] = []
    failed = False
    state: dict[str, Any] = {}

    def step(name: str, fn: Callable[[], str]) -> None:
        nonlocal failed
        start = time.perf_counter()
        try:
            note = fn()
            verdict = "ok"
        except Exception as exc:  # report every step, then fail
            traceback.print_exc()
            note, verdict, failed = f"{type(exc).__name__}: {exc}"[:90], "FAILED", True
        rows.append((name, verdict, f"{time.perf_counter() - start:.1f}", note))

    with tempfile.TemporaryDirectory() as scratch:
        root = Path(scratch)
        frame = _frame()
        sha = "gpu-check-" + str(frame.shape)
        p_shape = (int(frame.shape[0]), int(frame.shape[1]))

        def load() -> str:
            from transformers import Sam2VideoConfig, Sam2VideoModel, ViTModel

            from weldpool_core.teacher.dino import dino_vits8_config
            from weldpool_core.teacher.loader import load_dino, load_sam2, load_sam2_video

            torch.manual_seed(0)
            ViTModel(dino_vits8_config(), add_pooling_layer=False).save_pretrained(root / "dino")
            # One SAM2 checkpoint for the image model and the video model, as the hub's.
            Sam2VideoModel(Sam2VideoConfig()).save_pretrained(root / "sam2")
            state["sam2"] = load_sam2(str(root / "sam2"), str(device))
            state["video"] = load_sam2_video(str(root / "sam2"), str(device))
            state["dino"] = load_dino(str(root / "dino"), str(device), 480)
            got = (state["sam2"].dtype, state["video"].dtype)
            if got != (dtype, dtype):
                raise AssertionError(f"SAM2 loaded in {got}, expected {dtype}")
            return f"SAM2 {got[0]}, identity {state['sam2'].cache_identity[-40:]}"

        def encoder() -> str:
            from weldpool_core.teacher.hiera import MEASURED_FASTER, ImageEncoder

            predictor = state["sam2"]
            pixels = predictor.preprocess(frame)
            mine = ImageEncoder(predictor.model)  # ours, whichever the predictor picked here
            with torch.inference_mode():
                ours_ms, ours = _median_ms(lambda: mine(pixels), args.runs, device)
                theirs_ms, theirs = _median_ms(
                    lambda: predictor.model.get_image_embeddings(pixels), args.runs, device
                )
            for mine, reference in zip(ours, theirs, strict=True):
                scale = float(reference.float().abs().max())
                error = float((mine.float() - reference.float()).abs().max())
                if error > 0.02 * scale:
                    raise AssertionError(f"encoder differs by {error:.3g} (scale {scale:.3g})")
            runs = "ours" if device.type in MEASURED_FASTER else "transformers'"
            faster = "ours" if ours_ms < theirs_ms else "transformers'"
            return (
                f"ours {ours_ms:.1f} ms, transformers {theirs_ms:.1f} ms, outputs equal; "
                f"{faster} faster here, {runs} runs here (hiera.MEASURED_FASTER)"
            )

        def teacher() -> str:
            from weldpool_core.teacher.cache import EmbeddingCache
            from weldpool_core.teacher.teacher import Teacher

            run = Teacher(state["dino"], state["sam2"], "sam2", EmbeddingCache(root / "cache"))
            run.run(frame, sha)  # warm-up (kernels, allocator); writes the disk cache
            ms, result = _median_ms(lambda: run.run(frame, None), args.runs, device)
            return f"{ms:.0f} ms/frame uncached, mask {int(result.mask.sum())} px"

        def teacher_batch() -> str:
            from weldpool_core.teacher.cache import EmbeddingCache
            from weldpool_core.teacher.teacher import Teacher

            run = Teacher(state["dino"], state["sam2"], "sam2", EmbeddingCache(None))
            frames = [frame] * 8
            run.run_many(frames)  # warm-up at this batch size
            ms, results = _median_ms(lambda: run.run_many(frames), args.runs, device)
            single, _ = _median_ms(lambda: run.run(frame, None), args.runs, device)
            alone = run.run(frame, None).mask
            if any((r.mask != alone).mean() > 1e-3 for r in results):
                raise AssertionError("a batched frame's mask differs from the frame alone")
            return f"{ms / 8:.0f} ms/frame in batches of 8 ({single / (ms / 8):.2f}× one by one)"

        def click_from_disk() -> str:
            from weldpool_core.teacher.cache import EmbeddingCache, cached_embedding
            from weldpool_core.teacher.sam2 import Prompts

            predictor = state["sam2"]
            embedding, tier = cached_embedding(
                predictor, EmbeddingCache(root / "cache"), sha, lambda: frame, frame.shape[:2]
            )
            if tier != "disk":
                raise AssertionError(f"expected a disk hit, got {tier}")
            if embedding.features[2].dtype != predictor.dtype:
                raise AssertionError(f"disk hit in {embedding.features[2].dtype}")
            prompts = Prompts(((640.0, 400.0),), (1,))
            ms, prediction = _median_ms(
                lambda: predictor.predict(embedding, prompts), args.runs, device
            )
            return f"{ms:.1f} ms/click, score {prediction.score:.2f}"

        def propagate() -> str:
            import numpy as np

            from weldpool_core.teacher.cache import EmbeddingCache, cached_embedding

            frames = [np.roll(frame, 4 * i, axis=1) for i in range(6)]
            cache = EmbeddingCache(root / "cache")
            for i, picture in enumerate(frames):  # the teacher's cache, as propagation reads it
                cached_embedding(state["sam2"], cache, f"p{i}", lambda p=picture: p, p_shape)
            prompt = np.zeros(frame.shape[:2], bool)
            prompt[300:500, 500:800] = True
            times: list[float] = []

            def run() -> list[Any]:
                items, last = [], time.perf_counter()

                def embed(i: int) -> Any:
                    return cached_embedding(state["sam2"], cache, f"p{i}", None, p_shape)[0]

                for item in state["video"].propagate(len(frames), {0: prompt}, embed, "forward"):
                    _sync(device)
                    times.append(1000 * (time.perf_counter() - last))
                    items.append(item)
                    last = time.perf_counter()
                return items

            run()  # warm-up
            times.clear()
            items = run()
            confidence = min(item.confidence for item in items)
            ms = statistics.median(times)
            return f"{ms:.0f} ms/frame from cached embeddings, min confidence {confidence:.2f}"

        def train() -> str:
            from weldpool_core.io import to_rgb8
            from weldpool_core.student.data import TrainingFrame
            from weldpool_core.student.train import TrainConfig, train_student
            from weldpool_core.synth import SynthParams, synth_frame

            frames = [
                TrainingFrame(to_rgb8(f.image), f.mask, None, f"s{i}")
                for i, f in enumerate(
                    synth_frame(seed=s, params=SynthParams(320, 200)) for s in range(6)
                )
            ]
            out = root / "student"
            result = train_student(
                frames, out, config=TrainConfig(steps=args.steps, rounds=2, device=str(device))
            )
            state["student"] = out
            return f"{args.steps} steps, best round {result.best_epoch}"

        def predict() -> str:
            from weldpool_core.student.predict import StudentPredictor

            predictor = StudentPredictor.load(state["student"], device)
            images = [frame] * 8
            predictor.predict(images[:1])
            ms, out = _median_ms(lambda: predictor.predict(images), args.runs, device)
            return f"{8000 / ms:.0f} fps (batch 8 of 1280×800), {len(out[0].keypoints)} kp"

        def export() -> str:
            from weldpool_core.student.export import export_student

            result = export_student(state["student"])
            return ", ".join(f"{name} max diff {d:.1e}" for name, d in result.differences.items())

        step("load", load)
        step("encoder", encoder)
        step("teacher", teacher)
        step("teacher batch", teacher_batch)
        step("click from disk", click_from_disk)
        step("propagate", propagate)
        step("train", train)
        step("predict", predict)
        step("export", export)

    width = max(len(r[3]) for r in rows)
    print(f"\n| step | verdict | s | notes{' ' * (width - 5)} |")
    print(f"|---|---|---|{'-' * (width + 2)}|")
    for name, verdict, seconds, note in rows:
        print(f"| {name} | {verdict} | {seconds} | {note} |")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
