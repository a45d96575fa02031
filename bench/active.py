"""Active learning against random order, with an oracle reviewer, on synthetic weld runs.

A pool of frames from many synthetic runs (consecutive frames of a run look alike, as in a real
video), a fixed validation set (best-epoch choice, as the validation split does in the service)
and a test set, both from other runs. Both strategies start from the same random labels; each
round the oracle labels ``--step`` more frames — (a) the head of the review queue as the service
builds it (``combined_score`` of the student's uncertainty: the geometric mean of its latent
draws' spread and its mask's ambiguity, ⊕ novelty against its training frames,
``student.predict``; then the diversity pick over its top
50, on small thumbnails since no DINO weights are here; no teacher components, as a
random-weight teacher would score noise) or (b) random ones — and a fresh student is
trained for a fixed number of optimiser steps. Prints the test mIoU and mED per round (mean over
``--repeats`` start sets), the rank correlation of the queue's score with the student's real
error on the frames it ranks (whether the score finds the frames the student gets wrong), and
how many labels the queue needed to reach random order's final quality (goal: at most 70 % of
random's).

    .venv/bin/python bench/active.py [--rounds 6] [--steps 250] [--repeats 3]
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
import torch
from scipy.stats import spearmanr

from weldpool_core.active import combined_score, diverse_order
from weldpool_core.metrics import iou, keypoint_scores
from weldpool_core.student.model import student_config
from weldpool_core.student.predict import StudentPredictor, frame_codes, frames_to_batch
from weldpool_core.student.train import TrainConfig, train_student
from weldpool_core.synth import SynthFrame, SynthParams, synth_sequence

PARAMS = SynthParams(width=192, height=120)
BATCH = 8
DIVERSITY = 0.5  # WELDPOOL_QUEUE_DIVERSITY's default
DIVERSITY_POOL = 50  # WELDPOOL_QUEUE_DIVERSITY_POOL's default


# --varied: runs filmed under conditions the training augmentation does not cover (beyond its
# ±30 % gain, 6-level noise and ±10 % scale): most runs nominal, a few dim, glaring or zoomed.
CONDITIONS = ("nominal", "dim", "glare", "zoom")
RARE_RUNS = {3: "dim", 8: "dim", 5: "glare", 13: "glare", 10: "zoom", 17: "zoom"}


def _condition(frame: SynthFrame, kind: str, seed: int) -> SynthFrame:
    """``frame`` as a run under condition ``kind`` would film it (image, mask and keypoints)."""
    image = frame.image.astype(np.float32)
    if kind == "dim":  # low current: a quarter of the light, the same sensor noise
        noise = np.random.default_rng(seed).normal(0, 3, image.shape)
        image = 0.35 * image + noise
    elif kind == "glare":  # high current: the arc saturates the sensor
        image = 2.2 * image + 25
    elif kind == "zoom":  # another lens or stand-off: 1.5× around the frame's centre
        height, width = image.shape
        matrix = cv2.getRotationMatrix2D((width / 2, height / 2), 0, 1.5)
        image = cv2.warpAffine(image, matrix, (width, height), flags=cv2.INTER_LINEAR)
        mask = cv2.warpAffine(frame.mask.view(np.uint8), matrix, (width, height), flags=0) > 0
        keypoints = frame.keypoints @ matrix[:, :2].T + matrix[:, 2]
        frame = dataclasses.replace(frame, mask=mask, keypoints=keypoints)
    pixels = np.clip(np.round(image), 0, 255).astype(np.uint8)
    return dataclasses.replace(frame, image=pixels)


def _run(seed: int, length: int, kind: str) -> list[SynthFrame]:
    frames = synth_sequence(seed=seed, length=length, params=PARAMS)
    return [_condition(f, kind, seed * 1000 + i) for i, f in enumerate(frames)]


def _rgb(image: np.ndarray) -> np.ndarray:
    return np.repeat(image[:, :, None], 3, axis=2)


def _thumbnail(image: np.ndarray) -> np.ndarray:
    return cv2.resize(image, (16, 10), interpolation=cv2.INTER_AREA).astype(np.float64).ravel()


def _train(frames, indices, validation, steps: int, seed: int, folder: Path) -> StudentPredictor:
    """A fresh light student trained for about ``steps`` optimiser steps on the labelled frames."""
    samples = [(_rgb(frames[i].image), frames[i].mask, frames[i].keypoints) for i in indices]
    held_out = [(_rgb(f.image), f.mask, f.keypoints) for f in validation]
    student = student_config("light", input_size=128)
    config = TrainConfig(
        steps=steps, min_epochs=0, rounds=5, batch_size=BATCH, seed=seed, device="cpu"
    )
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


def _queue_pick(
    predictor, frames, unlabelled: list[int], count: int, samples: int
) -> tuple[list[int], float]:
    """The head of the review queue as the service builds it, from the student's uncertainty,
    and the rank correlation (Spearman) of the queue's score with the student's real error
    (1 − IoU) on the unlabelled frames: above 0, the score finds the frames the student gets
    wrong."""
    predictions = predictor.predict([_rgb(frames[i].image) for i in unlabelled], samples=samples)
    scores = np.array(
        [combined_score({"student_uncertainty": p.uncertainty}) or 0.0 for p in predictions]
    )
    errors = [1 - iou(p.mask, frames[i].mask) for p, i in zip(predictions, unlabelled, strict=True)]
    for part in ("spread", "ambiguity", "novelty"):
        values = [(p.uncertainty_parts or {}).get(part) for p in predictions]
        if all(v is not None for v in values):
            print(f"  ρ of {part} alone: {spearmanr(values, errors)[0]:.2f}", flush=True)
    batch, _ = frames_to_batch([_rgb(frames[i].image) for i in unlabelled], predictor.config)
    with torch.inference_mode():
        codes = frame_codes(predictor.model.features(batch))
    assert predictor.training_codes is not None
    distance = predictor.training_codes.distance(codes)
    print(
        f"  ρ of the unshifted distance: {spearmanr(distance, errors)[0]:.2f} (median "
        f"{np.median(distance):.2f}, max {np.max(distance):.2f}; familiar "
        f"{predictor.training_codes.familiar:.2f})",
        flush=True,
    )
    head = np.argsort(-scores, kind="stable")[:DIVERSITY_POOL]
    descriptors = np.array([_thumbnail(frames[unlabelled[i]].image) for i in head])
    order = diverse_order(scores[head], descriptors, DIVERSITY)
    return [unlabelled[head[i]] for i in order[:count]], float(spearmanr(scores, errors)[0])


def _diverse_pick(frames, unlabelled: list[int], count: int) -> list[int]:
    """The queue's k-center pick alone, over every unlabelled frame, with no score."""
    descriptors = np.array([_thumbnail(frames[i].image) for i in unlabelled])
    order = diverse_order(np.zeros(len(unlabelled)), descriptors, 1.0)
    return [unlabelled[i] for i in order[:count]]


def _simulate(
    pool, validation, test, args, repeat: int, root: Path, strategies: tuple[str, ...]
) -> dict[str, list[tuple]]:
    """One repeat: every strategy from the same start, ``args.rounds`` rounds each."""
    rng = np.random.default_rng(repeat)
    start = [int(i) for i in rng.choice(len(pool), args.start, replace=False)]
    labelled = {strategy: list(start) for strategy in strategies}
    history: dict[str, list[tuple]] = {strategy: [] for strategy in strategies}
    for round_index in range(args.rounds):
        for strategy in strategies:
            indices = labelled[strategy]
            folder = root / f"{repeat}-{strategy}-{round_index}"
            seed = 1000 * repeat + round_index
            predictor = _train(pool, indices, validation, args.steps, seed, folder)
            quality = _evaluate(predictor, test)
            taken = set(indices)
            unlabelled = [i for i in range(len(pool)) if i not in taken]
            count = min(args.step, len(unlabelled))
            rho = 0.0  # random order has no score
            if strategy == "queue":
                picked, rho = _queue_pick(predictor, pool, unlabelled, count, args.samples)
            elif strategy == "diverse":
                picked = _diverse_pick(pool, unlabelled, count)
            else:
                picked = [int(i) for i in rng.choice(unlabelled, count, replace=False)]
            history[strategy].append((len(indices), *quality, rho))
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
    parser.add_argument("--samples", type=int, default=8, help="latent draws per frame")
    parser.add_argument(
        "--diverse",
        action="store_true",
        help="also (c): the diversity pick alone, to tell its share of the queue's gain",
    )
    parser.add_argument(
        "--varied",
        action="store_true",
        help="a few pool runs dim, glaring or zoomed; the test set a quarter of each condition",
    )
    args = parser.parse_args()
    torch.set_num_threads(2)
    started = time.perf_counter()
    rare = RARE_RUNS if args.varied else {}
    rare_runs = sum(1 for seed in range(args.pool_runs) if seed in rare)
    pool = [
        f
        for seed in range(args.pool_runs)
        for f in _run(seed, args.run_length, rare.get(seed, "nominal"))
    ]
    validation = [f for seed in (200, 201) for f in _run(seed, 5, "nominal")]
    kinds = CONDITIONS if args.varied else ("nominal",)
    runs, length = (8, 6) if args.varied else (6, 8)
    test = [
        f
        for index, seed in enumerate(range(100, 100 + runs))
        for f in _run(seed, length, kinds[index % len(kinds)])
    ]
    strategies = ("queue", "random", "diverse") if args.diverse else ("queue", "random")
    results = []
    with tempfile.TemporaryDirectory() as root:
        for repeat in range(args.repeats):
            results.append(_simulate(pool, validation, test, args, repeat, Path(root), strategies))
            print(f"repeat {repeat + 1}/{args.repeats} done", flush=True)
    mean = {
        strategy: [
            tuple(float(np.mean([result[strategy][r][c] for result in results])) for c in range(4))
            for r in range(args.rounds)
        ]
        for strategy in strategies
    }
    print(
        f"\nactive learning: pool of {len(pool)} synthetic frames ({args.pool_runs} runs of "
        f"{args.run_length}{f', {rare_runs} of them dim, glaring or zoomed' if rare else ''}), "
        f"test "
        f"{len(test)} frames of {runs} other runs ({', '.join(kinds)}); light student at 128², "
        f"~{args.steps} steps of {BATCH} per training; mean of {args.repeats} start sets; "
        f"{time.perf_counter() - started:.0f} s"
    )
    header = f"{'labels':>6}" + "".join(
        f" {name + ' mIoU':>13} {name + ' mED':>12}" for name in strategies
    )
    print(header + f" {'score~error ρ':>14}")
    for r in range(args.rounds):
        row = f"{mean['queue'][r][0]:>6.0f}" + "".join(
            f" {mean[name][r][1]:>13.3f} {mean[name][r][2]:>12.1f}" for name in strategies
        )
        print(row + f" {mean['queue'][r][3]:>14.2f}")
    final_count, final_iou, final_med, _ = mean["random"][-1]
    reached = next(
        (c for c, q_iou, q_med, _ in mean["queue"] if q_iou >= final_iou and q_med <= final_med),
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
