"""Active learning against random order, with an oracle reviewer, on synthetic weld runs.

A pool of frames from many synthetic runs (consecutive frames of a run look alike, as in a real
video), a fixed validation set (best-epoch choice, as the validation split does in the service)
and a test set, both from other runs. Both strategies start from the same random labels; each
round the oracle labels ``--step`` more frames — (a) the head of the review queue as the service
builds it (``combined_score`` of the student's spread over latent samples, then the diversity
pick over its top 50, on small thumbnails since no DINO weights are here; no teacher components,
as a random-weight teacher would score noise) or (b) random ones — and a fresh student is
trained for a fixed number of optimiser steps. Prints the test mIoU and mED per round (mean over
``--repeats`` start sets), and how many labels the queue needed to reach random order's final
quality (goal: at most 70 % of random's).

    .venv/bin/python bench/active.py [--rounds 6] [--steps 250] [--repeats 3]
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
import torch

from weldpool_core.active import combined_score, diverse_order
from weldpool_core.metrics import iou, keypoint_scores
from weldpool_core.student.model import student_config
from weldpool_core.student.predict import StudentPredictor
from weldpool_core.student.train import TrainConfig, train_student
from weldpool_core.synth import SynthParams, synth_sequence

PARAMS = SynthParams(width=192, height=120)
BATCH = 8
DIVERSITY = 0.5  # WELDPOOL_QUEUE_DIVERSITY's default
DIVERSITY_POOL = 50  # WELDPOOL_QUEUE_DIVERSITY_POOL's default


def _rgb(image: np.ndarray) -> np.ndarray:
    return np.repeat(image[:, :, None], 3, axis=2)


def _thumbnail(image: np.ndarray) -> np.ndarray:
    return cv2.resize(image, (16, 10), interpolation=cv2.INTER_AREA).astype(np.float64).ravel()


def _train(frames, indices, validation, steps: int, seed: int, folder: Path) -> StudentPredictor:
    """A fresh light student trained for about ``steps`` optimiser steps on the labelled frames."""
    samples = [(_rgb(frames[i].image), frames[i].mask, frames[i].keypoints) for i in indices]
    held_out = [(_rgb(f.image), f.mask, f.keypoints) for f in validation]
    student = student_config("light", input_size=128)
    epochs = max(1, math.ceil(steps * BATCH / len(samples)))
    config = TrainConfig(epochs=epochs, batch_size=BATCH, seed=seed, device="cpu")
    train_student(samples, folder, student, config, validation=held_out)
    return StudentPredictor.load(folder, "cpu")


def _evaluate(predictor: StudentPredictor, test) -> tuple[float, float]:
    predictions = predictor.predict([_rgb(f.image) for f in test])
    mean_iou = float(np.mean([iou(p.mask, f.mask) for p, f in zip(predictions, test, strict=True)]))
    pairs = {
        str(i): (p.keypoints, f.keypoints)
        for i, (p, f) in enumerate(zip(predictions, test, strict=True))
    }
    med = keypoint_scores(pairs).med
    return mean_iou, float("nan") if med is None else med


def _queue_pick(predictor, frames, unlabelled: list[int], count: int, samples: int) -> list[int]:
    """The head of the review queue as the service builds it, from the student's spread alone."""
    predictions = predictor.predict([_rgb(frames[i].image) for i in unlabelled], samples=samples)
    scores = np.array(
        [combined_score({"student_spread": p.uncertainty}) or 0.0 for p in predictions]
    )
    head = np.argsort(-scores, kind="stable")[:DIVERSITY_POOL]
    descriptors = np.array([_thumbnail(frames[unlabelled[i]].image) for i in head])
    order = diverse_order(scores[head], descriptors, DIVERSITY)
    return [unlabelled[head[i]] for i in order[:count]]


def _simulate(pool, validation, test, args, repeat: int, root: Path) -> dict[str, list[tuple]]:
    """One repeat: both strategies from the same start, ``args.rounds`` rounds each."""
    rng = np.random.default_rng(repeat)
    start = [int(i) for i in rng.choice(len(pool), args.start, replace=False)]
    labelled = {"queue": list(start), "random": list(start)}
    history: dict[str, list[tuple]] = {"queue": [], "random": []}
    for round_index in range(args.rounds):
        for strategy in ("queue", "random"):
            indices = labelled[strategy]
            folder = root / f"{repeat}-{strategy}-{round_index}"
            seed = 1000 * repeat + round_index
            predictor = _train(pool, indices, validation, args.steps, seed, folder)
            history[strategy].append((len(indices), *_evaluate(predictor, test)))
            if round_index == args.rounds - 1:
                continue
            taken = set(indices)
            unlabelled = [i for i in range(len(pool)) if i not in taken]
            if strategy == "queue":
                picked = _queue_pick(predictor, pool, unlabelled, args.step, args.samples)
            else:
                picked = [int(i) for i in rng.choice(unlabelled, args.step, replace=False)]
            labelled[strategy] = indices + picked
    return history


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=6)
    parser.add_argument("--start", type=int, default=10, help="labels before the first round")
    parser.add_argument("--step", type=int, default=10, help="labels added per round")
    parser.add_argument("--steps", type=int, default=250, help="optimiser steps per training")
    parser.add_argument("--repeats", type=int, default=3, help="start sets averaged over")
    parser.add_argument("--pool-runs", type=int, default=20)
    parser.add_argument("--run-length", type=int, default=12)
    parser.add_argument("--samples", type=int, default=8, help="latent draws for the spread")
    args = parser.parse_args()
    torch.set_num_threads(2)
    started = time.perf_counter()
    pool = [
        f
        for seed in range(args.pool_runs)
        for f in synth_sequence(seed=seed, length=args.run_length, params=PARAMS)
    ]
    validation = [f for seed in (200, 201) for f in synth_sequence(seed, 5, PARAMS)]
    test = [f for seed in range(100, 106) for f in synth_sequence(seed, 8, PARAMS)]
    runs = []
    with tempfile.TemporaryDirectory() as root:
        for repeat in range(args.repeats):
            runs.append(_simulate(pool, validation, test, args, repeat, Path(root)))
            print(f"repeat {repeat + 1}/{args.repeats} done", flush=True)
    mean = {
        strategy: [
            tuple(float(np.nanmean([run[strategy][r][c] for run in runs])) for c in range(3))
            for r in range(args.rounds)
        ]
        for strategy in ("queue", "random")
    }
    print(
        f"\nactive learning: pool of {len(pool)} synthetic frames ({args.pool_runs} runs of "
        f"{args.run_length}), test {len(test)} frames of 6 other runs; light student at 128², "
        f"~{args.steps} steps of {BATCH} per training; mean of {args.repeats} start sets; "
        f"{time.perf_counter() - started:.0f} s"
    )
    print(
        f"{'labels':>6} {'queue mIoU':>11} {'queue mED':>10} {'random mIoU':>12} {'random mED':>11}"
    )
    for (count, q_iou, q_med), (_, r_iou, r_med) in zip(mean["queue"], mean["random"], strict=True):
        print(f"{count:>6.0f} {q_iou:>11.3f} {q_med:>10.1f} {r_iou:>12.3f} {r_med:>11.1f}")
    final_count, final_iou, final_med = mean["random"][-1]
    reached = next(
        (c for c, q_iou, q_med in mean["queue"] if q_iou >= final_iou and q_med <= final_med),
        None,
    )
    if reached is None:
        print(f"the queue did not reach random order's final quality in {final_count:.0f} labels")
    else:
        print(
            f"the queue reached random order's final quality (mIoU {final_iou:.3f}, mED "
            f"{final_med:.1f} px) with {reached:.0f} labels: {reached / final_count:.0%} of "
            f"random's {final_count:.0f} (goal ≤ 70 %)"
        )


if __name__ == "__main__":
    main()
