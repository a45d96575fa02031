"""Which uncertainty ranks the student's errors on the varied synthetic pool of bench/active.py?

The pool of ``bench/active.py --varied`` (20 synthetic runs of 12 frames, 6 of them dim,
glaring or zoomed beyond what the training augmentation covers) and its validation runs. For
each start set (``--repeats``) and each label count (``--labels``), a fresh light student (128²,
250 steps of 8, as that bench trains it) learns from that many frames of the pool drawn at
random, and every candidate score is computed on the rest of the pool: Spearman ρ against the
student's real error (1 − IoU), per student, then the mean and range over the students. The
candidates are the parts of ``StudentPredictor.predict``'s uncertainty (``spread``,
``ambiguity``, ``novelty``) and what is made of them: ``shipped`` (the uncertainty as
``predict`` returns it), ``spread ⊕ novelty`` (the rule before 2026-12-05's geometric mean),
``geometric`` (√(spread × ambiguity), computed here apart from ``predict``), ``distance`` (to
the nearest training frame, unshifted) and ``expected`` (1 − the soft IoU of the draws' mean
mask with the plain pass's answer, its mask ≥ 0.5) and ``dropout`` (1 − the mean soft IoU of
8 passes with feature dropout 0.2 with the plain pass, as in ``bench/uncertainty.py``, the
real-label counterpart). About 3 minutes on 2 cores.

    PYTHONPATH=. .venv/bin/python bench/uncertainty_synthetic.py [--repeats 3] [--labels 10 30]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from active import CONDITIONS, RARE_RUNS, _rgb, _run, _train
from scipy.stats import spearmanr

from weldpool_core.metrics import iou
from weldpool_core.student.predict import (
    StudentPrediction,
    StudentPredictor,
    combine,
    frame_codes,
    frames_to_batch,
    predictive_mask,
)

SAMPLES = 8  # the app's latent draws per frame


def soft_iou(a: np.ndarray, b: np.ndarray) -> float:
    """Σ min ÷ Σ max of two probability maps (1 when both are empty)."""
    union = float(np.maximum(a, b).sum())
    return float(np.minimum(a, b).sum()) / union if union > 1e-6 else 1.0


def signals(
    predictor: StudentPredictor, images: list[np.ndarray]
) -> tuple[list[StudentPrediction], dict[str, np.ndarray]]:
    """The predictions (with the uncertainty) and every candidate, per frame."""
    found = predictor.predict(images, samples=SAMPLES)
    parts = [p.uncertainty_parts or {} for p in found]
    spread = np.array([q["spread"] or 0.0 for q in parts])
    ambiguity = np.array([q["ambiguity"] or 0.0 for q in parts])
    novelty = [q["novelty"] for q in parts]
    batch, geometries = frames_to_batch(images, predictor.config)
    model = predictor.model
    with torch.inference_mode():
        features, skips = model.encoder_maps(batch)
        mean, logvar = model.posterior(features)
        plain = torch.sigmoid(model.decode(mean, skips)[0].float()).numpy()
        drawn = predictive_mask(model, mean, logvar, SAMPLES, skips=skips).numpy()
        assert predictor.training_codes is not None
        distance = np.array(predictor.training_codes.distance(frame_codes(features)))
        torch.manual_seed(0)
        dropped = []
        for _ in range(SAMPLES):
            kept, _ = model.posterior(F.dropout2d(features, 0.2, training=True))
            dropped.append(torch.sigmoid(model.decode(kept, skips)[0].float()).numpy())
    expected, dropout = [], []
    for index, geometry in enumerate(geometries):
        rows, columns = geometry.inner_rows, geometry.inner_columns
        base = plain[index, rows, columns].astype(np.float64)
        dropout.append(
            1 - float(np.mean([soft_iou(d[index, rows, columns], base) for d in dropped]))
        )
        p = drawn[index, rows, columns].astype(np.float64)
        answer = plain[index, rows, columns] >= 0.5
        common = float(p[answer].sum())
        expected.append(1 - common / max(float(answer.sum()) + float(p[~answer].sum()), 1e-6))
    return found, {
        "shipped": np.array([p.uncertainty for p in found], np.float64),
        "spread": spread,
        "ambiguity": ambiguity,
        "novelty": np.array([n or 0.0 for n in novelty]),
        "spread ⊕ novelty": np.array([combine(s, n) for s, n in zip(spread, novelty, strict=True)]),
        "geometric": np.sqrt(spread * ambiguity),
        "distance": distance,
        "expected": np.array(expected),
        "dropout": np.array(dropout),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3, help="start sets")
    parser.add_argument("--labels", type=int, nargs="+", default=[10, 30])
    parser.add_argument("--steps", type=int, default=250, help="optimiser steps per training")
    args = parser.parse_args()
    torch.set_num_threads(2)
    begun = time.perf_counter()
    pool, condition = [], []
    for seed in range(20):
        kind = RARE_RUNS.get(seed, "nominal")
        for frame in _run(seed, 12, kind):
            pool.append(frame)
            condition.append(kind)
    validation = [f for seed in (200, 201) for f in _run(seed, 5, "nominal")]
    rows: list[dict[str, float]] = []
    with tempfile.TemporaryDirectory() as root:
        for repeat in range(args.repeats):
            order = [int(i) for i in np.random.default_rng(repeat).permutation(len(pool))]
            for count in args.labels:
                labelled = set(order[:count])
                folder = Path(root) / f"{repeat}-{count}"
                seed = 1000 * repeat + count
                predictor = _train(pool, sorted(labelled), validation, args.steps, seed, folder)
                rest = [i for i in range(len(pool)) if i not in labelled]
                images = [_rgb(pool[i].image) for i in rest]
                masks, found = signals(predictor, images)
                error = [1 - iou(p.mask, pool[i].mask) for p, i in zip(masks, rest, strict=True)]
                rho = {name: float(spearmanr(v, error)[0]) for name, v in found.items()}
                rows.append(rho)
                kinds = np.array([condition[i] for i in rest])
                by_kind = ", ".join(
                    f"{k} {np.mean(np.array(error)[kinds == k]):.3f}" for k in CONDITIONS
                )
                print(f"start set {repeat}, {count} labels: 1 − IoU {by_kind}", flush=True)
                print("   " + "  ".join(f"{k} {v:+.2f}" for k, v in rho.items()), flush=True)
    print(
        f"\n{len(rows)} students ({args.repeats} start sets × labels {args.labels}), "
        f"{time.perf_counter() - begun:.0f} s; ρ against 1 − IoU on the rest of the pool"
    )
    print(f"{'candidate':<18}{'mean':>7}{'min':>7}{'max':>7}   per student")
    for name in rows[0]:
        values = [r[name] for r in rows]
        shown = " ".join(f"{v:+.2f}" if not np.isnan(v) else "  nan" for v in values)
        print(
            f"{name:<18}{np.nanmean(values):>+7.2f}{np.nanmin(values):>+7.2f}"
            f"{np.nanmax(values):>+7.2f}   {shown}"
        )


if __name__ == "__main__":
    main()
