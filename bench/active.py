"""Active learning against random order, with an oracle reviewer, on synthetic weld runs.

A pool of frames from several synthetic runs (consecutive frames of a run look alike, as in a
real video) and a held-out test set from other runs. Both strategies start from the same 10
random labels; each round the oracle labels 10 more frames — (a) the head of the review queue
(the student's uncertainty over latent samples, with the queue's diversity pick on small
thumbnails, since no DINO weights are here) or (b) random ones — and the student is retrained
from scratch. Prints mIoU and mED on the test set per round, and how many labels the queue
needed to reach random order's final quality (goal: at most 70 % of random's).

    .venv/bin/python bench/active.py [--rounds 6] [--epochs 10] [--pool-runs 6]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
import torch

from weldpool_core.active import diverse_order
from weldpool_core.metrics import iou, keypoint_scores
from weldpool_core.student.model import student_config
from weldpool_core.student.predict import StudentPredictor
from weldpool_core.student.train import TrainConfig, train_student
from weldpool_core.synth import SynthParams, synth_sequence

PARAMS = SynthParams(width=192, height=120)


def _rgb(image: np.ndarray) -> np.ndarray:
    return np.repeat(image[:, :, None], 3, axis=2)


def _thumbnail(image: np.ndarray) -> np.ndarray:
    return cv2.resize(image, (16, 10), interpolation=cv2.INTER_AREA).astype(np.float64).ravel()


def _train(frames, indices, epochs: int, seed: int, folder: Path) -> StudentPredictor:
    samples = [(_rgb(frames[i].image), frames[i].mask, frames[i].keypoints) for i in indices]
    student = student_config("light", input_size=128)
    config = TrainConfig(epochs=epochs, batch_size=8, seed=seed, device="cpu")
    train_student(samples, folder, student, config)
    return StudentPredictor.load(folder, "cpu")


def _evaluate(predictor: StudentPredictor, test) -> tuple[float, float | None]:
    predictions = predictor.predict([_rgb(f.image) for f in test])
    mean_iou = float(np.mean([iou(p.mask, f.mask) for p, f in zip(predictions, test, strict=True)]))
    pairs = {
        str(i): (p.keypoints, f.keypoints)
        for i, (p, f) in enumerate(zip(predictions, test, strict=True))
    }
    return mean_iou, keypoint_scores(pairs).med


def _queue_pick(predictor, frames, unlabelled: list[int], count: int, samples: int) -> list[int]:
    predictions = predictor.predict([_rgb(frames[i].image) for i in unlabelled], samples=samples)
    scores = np.array([p.uncertainty or 0.0 for p in predictions])
    head = np.argsort(-scores, kind="stable")[: max(count * 4, count)]
    order = diverse_order(
        scores[head], np.array([_thumbnail(frames[unlabelled[i]].image) for i in head])
    )
    return [unlabelled[head[i]] for i in order[:count]]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=6)
    parser.add_argument("--epochs", type=int, default=10)
    parser.add_argument("--pool-runs", type=int, default=6)
    parser.add_argument("--run-length", type=int, default=30)
    parser.add_argument("--samples", type=int, default=6)
    args = parser.parse_args()
    torch.set_num_threads(2)
    started = time.perf_counter()
    pool = [
        f
        for seed in range(args.pool_runs)
        for f in synth_sequence(seed=seed, length=args.run_length, params=PARAMS)
    ]
    test = [f for seed in (100, 101) for f in synth_sequence(seed=seed, length=15, params=PARAMS)]
    rng = np.random.default_rng(0)
    start = [int(i) for i in rng.choice(len(pool), 10, replace=False)]
    labelled = {"queue": list(start), "random": list(start)}
    history: dict[str, list[tuple[int, float, float | None]]] = {"queue": [], "random": []}
    with tempfile.TemporaryDirectory() as root:
        for round_index in range(args.rounds):
            for strategy in ("queue", "random"):
                indices = labelled[strategy]
                folder = Path(root) / f"{strategy}-{round_index}"
                predictor = _train(pool, indices, args.epochs, seed=round_index, folder=folder)
                history[strategy].append((len(indices), *_evaluate(predictor, test)))
                unlabelled = [i for i in range(len(pool)) if i not in set(indices)]
                if strategy == "queue":
                    picked = _queue_pick(predictor, pool, unlabelled, 10, args.samples)
                else:
                    picked = [int(i) for i in rng.choice(unlabelled, 10, replace=False)]
                labelled[strategy] = indices + picked
    print(
        f"\nactive learning on {len(pool)} synthetic frames ({args.pool_runs} runs), test "
        f"{len(test)} frames of other runs; light student at 128², {args.epochs} epochs "
        f"per round; {time.perf_counter() - started:.0f} s"
    )
    print(
        f"{'labels':>6} {'queue mIoU':>11} {'queue mED':>10} {'random mIoU':>12} {'random mED':>11}"
    )
    for (count, q_iou, q_med), (_, r_iou, r_med) in zip(
        history["queue"], history["random"], strict=True
    ):
        print(f"{count:>6} {q_iou:>11.3f} {_px(q_med):>10} {r_iou:>12.3f} {_px(r_med):>11}")
    final_count, final_iou, final_med = history["random"][-1]
    reached = next(
        (
            c
            for c, q_iou, q_med in history["queue"]
            if q_iou >= final_iou and (final_med is None or (q_med or 1e9) <= final_med)
        ),
        None,
    )
    if reached is None:
        print(f"the queue did not reach random order's final quality within {final_count} labels")
    else:
        print(
            f"the queue reached random order's final quality (mIoU {final_iou:.3f}, mED "
            f"{_px(final_med)}) with {reached} labels: {reached / final_count:.0%} of "
            f"random's {final_count} (goal ≤ 70 %)"
        )


def _px(value: float | None) -> str:
    return "-" if value is None else f"{value:.1f}"


if __name__ == "__main__":
    main()
