"""What a label buys, on the real clips: the review queue's order against random and most-novel.

The learning loop simulated on the 15 real labels (``../shared/data/waam/labels`` or
$WELDPOOL_SHARED_DATA), leave-one-clip-out: for each held-out clip, the pool is the other two
clips' 10 labelled frames. Every strategy starts from the same labels, one frame of each pool
clip drawn at random (per seed); each round it labels ``--step`` more frames of the pool, a
fresh default student (``StudentConfig()``, ``TrainConfig(seed=seed)``, as ``weldpool train``
trains it) is trained on the labels so far, and mIoU and mED are measured on the held-out
clip's 5 frames. The strategies pick the next frames:

- ``queue``: the head of the review queue as the service builds it from the student: its
  uncertainty (``predict(samples=8)``: √(the latent draws' spread × the mask's ambiguity) ⊕
  novelty beyond the familiar distance) through ``combined_score``, reordered for diversity
  (``diverse_order``, trade-off 0.5; on 16×10 thumbnails, as no DINO weights are here; no
  teacher components: a random-weight teacher would score noise);
- ``novel``: most novel first: the largest distance of the frame's encoder descriptor to the
  nearest labelled frame's (``TrainingCodes.distance``, unshifted);
- ``random``: a seeded random order.

The first round (the start labels) and the last (all 10) are the same for every strategy and
trained once. Prints the table (mean over seeds and folds, and the range over seeds) and writes
the plot (``--plot``, a PNG; needs matplotlib: ``pip install matplotlib``). Trained folders
are kept under ``--cache`` (``curve-<fold>-s<seed>-<strategy>-<labels>``, with the frames they
learnt from): a rerun only scores, trains again a folder whose strategy now picks other frames
(after a change of the score), and more seeds can be added later.

    PYTHONPATH=. .venv/bin/python bench/label_curve.py [--seeds 0 1 2] [--step 2]
        [--plot docs/images/label-curve.png]
"""

from __future__ import annotations

import argparse
import json
import shutil
import time
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import torch
from real_student import cached_fold, folds, real_frames

from weldpool_core.active import combined_score, diverse_order
from weldpool_core.student.data import TrainingFrame
from weldpool_core.student.model import StudentConfig
from weldpool_core.student.predict import StudentPredictor, frame_codes, frames_to_batch
from weldpool_core.student.train import TrainConfig

STRATEGIES = ("queue", "novel", "random")
SAMPLES = 8  # the app's latent draws per frame
DIVERSITY = 0.5  # WELDPOOL_QUEUE_DIVERSITY's default


def _thumbnail(image: np.ndarray) -> np.ndarray:
    gray = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) if image.ndim == 3 else image
    return cv2.resize(gray, (16, 10), interpolation=cv2.INTER_AREA).astype(np.float64).ravel()


def _pick(
    strategy: str,
    predictor: StudentPredictor,
    frames: list[TrainingFrame],
    unlabelled: list[int],
    count: int,
    rng: np.random.Generator,
) -> list[int]:
    """The next ``count`` frames of ``unlabelled`` the strategy labels."""
    if strategy == "random":
        return [int(i) for i in rng.choice(unlabelled, count, replace=False)]
    images = [frames[i].image for i in unlabelled]
    if strategy == "novel":
        batch, _ = frames_to_batch(images, predictor.config)
        with torch.inference_mode():
            codes = frame_codes(predictor.model.features(batch))
        assert predictor.training_codes is not None
        distance = np.array(predictor.training_codes.distance(codes))
        return [unlabelled[i] for i in np.argsort(-distance, kind="stable")[:count]]
    found = predictor.predict(images, samples=SAMPLES)
    scores = np.array(
        [combined_score({"student_uncertainty": p.uncertainty}) or 0.0 for p in found]
    )
    descriptors = np.array([_thumbnail(image) for image in images])
    order = diverse_order(scores, descriptors, DIVERSITY)
    return [unlabelled[i] for i in order[:count]]


def _curve(
    frames: list[TrainingFrame],
    fold: tuple[str, list[int], list[int]],
    seed: int,
    step: int,
    cache: Path,
) -> dict[str, list[tuple[int, float, float]]]:
    """One fold and seed: per strategy, ``(labels, mIoU, mED)`` per round."""
    name, pool, test = fold
    held = [frames[i] for i in test]
    clips = sorted({frames[i].name.split("_f")[0] for i in pool})
    rng = np.random.default_rng(seed)
    start = [int(rng.choice([i for i in pool if frames[i].name.startswith(c)])) for c in clips]
    config = replace(TrainConfig(device="cpu"), seed=seed)
    stem = f"curve-{name.replace(':', '-')}-s{seed}"
    curves: dict[str, list[tuple[int, float, float]]] = {}
    shared: dict[int, tuple[StudentPredictor, float, float]] = {}

    def trained(labels: list[int], strategy: str) -> tuple[StudentPredictor, float, float]:
        shared_round = len(labels) in (len(start), len(pool))
        if shared_round and len(labels) in shared:
            return shared[len(labels)]
        folder = cache / f"{stem}-{'all' if shared_round else strategy}-{len(labels)}"
        chosen = [frames[i] for i in sorted(labels)]
        record = folder / "curve-labels.json"
        if record.is_file() and json.loads(record.read_text()) != [f.name for f in chosen]:
            shutil.rmtree(folder)  # trained on other picks (an earlier score): train again
        begun = time.perf_counter()
        done = cached_fold(chosen, held, folder, StudentConfig(), config, 0)
        record.write_text(json.dumps([f.name for f in chosen]))
        if time.perf_counter() - begun > 5:
            print(f"  {folder.name}: trained {done.seconds:.0f} s", flush=True)
        answer = (StudentPredictor.load(folder, "cpu"), done.scores.miou, done.scores.med or np.nan)
        if shared_round:
            shared[len(labels)] = answer
        return answer

    for strategy in STRATEGIES:
        labels, order_rng = list(start), np.random.default_rng(1000 + seed)
        curves[strategy] = []
        while True:
            predictor, miou, med = trained(labels, strategy)
            curves[strategy].append((len(labels), miou, med))
            unlabelled = [i for i in pool if i not in labels]
            if not unlabelled:
                break
            count = min(step, len(unlabelled))
            if len(unlabelled) - count < step:  # the last round: every label
                count = len(unlabelled)
            labels += _pick(strategy, predictor, frames, unlabelled, count, order_rng)
    return curves


def _table(results: dict[tuple[str, int], dict[str, list[tuple[int, float, float]]]]) -> dict:
    """Mean mIoU / mED per strategy and label count over folds and seeds, with the seeds'
    range of the fold-mean mIoU; printed and returned (for the plot)."""
    seeds = sorted({seed for _, seed in results})
    counts = [n for n, _, _ in next(iter(results.values()))["random"]]
    table: dict = {}
    print(f"\n{len(seeds)} seed(s) × {len({f for f, _ in results})} folds; mIoU / mED px on the")
    print("held-out clip's 5 frames, mean over folds and seeds (range of the seeds' means)")
    print(f"{'labels':>7}" + "".join(f"{s:>28}" for s in STRATEGIES))
    for j, n in enumerate(counts):
        row = f"{n:>7}"
        for strategy in STRATEGIES:
            per_seed = [
                np.mean([results[(f, s)][strategy][j][1] for f, ss in results if ss == s])
                for s in seeds
            ]
            miou = float(np.mean([r[strategy][j][1] for r in results.values()]))
            med = float(np.nanmean([r[strategy][j][2] for r in results.values()]))
            table[(strategy, n)] = (miou, min(per_seed), max(per_seed), med)
            row += f"{miou:>10.3f} ({min(per_seed):.3f}–{max(per_seed):.3f}) {med:>5.1f}"
        print(row)
    return table


def _plot(table: dict, path: Path, seeds: int) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axis = plt.subplots(figsize=(6.4, 4.0), dpi=120)
    labels = {"queue": "review queue", "novel": "most novel first", "random": "random order"}
    for strategy in STRATEGIES:
        points = sorted((n, v) for (s, n), v in table.items() if s == strategy)
        counts = [n for n, _ in points]
        axis.plot(counts, [v[0] for _, v in points], marker="o", label=labels[strategy])
        axis.fill_between(counts, [v[1] for _, v in points], [v[2] for _, v in points], alpha=0.15)
    axis.set_xlabel("labels used (of the two other clips' 10)")
    axis.set_ylabel("mIoU on the held-out clip")
    axis.set_title(f"What a label buys: leave-one-clip-out, {seeds} seed(s)")
    axis.grid(alpha=0.3)
    axis.legend()
    figure.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path)
    print(f"plot: {path}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--step", type=int, default=2, help="labels added per round")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--cache", type=Path, default=Path("/tmp/weldpool-bench-students"))
    parser.add_argument("--plot", type=Path, help="write the plot (PNG) here")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    frames = real_frames()
    args.cache.mkdir(parents=True, exist_ok=True)
    results = {}
    for seed in args.seeds:
        for fold in folds(frames, "loco"):
            print(f"seed {seed} {fold[0]}", flush=True)
            results[(fold[0], seed)] = _curve(frames, fold, seed, args.step, args.cache)
            (args.cache / "label-curve.json").write_text(
                json.dumps({f"{f}|{s}": c for (f, s), c in results.items()})
            )
    table = _table(results)
    if args.plot:
        _plot(table, args.plot, len(args.seeds))


if __name__ == "__main__":
    main()
