"""Which uncertainty ranks the student's real errors? Candidates on the 15 real labels, LOCO.

Leave-one-clip-out on ``../shared/data/waam/labels`` (or $WELDPOOL_SHARED_DATA): for each seed,
each of the three clips is held out, a default student trains on the other two clips' 10
frames (``evaluate.train_and_score``), and every candidate score is computed on the 5 held-out
frames. Spearman ρ of each candidate against 1 − IoU, with a 95 % bootstrap interval (frames
drawn with replacement): pooled over the folds' students (what an outside check measures) and
within each fold (one student ranking one clip: what the review queue faces), over the seeds'
held-out frames together, and the per-seed values. Also the cost of each candidate in ms per
frame (2 threads, batch of 5 frames) and, for the seeds' students as an ensemble, ρ against
the ensemble's own error.

Candidates (one student): ``shipped`` (``StudentPredictor.predict``'s uncertainty: since
2026-12-05 ``geometric`` below, noisy-or'd with novelty beyond the student's own familiar
distance; before it, ``latent`` in its place), ``ambiguity``
(of the plain pass alone), ``novelty`` (the shipped one), ``novelty_fixed`` (beyond the fixed
``FAMILIAR_DISTANCE`` that every student used before measuring its own), ``before`` (the score
shipped before this bench: test-time-pass disagreement noisy-or'd with r / (1 + r)), ``tta``
(that disagreement alone), ``tta_strong`` (passes twice as wide), ``novelty_old`` (r / (1 + r)),
``latent`` (1 − soft IoU of the latent draws' mean mask with the plain one), ``expected`` (1 −
soft IoU of the draws' mean mask with the plain pass's *answer*, its mask ≥ 0.5: the IoU the
answer would lose if the draws' probabilities were calibrated), ``geometric`` (√(latent ×
ambiguity), computed here apart from ``predict``), ``dropout`` (the
same under feature dropout at test time), ``heatmap`` (1 − the strongest keypoint peak); and
across the seeds' students: ``ensemble`` (1 − the mean soft IoU between each student's mask
probability and the students' mean); and across one run's rounds (a student trained here keeps
each round's weights, ``rounds_kept``): ``rounds A-B`` (the same spread over the best round and
the rounds of ``ROUND_SETS``), an ensemble that costs no extra training.

It also prints the students' mIoU with the mask read from other outputs they compute anyway:
the latent draws' mean and the test-time passes' mean (each ≥ 0.5), beside the plain pass's.

Trained folders are kept under ``--cache`` (default /tmp/weldpool-bench-students, which
``real_student.py --cache`` shares), so a rerun only scores; a folder trained before students
measured their familiar distance gets it measured (``train.save_training_codes``) first.

    PYTHONPATH=. .venv/bin/python bench/uncertainty.py [--seeds 0 1 2] [--samples 8]
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from real_student import bootstrap_rho, folds, real_frames
from scipy.stats import spearmanr

from weldpool_core.heatmap import HeatmapParams
from weldpool_core.metrics import iou
from weldpool_core.student import checkpoint
from weldpool_core.student import predict as P
from weldpool_core.student.checkpoint import load_codes, read_student_config
from weldpool_core.student.data import TrainingFrame, prepare_frame
from weldpool_core.student.evaluate import score_predictions
from weldpool_core.student.model import StudentConfig, build_student
from weldpool_core.student.predict import StudentPredictor, frames_to_batch
from weldpool_core.student.train import TrainConfig, save_training_codes, train_student

TTA_RANGES = {"shift": 0.04, "scale": 0.06, "rotation_deg": 4.0, "gamma": 0.35, "gain": 0.2}
"""The earlier score's test-time passes (± fractions of the input, degrees, log-gamma, gain)."""


def soft_iou(a: torch.Tensor, b: torch.Tensor, inside: torch.Tensor) -> torch.Tensor:
    """Soft IoU per frame of two N×S×S probability maps over the ``inside`` pixels."""
    a, b = a * inside, b * inside
    union = torch.maximum(a, b).flatten(1).sum(1)
    common = torch.minimum(a, b).flatten(1).sum(1)
    return torch.where(union > 1e-6, common / union.clamp(min=1e-6), torch.ones_like(union))


def _warp(images: torch.Tensor, theta: torch.Tensor) -> torch.Tensor:
    grid = F.affine_grid(theta.expand(len(images), 2, 3), list(images.shape), align_corners=False)
    return F.grid_sample(images, grid, mode="bilinear", padding_mode="zeros", align_corners=False)


def tta_passes(
    model: torch.nn.Module, batch: torch.Tensor, samples: int, scale: float = 1.0
) -> list[tuple[torch.Tensor, torch.Tensor]]:
    """``samples`` seeded test-time passes (shift, scale, rotation, gamma, gain within ``scale``
    × ``TTA_RANGES``), each as its mask probability mapped back onto the plain pass's grid and
    where that mapping saw the frame (N×S×S each)."""
    ranges = {key: value * scale for key, value in TTA_RANGES.items()}
    rng = np.random.default_rng([0, 11])
    passes = []
    for _ in range(samples):
        angle = np.deg2rad(rng.uniform(-1, 1) * ranges["rotation_deg"])
        size = 1 + rng.uniform(-1, 1) * ranges["scale"]
        shift = rng.uniform(-1, 1, 2) * 2 * ranges["shift"]
        cos, sin = np.cos(angle) * size, np.sin(angle) * size
        theta = torch.tensor([[cos, -sin, shift[0]], [sin, cos, shift[1]]], dtype=torch.float32)
        spread = np.log1p(ranges["gamma"])
        gamma = float(np.exp(rng.uniform(-spread, spread)))
        gain = float(1 + rng.uniform(-1, 1) * ranges["gain"])
        changed = (_warp(batch, theta).clamp(0, 1).pow(gamma) * gain).clamp(0, 1)
        mean, _, skips = model.encode(changed.contiguous(memory_format=torch.channels_last))
        logits, _ = model.decode(mean, skips)
        inverse = torch.linalg.inv(torch.cat([theta, torch.tensor([[0.0, 0.0, 1.0]])]))[:2]
        probability = torch.sigmoid(logits.float())
        back = _warp(torch.stack([probability, torch.ones_like(probability)], 1), inverse)
        passes.append((back[:, 0], back[:, 1] > 0.99))
    return passes


def tta_disagreement(
    passes: list[tuple[torch.Tensor, torch.Tensor]], plain: torch.Tensor, inside: torch.Tensor
) -> list[float]:
    """The earlier score's disagreement: 1 − the mean soft IoU between the plain mask
    probability and the test-time passes mapped back onto it."""
    total = sum(soft_iou(back, plain, inside & seen) for back, seen in passes)
    return [float(1 - v / len(passes)) for v in total]


def tta_mean(passes: list[tuple[torch.Tensor, torch.Tensor]], plain: torch.Tensor) -> torch.Tensor:
    """The mask probability averaged over the plain pass and the test-time passes (each where it
    saw the frame)."""
    total, count = plain.clone(), torch.ones_like(plain)
    for back, seen in passes:
        total += back * seen
        count += seen
    return total / count


def candidates(
    predictor: StudentPredictor, images: list[np.ndarray], samples: int
) -> tuple[dict[str, list[float]], dict[str, float], torch.Tensor, torch.Tensor]:
    """Every single-student candidate per frame, its ms per frame, the plain mask probability
    and the inside mask (N×S×S)."""
    model = predictor.model
    batch, geometries = frames_to_batch(images, predictor.config)
    batch = batch.contiguous(memory_format=torch.channels_last)
    out: dict[str, list[float]] = {}
    cost: dict[str, float] = {}
    masks: dict[str, torch.Tensor] = {}
    with torch.inference_mode():
        features, skips = model.encoder_maps(batch)
        mean, logvar = model.posterior(features)
        mask_logits, heat_logits = model.decode(mean, skips)
        plain = torch.sigmoid(mask_logits.float())
        heat = torch.sigmoid(heat_logits.float())
        inside = torch.zeros(plain.shape, dtype=torch.bool)
        for index, geometry in enumerate(geometries):
            inside[index, geometry.inner_rows, geometry.inner_columns] = True
        known = predictor.training_codes
        assert known is not None
        distance = known.distance(P.frame_codes(features))
        fixed_beyond = [max(0.0, r - P.FAMILIAR_DISTANCE) for r in distance]

        def timed(name: str, fn: Callable[[], list[float]]) -> None:
            begun = time.perf_counter()
            out[name] = fn()
            cost[name] = 1000 * (time.perf_counter() - begun) / len(images)

        def shipped() -> list[float]:
            found = predictor.predict(images, samples=samples)
            return [float(p.uncertainty or 0.0) for p in found]

        masks["tta mean"] = tta_mean(tta_passes(model, batch, samples), plain)

        def before() -> list[float]:  # timed with its passes, as it runs in a queue
            spread = tta_disagreement(tta_passes(model, batch, samples), plain, inside)
            return [1 - (1 - d) * (1 - r / (1 + r)) for d, r in zip(spread, distance, strict=True)]

        def ambiguity_of(probability: torch.Tensor) -> list[float]:
            return [
                P.mask_ambiguity(p[g.inner_rows, g.inner_columns].numpy())
                for p, g in zip(probability, geometries, strict=True)
            ]

        def dropout() -> list[float]:
            torch.manual_seed(0)
            total = torch.zeros(len(batch))
            for _ in range(samples):
                m, _ = model.posterior(F.dropout2d(features, 0.2, training=True))
                logits, _ = model.decode(m, skips)
                total += soft_iou(torch.sigmoid(logits.float()), plain, inside)
            return [float(1 - v / samples) for v in total]

        def latent() -> list[float]:
            drawn = P.predictive_mask(model, mean, logvar, samples, skips=skips)
            masks["draws' mean"] = drawn
            return [float(1 - v) for v in soft_iou(drawn, plain, inside)]

        def expected() -> list[float]:
            drawn = P.predictive_mask(model, mean, logvar, samples, skips=skips)
            return [float(1 - v) for v in soft_iou(drawn, (plain >= 0.5).float(), inside)]

        begun = time.perf_counter()
        predictor.predict(images, samples=0)
        cost["predict alone"] = 1000 * (time.perf_counter() - begun) / len(images)
        timed("shipped", shipped)
        timed("ambiguity", lambda: ambiguity_of(plain))
        timed("novelty", lambda: known.novelty(P.frame_codes(features)))
        timed("before", before)
        timed("tta", lambda: tta_disagreement(tta_passes(model, batch, samples), plain, inside))
        timed(
            "tta_strong",
            lambda: tta_disagreement(tta_passes(model, batch, samples, 2.0), plain, inside),
        )
        timed("novelty_old", lambda: [r / (1 + r) for r in distance])
        timed("novelty_fixed", lambda: [e / (1 + e) for e in fixed_beyond])
        timed("latent", latent)
        timed("expected", expected)
        out["geometric"] = [
            float(np.sqrt(a * b)) for a, b in zip(out["latent"], out["ambiguity"], strict=True)
        ]
        cost["geometric"] = cost["latent"] + cost["ambiguity"]
        timed("dropout", dropout)
        timed("heatmap", lambda: [float(1 - v) for v in (heat * inside).flatten(1).max(1).values])
    return out, cost, plain, inside, masks


def bootstrap(scores: list[float], errors: list[float], draws: int = 2000) -> tuple[float, ...]:
    """ρ and its 95 % bootstrap interval."""
    if len(scores) < 3 or np.ptp(scores) == 0:  # a constant score: no rank to correlate
        return (float("nan"),) * 3
    return bootstrap_rho(scores, errors, draws)


def within_rho(rows: list[dict], name: str, fold: str) -> tuple[float, ...]:
    """ρ within one fold over every seed's students, each seed ranked on its own: the mean
    of the per-seed ρ, with a bootstrap interval over frames drawn within each seed."""
    per_seed = {}
    for row in rows:
        if row["fold"] == fold:
            per_seed.setdefault(row["seed"], []).append(row)
    values = [
        spearmanr([r[name] for r in group], [1 - r["iou"] for r in group])[0]
        for group in per_seed.values()
        if np.ptp([r[name] for r in group]) > 0
    ]
    rng = np.random.default_rng(0)
    draws = []
    for _ in range(1000):
        rhos = []
        for group in per_seed.values():
            pick = rng.integers(0, len(group), len(group))
            x = np.array([group[i][name] for i in pick])
            y = np.array([1 - group[i]["iou"] for i in pick])
            if np.ptp(x) > 0 and np.ptp(y) > 0:
                rhos.append(spearmanr(x, y)[0])
        if rhos:
            draws.append(np.mean(rhos))
    if not draws:  # a constant score: no rank to correlate
        return (float("nan"),) * 3
    low, high = np.percentile(draws, [2.5, 97.5])
    return float(np.nanmean(values)), float(low), float(high)


def fold_folder(fold: str, seed: int, tag: str = "default") -> str:
    """The cached folder's name of a fold (``real_student.run_folds``'s naming: ``default``,
    or a variant's tag such as ``v11``)."""
    return f"{tag}-{fold.replace(':', '-')}-s{seed}"


ROUNDS_FOLDER = "bench-rounds"
"""Where a student trained here keeps each round's weights (``NN.pt``), for the candidates
made of one run's rounds."""


@contextmanager
def rounds_kept(folder: Path) -> Iterator[None]:
    """While a student trains into ``folder``, also keep each round's weights (the training
    state ``train_student`` saves after every round; the run itself is unchanged)."""
    save = checkpoint.save_state
    kept = folder / ROUNDS_FOLDER

    def keeping(model_dir: Path, state: dict[str, Any]) -> None:
        save(model_dir, state)
        kept.mkdir(exist_ok=True)
        weights = {k: v.detach().clone().contiguous() for k, v in state["model"].items()}
        torch.save(weights, kept / f"{int(state['epoch']):02d}.pt")

    checkpoint.save_state = keeping
    try:
        yield
    finally:
        checkpoint.save_state = save


def round_predictors(folder: Path, rounds: list[int]) -> list[StudentPredictor]:
    """Predictors of the run's weights after each of ``rounds`` (kept by ``rounds_kept``)."""
    config = read_student_config(folder)
    out = []
    for number in rounds:
        model = build_student(config, load_pretrained=False).model
        state = torch.load(folder / ROUNDS_FOLDER / f"{number:02d}.pt", weights_only=True)
        model.load_state_dict(state)
        out.append(StudentPredictor(model, torch.device("cpu")))
    return out


ROUND_SETS = {
    "rounds 17-20": [17, 18, 19, 20],
    "rounds 14-20": [14, 16, 18, 20],
    "rounds 8-20": [8, 12, 16, 20],
    "rounds 5-20": [5, 10, 15, 20],
}
"""The candidates made of one run's rounds (of the default 20): late, spread, and wide."""


def rounds_spread(
    folder: Path, batch: torch.Tensor, inside: torch.Tensor, best: torch.Tensor
) -> tuple[dict[str, list[float]], dict[str, float]]:
    """For each set in ``ROUND_SETS``: 1 − the mean soft IoU of each round's mask probability
    (and the best round's, ``best``) with their mean, per frame; and its ms per frame (the
    extra forward passes)."""
    out, cost = {}, {}
    needed = sorted({number for rounds in ROUND_SETS.values() for number in rounds})
    loaded = dict(zip(needed, round_predictors(folder, needed), strict=True))  # each read once
    for name, rounds in ROUND_SETS.items():
        predictors = [loaded[number] for number in rounds]
        begun = time.perf_counter()
        with torch.inference_mode():
            stack = [best]
            for predictor in predictors:
                mean, _, skips = predictor.model.encode(batch)
                logits, _ = predictor.model.decode(mean, skips)
                stack.append(torch.sigmoid(logits.float()))
            centre = torch.stack(stack).mean(0)
            agreement = torch.stack([soft_iou(p, centre, inside) for p in stack]).mean(0)
        cost[name] = 1000 * (time.perf_counter() - begun) / len(batch)
        out[name] = [float(1 - v) for v in agreement]
    return out, cost


def train_fold(
    frames: list[TrainingFrame], train: list[int], folder: Path, seed: int
) -> tuple[StudentPredictor, float]:
    """The fold's student, trained into ``folder`` unless it is there already (each round's
    weights kept as well)."""
    done = folder / "bench-done.json"
    if not done.is_file():
        config = replace(TrainConfig(device="cpu"), seed=seed)
        begun = time.perf_counter()
        chosen = [frames[i] for i in train]
        with rounds_kept(folder):
            train_student(chosen, folder, StudentConfig(), config, validation=chosen)
        done.write_text(json.dumps({"seconds": time.perf_counter() - begun}))
    codes = load_codes(folder)
    if codes is not None and codes[1] is None:  # trained before students measured their own
        predictor = StudentPredictor.load(folder, "cpu")
        config = predictor.config
        params = HeatmapParams(k=config.k)
        size, aspect = config.input_size, config.aspect
        prepared = [prepare_frame(frames[i], size, aspect, params) for i in train]
        save_training_codes(folder, prepared, torch.device("cpu"), 8)
    return StudentPredictor.load(folder, "cpu"), json.loads(done.read_text())["seconds"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--samples", type=int, default=8)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--cache", type=Path, default=Path("/tmp/weldpool-bench-students"))
    parser.add_argument(
        "--tag",
        default="default",
        help="score a variant's students that real_student.py --ablation trained into --cache "
        "(its tag, e.g. v11) instead of the default's",
    )
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    frames = real_frames()
    rows: list[dict] = []
    costs: dict[str, list[float]] = {}
    probabilities: dict[tuple[str, int], tuple[torch.Tensor, torch.Tensor]] = {}
    for seed in args.seeds:
        for name, train, test in folds(frames, "loco"):
            folder = args.cache / fold_folder(name, seed, args.tag)
            if args.tag != "default" and not (folder / "bench-done.json").is_file():
                raise SystemExit(f"{folder} is not trained: run real_student.py --ablation first")
            predictor, seconds = train_fold(frames, train, folder, seed)
            held = [frames[i] for i in test]
            images = [f.image for f in held]
            scores, cost, plain, inside, masks = candidates(predictor, images, args.samples)
            batch, geometries = frames_to_batch(images, predictor.config)
            if (folder / ROUNDS_FOLDER).is_dir():
                batch = batch.contiguous(memory_format=torch.channels_last)
                spread, spent = rounds_spread(folder, batch, inside, plain)
                scores |= spread
                cost |= spent
            other_ious = {
                source: [
                    iou(
                        P.to_frame(m.numpy(), m.numpy(), geometry, predictor.config).mask,
                        frame.mask,
                    )
                    for m, geometry, frame in zip(probability, geometries, held, strict=True)
                ]
                for source, probability in masks.items()
            }
            for key, value in cost.items():
                costs.setdefault(key, []).append(value)
            probabilities[(name, seed)] = (plain, inside)
            found = score_predictions(predictor.predict(images), held, predictor.config.k)
            for j, frame in enumerate(held):
                rows.append(
                    {
                        "seed": seed,
                        "fold": name,
                        "frame": frame.name,
                        "iou": found.ious[j],
                        "med": float(np.nanmean(found.distances[j])),
                        **{f"iou {source}": values[j] for source, values in other_ious.items()},
                        **{key: values[j] for key, values in scores.items()},
                    }
                )
            print(
                f"seed {seed} {name:<10} trained {seconds:.0f} s, mIoU {found.miou:.3f}, mED "
                f"{found.med or float('nan'):.1f} px",
                flush=True,
            )
    # The seeds' students as an ensemble: each frame's spread about the students' mean.
    ensemble_errors: dict[tuple[str, str], float] = {}
    if len(args.seeds) > 1:
        truth = {f.name: f for f in frames}
        for name, _, test in folds(frames, "loco"):
            stack = torch.stack([probabilities[(name, s)][0] for s in args.seeds])
            inside = probabilities[(name, args.seeds[0])][1]
            centre = stack.mean(0)
            spread = 1 - torch.stack([soft_iou(p, centre, inside) for p in stack]).mean(0)
            first = args.cache / fold_folder(name, args.seeds[0], args.tag)
            predictor = StudentPredictor.load(first, "cpu")
            _, geometries = frames_to_batch([frames[i].image for i in test], predictor.config)
            for j, index in enumerate(test):
                vote = P.to_frame(
                    centre[j].numpy(), centre[j].numpy(), geometries[j], predictor.config
                ).mask
                ensemble_errors[(name, frames[index].name)] = 1 - iou(
                    vote, truth[frames[index].name].mask
                )
                for row in rows:
                    if row["fold"] == name and row["frame"] == frames[index].name:
                        row["ensemble"] = float(spread[j])
    names = [
        k for k in rows[0] if k not in ("seed", "fold", "frame", "iou", "med") and k[:4] != "iou "
    ]
    fold_names = [name for name, _, _ in folds(frames, "loco")]
    errors = [1 - r["iou"] for r in rows]
    print(f"\n{len(rows)} held-out predictions ({len(args.seeds)} seeds × 3 folds × 5 frames)")
    print(
        f"{'candidate':<12}{'ms/frame':>9}{'ρ pooled (95 %)':>24}"
        + "".join(f"{'within ' + f.split(':')[1]:>22}" for f in fold_names)
    )
    for name in names:
        r = bootstrap([row[name] for row in rows], errors)
        within = [within_rho(rows, name, f) for f in fold_names]
        ms = np.median(costs.get(name, [float("nan")]))
        print(
            f"{name:<12}{ms:>9.1f}{f'{r[0]:+.2f} ({r[1]:+.2f} to {r[2]:+.2f})':>24}"
            + "".join(f"{f'{w[0]:+.2f} ({w[1]:+.2f} to {w[2]:+.2f})':>22}" for w in within)
        )
    alone = np.median(costs["predict alone"])
    print(
        f"predict() without the uncertainty: {alone:.1f} ms/frame, with it (shipped): "
        f"{np.median(costs['shipped']):.1f} (median over the folds, batch of 5)"
    )
    print("\nper seed, ρ pooled over the 15 held-out frames:")
    for name in names:
        per = []
        for seed in args.seeds:
            mine = [r for r in rows if r["seed"] == seed]
            scores = [r[name] for r in mine]
            errors_ = [1 - r["iou"] for r in mine]
            per.append(spearmanr(scores, errors_)[0] if np.ptp(scores) > 0 else float("nan"))
        print(f"  {name:<12}" + "".join(f"{v:+7.2f}" for v in per))
    if ensemble_errors:
        first = [r for r in rows if r["seed"] == args.seeds[0]]
        spread = [r["ensemble"] for r in first]
        own = [ensemble_errors[(r["fold"], r["frame"])] for r in first]
        r = bootstrap(spread, own)
        print(
            f"\nensemble of {len(args.seeds)}: ρ(spread, ensemble's 1 − IoU) {r[0]:+.2f} "
            f"({r[1]:+.2f} to {r[2]:+.2f}); ensemble mIoU {1 - np.mean(own):.3f} vs single "
            f"students' {np.mean([r['iou'] for r in rows]):.3f}"
        )
    print("\nper fold and seed: mIoU / mED px")
    for fold in fold_names:
        cells = []
        for seed in args.seeds:
            mine = [r for r in rows if r["seed"] == seed and r["fold"] == fold]
            miou, med = np.mean([r["iou"] for r in mine]), np.nanmean([r["med"] for r in mine])
            cells.append(f"{miou:.3f} / {med:.1f}")
        print(f"  {fold:<10}" + "".join(f"{c:>18}" for c in cells))
    print("\nthe mask from other outputs of the same students: mIoU per fold (mean over seeds)")
    sources = ["iou"] + [k for k in rows[0] if k[:4] == "iou "]
    print(
        f"  {'mask':<22}"
        + "".join(f"{f:>12}" for f in fold_names)
        + f"{'mean':>9}"
        + "".join(f"{'seed ' + str(s):>9}" for s in args.seeds)
    )
    for source in sources:
        per_fold = [np.mean([r[source] for r in rows if r["fold"] == f]) for f in fold_names]
        per_seed = [np.mean([r[source] for r in rows if r["seed"] == s]) for s in args.seeds]
        label = "plain pass (shipped)" if source == "iou" else source[4:] + " ≥ 0.5"
        print(
            f"  {label:<22}"
            + "".join(f"{v:>12.3f}" for v in per_fold)
            + f"{np.mean(per_fold):>9.3f}"
            + "".join(f"{v:>9.3f}" for v in per_seed)
        )
    suffix = "" if args.tag == "default" else f"-{args.tag}"
    (args.cache / f"rows{suffix}.json").write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
